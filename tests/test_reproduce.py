"""`reproduce` end to end on the tiny budget: every experiment runs and the report links real files."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from conftest import optima_under

from smorphi_rl.cli import main
from smorphi_rl.protocol import CACHE_ENV, OPTIMUM_CACHE

pytestmark = pytest.mark.slow


def test_reproduce_tiny_writes_a_claim_by_claim_report(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", CACHE_ENV)}
    with optima_under(tmp_path / "logs"):  # the suite's optima, where it looks
        proc = subprocess.run(
            [sys.executable, "-m", "smorphi_rl.cli", "reproduce", "--budget", "tiny", "--name", "r"],
            capture_output=True, text=True, cwd=tmp_path, env=env, timeout=900,
        )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    root = tmp_path / "logs" / "r"
    report = (root / "report.md").read_text()
    for heading in ("Tables 2-3", "Tables 4 and 6", "Figure 5", "Table 5", "claims, one by one"):
        assert heading in report, heading
    claims = [line for line in report.splitlines() if line.startswith("- ")]
    verdicts = ("agree", "undecided", "Not testable")  # the last: no transfer run converged on one side
    assert len(claims) == 7 and sum(any(v in c for v in verdicts) for c in claims) == 6
    assert any("adapts faster" in c and "Greedy median gap at" in c for c in claims)  # at equal env steps
    (protocol,) = [c for c in claims if "evaluation protocol" in c]
    assert re.search(r"PPO \d\.\d\d \(1 seed\), IMPALA \d\.\d\d \(1 seed\)", protocol), protocol
    assert "gap to the exact optimum" in report
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report):
        assert (root / link).is_file(), link
    (searched,) = [c for c in claims if "better shapes than random" in c]  # each algorithm on its own
    assert "PPO" in searched and "IMPALA" in searched and "random search" in searched, searched
    for method in ("ppo-map-1-seed0", "impala-map-1-seed0", "random-map-1-seed0", "nsga2-map-1-seed0",
                   "exhaustive-map-1", "pretrain"):  # fmt: skip
        assert (root / method).is_dir(), method
    assert "| val-1 |" in report
    assert not list(root.rglob(OPTIMUM_CACHE))  # the --log-dir's cache, shared with train and design --exact


def test_reproduce_refuses_an_unknown_budget_and_an_existing_run(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "--budget", "huge"])
    assert exc.value.code == 2 and "invalid choice: 'huge'" in capsys.readouterr().err
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "report.md").write_text("keep me")
    assert main(["reproduce", "--budget", "tiny", "--name", "taken", "--log-dir", str(tmp_path)]) == 1
    assert "already exists" in capsys.readouterr().err
    assert (tmp_path / "taken" / "report.md").read_text() == "keep me"


def test_a_stop_request_that_cuts_a_run_short_stops_the_job(capsys, monkeypatch, tmp_path):
    """A run cut short by Ctrl-C or SIGTERM returns (its handler took the signal): the job then stops with exit 130
    rather than train the next run, pretrain or report claims on a cut-short policy; what it wrote is kept."""
    import contextlib
    from types import SimpleNamespace

    from smorphi_rl import cluster
    from smorphi_rl.training import run

    calls = []

    def cut_short(cfg, name, log_dir, **kwargs):
        calls.append(name)
        (log_dir / name).mkdir()
        return SimpleNamespace(run_dir=log_dir / name, interrupted=True)

    monkeypatch.setattr(run, "train", cut_short)
    monkeypatch.setattr(cluster, "ray_session", lambda address: contextlib.nullcontext())
    assert main(["reproduce", "--budget", "tiny", "--name", "r", "--log-dir", str(tmp_path)]) == 130
    assert f"interrupted: what it wrote is kept in {tmp_path / 'r'}" in capsys.readouterr().err
    assert calls == ["ppo-map-1-seed0"] and (tmp_path / "r" / "ppo-map-1-seed0").is_dir()
    assert not (tmp_path / "r" / "report.md").exists()


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_a_stop_while_the_report_is_written_waits_for_it(capsys, monkeypatch, tmp_path, signame):
    """Ray's shutdown leaves SIGTERM a kill: a SIGTERM as the report was written ended the job with 143 and no word."""
    import contextlib
    import signal
    from types import SimpleNamespace

    from smorphi_rl import cluster, reproduce
    from smorphi_rl.training import run, transfer

    def whole(cfg, name, log_dir, **kwargs):
        (log_dir / name).mkdir()
        return SimpleNamespace(run_dir=log_dir / name, interrupted=False, stop_held=False)

    @contextlib.contextmanager
    def ray_session(address):
        yield
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as Ray's shutdown leaves it

    def writes(budget_name, b, root, *args):
        signal.raise_signal(getattr(signal, signame))
        (root / "report.md").write_text("# whole")
        return root / "report.md"

    monkeypatch.setattr(run, "train", whole)
    monkeypatch.setattr(transfer, "run_transfer", lambda job, **kwargs: (tmp_path / "r" / "transfer", []))
    monkeypatch.setattr(cluster, "ray_session", ray_session)
    monkeypatch.setattr(reproduce, "_write_report", writes)
    assert main(["reproduce", "--budget", "tiny", "--name", "r", "--log-dir", str(tmp_path)]) == 130
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said == f"smorphi-rl: interrupted as the job ended: its report is whole ({tmp_path / 'r' / 'report.md'})"
    assert (tmp_path / "r" / "report.md").read_text() == "# whole"
    assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL  # SIGTERM is Ctrl-C again afterwards


