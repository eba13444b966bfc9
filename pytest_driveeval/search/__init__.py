"""Robustness search: hypothesis looks for the smallest perturbation that breaks a policy or a filter.

:mod:`.engine` is the batched search, :mod:`.spec` the scenario's
``Perturbation`` section, :mod:`.item` turns a search into an item's outcome.
The strategies themselves are public in :mod:`pytest_driveeval.strategies`.
"""
