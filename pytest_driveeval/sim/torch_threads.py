"""torch on one intra-op thread for the length of a block.

The engines' batches are small (one scene, tens of episodes), too small for
intra-op threads to help; on a loaded machine (two pytest-xdist workers on
two cores) those threads spin against each other.  Measured on the
closed-loop search of the real scene with the shipped model, 31 s with
torch's default two threads, 9 s on one; the shipped GNN's 64 merging
episodes, 16 s and 0.5 s; the same verdicts and figures either way.  Every
scenario item runs on one thread (harness.fixtures): the shipped planning
model's 16 generated scenes took 90 s on two threads beside another job and
12 s on one.
"""
from __future__ import annotations

import sys
from contextlib import contextmanager
from typing import Iterator

__all__ = ["one_torch_thread"]


@contextmanager
def one_torch_thread(if_imported: bool = False) -> Iterator[None]:
    """torch on one thread inside the block, then as it was.  ``if_imported``: only when something
    imported torch already (a use case without a model need not pay for importing it)."""
    if if_imported and "torch" not in sys.modules:
        yield
        return
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
