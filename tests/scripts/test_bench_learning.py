"""The learning benchmark's convergence column counts as the sweep and transfer tables count."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
from bench_learning import Row, converged_cell


def run(seed: int, converged_at: float | None, converged: str, env_steps: float = 300_000.0) -> Row:
    return Row("map-1", "PPO peak", seed, 0.0, 1.0, 80.0, 90.0, converged_at=converged_at, converged=converged,
               env_steps=env_steps)  # fmt: skip


def test_a_run_that_did_not_converge_counts_past_the_steps_it_trained_and_the_median_has_its_interval():
    """It counted past its last evaluation (0 with none), and the median came without the interval computed."""
    group = [run(0, 100_000.0, "100000"), run(1, None, "not converged"), run(2, None, "not converged")]
    assert converged_cell(group) == "1 of 3, median > 300,000 [100,000, inf] steps"
    both = [run(0, 100_000.0, "100000"), run(1, 140_000.0, "140000"), run(2, None, "not converged")]
    assert converged_cell(both).startswith("2 of 3, median 140,000 [100,000, ")


def test_a_run_never_measured_is_left_out_of_the_count():
    group = [run(0, 100_000.0, "100000"), run(1, None, "not measured")]
    assert converged_cell(group) == "1 of 1, median 100,000 (1 seed) steps"
    assert converged_cell([run(0, None, "not measured")]) == "not measured"