def test_a_run_stopped_with_a_word_of_its_own_still_names_the_job_folder(capsys, monkeypatch, tmp_path):
    """A run's own stop line ('nothing was kept', of the run) is not the job's: the job's folder is kept and named."""
    import contextlib

    from smorphi_rl import cluster
    from smorphi_rl.errors import Interrupted
    from smorphi_rl.training import run

    def stopped(cfg, name, log_dir, **kwargs):
        raise Interrupted(f"stopped before the run's first report: nothing was kept ({log_dir / name} was removed)")

    monkeypatch.setattr(run, "train", stopped)
    monkeypatch.setattr(cluster, "ray_session", lambda address: contextlib.nullcontext())
    assert main(["reproduce", "--budget", "tiny", "--name", "r", "--log-dir", str(tmp_path)]) == 130
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said == f"smorphi-rl: interrupted: what it wrote is kept in {tmp_path / 'r'}"


def test_a_claim_over_seeds_is_decided_by_its_intervals_and_one_seed_decides_nothing():
    from smorphi_rl.reproduce import above
    from smorphi_rl.stats import median_interval

    high, low = median_interval([10.0, 11.0, 12.0]), median_interval([1.0, 2.0, 3.0])
    assert above(high, low) == "**agrees**" and above(low, high) == "**does not agree**"
    assert above(high, median_interval([9.0, 11.0, 13.0])) == "**undecided**"  # the intervals overlap
    assert above(high, 5.0) == "**agrees**" and above(low, 2.5) == "**undecided**"  # against one fixed run
    assert above(median_interval([10.0]), low) == "**undecided** (1 seed: too few to decide)"
    two_apart = above(median_interval([1.0, 2.0]), median_interval([0.0, 0.5]))  # two equal methods: 1 time in 6
    assert two_apart == "**undecided** (2 seeds: too few to decide)"


def test_the_search_claims_compare_seed_by_seed_and_each_algorithm_on_its_own():
    """RL's best over seeds was set against one random search and one NSGA-II front (seed 0's), and the better
    algorithm was picked on the data it was then tested with."""
    from smorphi_rl.compare import MethodScore
    from smorphi_rl.reproduce import BUDGETS, _claims

    def score(r1: float, p_c: float, p_len: int, front: list[tuple[int, float]] = ()) -> MethodScore:
        lens, pcs = (np.array([f[i] for f in front], dtype=float) for i in (0, 1))
        return MethodScore("x", "100 FBCPP evaluations", (0, 0, 0), p_c, p_len, r1, 90.0 - r1, 0.5, lens, pcs)

    b = replace(BUDGETS["tiny"], train_seeds=(0, 1, 2), algorithms=("ppo", "impala"))
    by_seed = {}
    for i in range(3):
        by_seed[("ppo", i)] = score(89.0 + 0.1 * i, 97.0, 80)
        by_seed[("impala", i)] = score(80.0 + 0.1 * i, 90.0, 100)
        by_seed[("random", i)] = score(85.0 + 0.1 * i, 95.0, 100)
        by_seed[("nsga2", i)] = score(86.0, 96.0, 90, [(90, 96.0), (95, 92.0) if i else (99, 99.0)])
    claims = _claims("map-1", b, by_seed, {})
    (random,) = [c for c in claims if "better shapes than random" in c]
    assert "PPO 89.10 [89.00, 89.20]: **agrees**" in random
    assert "IMPALA 80.10 [80.00, 80.20]: **does not agree**" in random
    (front,) = [c for c in claims if "dominates NSGA-II" in c]
    assert "PPO's best is dominated by a shape of NSGA-II's front (same seed) on 0 of 3: **agrees**" in front
    assert "IMPALA's best is dominated by a shape of NSGA-II's front (same seed) on 3 of 3: **does not agree**" in front
    (gap,) = [c for c in claims if "gap to the exact optimum" in c]
    assert "PPO 0.90 [0.80, 1.00]" in gap and "NSGA-II 4.00" in gap


def test_a_job_started_in_the_same_second_takes_the_next_stamped_name(capsys, monkeypatch, tmp_path):
    """The default name is stamped to the second: a second job in that second was refused a name its user never
    gave; it now takes `-2`, and a stop names the folder it took."""
    import contextlib
    from types import SimpleNamespace

    from smorphi_rl import cluster
    from smorphi_rl.cli import train as cli_train
    from smorphi_rl.training import run

    def cut_short(cfg, name, log_dir, **kwargs):
        (log_dir / name).mkdir()
        return SimpleNamespace(run_dir=log_dir / name, interrupted=True)

    monkeypatch.setattr(cli_train, "time", SimpleNamespace(strftime=lambda fmt: "20261207-120000"))
    monkeypatch.setattr(run, "train", cut_short)
    monkeypatch.setattr(cluster, "ray_session", lambda address: contextlib.nullcontext())
    (tmp_path / "reproduce-tiny-20261207-120000").mkdir()
    (tmp_path / "reproduce-tiny-20261207-120000" / "report.md").write_text("keep me")
    assert main(["reproduce", "--budget", "tiny", "--log-dir", str(tmp_path)]) == 130
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said == f"smorphi-rl: interrupted: what it wrote is kept in {tmp_path / 'reproduce-tiny-20261207-120000-2'}"
    assert (tmp_path / "reproduce-tiny-20261207-120000" / "report.md").read_text() == "keep me"
    assert main(["reproduce", "--budget", "tiny", "--name", "reproduce-tiny-20261207-120000",
                 "--log-dir", str(tmp_path)]) == 1  # fmt: skip
    assert "already exists" in capsys.readouterr().err  # a name the user gave is never changed
