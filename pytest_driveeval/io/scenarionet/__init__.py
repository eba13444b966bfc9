"""ScenarioNet (MetaDrive scenario description) pickles, read through a whitelist, and their
conversion to the L5 arrays and semantic map the closed-loop engine steps."""
