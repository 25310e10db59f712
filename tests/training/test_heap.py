"""The collector settled in a training process: start-up objects frozen once, later cycles still collected."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from smorphi_rl.training import heap


@pytest.fixture
def fresh_process(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The collector as a new process has it, restored afterwards."""
    threshold = gc.get_threshold()
    monkeypatch.setattr(heap, "_settled", False)
    gc.unfreeze()
    yield
    gc.unfreeze()
    gc.set_threshold(*threshold)


class _Node:
    def __init__(self) -> None:
        self.other: _Node | None = None


def test_settle_freezes_what_is_alive_once_and_later_cycles_are_collected(fresh_process: None) -> None:
    before = _Node()
    heap.settle_heap()
    assert gc.get_freeze_count() > 0
    assert not any(o is before for o in gc.get_objects())  # out of every generation the collector walks
    assert gc.get_threshold()[2] == heap.FULL_PASS_EVERY

    frozen = gc.get_freeze_count()
    after = _Node()
    heap.settle_heap()  # a second algorithm in the same process: nothing more is frozen
    assert gc.get_freeze_count() == frozen
    assert any(o is after for o in gc.get_objects())

    a, b = _Node(), _Node()
    a.other, b.other = b, a
    ref = weakref.ref(a)
    del a, b
    gc.collect()
    assert ref() is None  # a cycle made after the freeze is collected
