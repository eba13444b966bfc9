"""What every part of the package leans on: the error types, what an evaluation returns
(``Outcome``), atomic writes, time limits and the use-case interface with its registry.
It imports nothing else of the package, so any part may import it."""
