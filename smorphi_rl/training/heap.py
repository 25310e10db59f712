"""The cyclic garbage collector in the processes that train: start-up objects frozen, full passes rarer.

A trial's process holds about 500,000 objects once torch and RLlib are imported and the algorithm is built
(modules, functions, RLlib's registries), nearly all alive until the process ends. Python's collector walks
every one of them in each full pass: 0.44 s a pass, 4 passes (1.6 s) in a 100-iteration PPO run on 2 cores,
while the young generations cost 0.3 s in all. Freezing what is alive after the build moves it out of the
collector's reach (`gc.freeze`); a full pass then walks only what training made since, and with the third
threshold at 50 instead of 10 it ran 3 times: 0.6 s of collection in all (map-1, 100 iterations).
Cycles made after the freeze are collected as before.
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
