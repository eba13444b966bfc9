"""Did it get worse?  Each scenario item against its baseline (a file committed with the scenarios)
or an earlier run: :mod:`.payload` is what is kept, :mod:`.rules` what counts as worse,
:mod:`.compare` the comparison, :mod:`.store` where references live, :mod:`.gate` the session's side."""
