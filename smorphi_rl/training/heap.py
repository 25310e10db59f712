"""The cyclic garbage collector in the processes that train: start-up objects frozen, full passes rarer.

A trial's process holds about 500,000 objects once torch and RLlib are imported and the algorithm is built
(modules, functions, RLlib's registries), nearly all alive until the process ends. Python's collector walks
every one of them in each full pass, about 0.25 s each. Freezing what is alive after the build moves it out
of the collector's reach (`gc.freeze`); a full pass then walks only what training made since, and with the
third threshold at 50 instead of 10 there are fewer of them. Measured in the trial process of `train` on
map-1 (PPO, 100 iterations): 1.98 s of collection in all (7 full passes, 1.70 s), settled 0.87 s (5 full
passes, 0.58 s). Cycles made after the freeze are collected as before.
"""

from __future__ import annotations

import gc

FULL_PASS_EVERY = 50
"""Collections of the middle generation between two full ones (Python's default: 10)."""

_settled = False


def settle_heap() -> None:
    """Once per process: collect the young generations, freeze every object alive, make full passes rarer.

    Later calls do nothing, so a process that builds many algorithms (the test suite, a notebook) freezes
    only once: frozen objects are never collected, and a stopped algorithm's cycles must stay collectable."""
    global _settled
    if _settled:
        return
    _settled = True
    gc.collect(1)
    gc.freeze()
    first, second, _ = gc.get_threshold()
    gc.set_threshold(first, second, FULL_PASS_EVERY)
