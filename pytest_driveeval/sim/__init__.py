"""Simulators: drive agents through scenes, step by step.

What every simulator shares: the kinematic state of a batch of agents
(:mod:`.state`, ``AgentState``) and the models that step it from an action
(:mod:`.dynamics`: the requested pose taken as is, a unicycle with limits, a
kinematic bicycle).  :mod:`.logreplay` drives the ego through logged scenes
while the other agents replay the log; :mod:`.episodes` steps the policy
benchmark's seeded episodes of the :mod:`.blueprints` (highway, merging,
intersection), whose traffic drives by IDM and MOBIL (:mod:`.agents`).

Importing this package is light (numpy only); the simulators import torch.
"""
