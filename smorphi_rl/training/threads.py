"""Torch's intra-op threads while acting: one.

A trial's process gives its PPO learner two threads (`callbacks.on_algorithm_init`), but sampling runs a forward
pass over 32 rows per step, where waking a second OpenMP thread costs more than it saves: on 2 cores, sampling
took 4-5 ms less an iteration with one thread, and a run's weights after 8 iterations were the same bits either
way. (The greedy roll-outs of an evaluation gave the same outcomes and time at one thread, so they are left.)
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """Run the block with torch on one intra-op thread, then give back the count it had."""
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
