"""`smorphi-rl reproduce`: the paper's experiments end to end on the shipped maps, and a report that
says claim by claim where our results agree with the paper and where they do not.

PPO and IMPALA (the paper's A3C) on map-1 and map-2; random shapes; NSGA-II; the exhaustive
front; a policy pretrained on map-1 and map-2 transferred to the validation maps. Everything
lands under logs/<run>/, with report.md on top.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from smorphi_rl import interrupts
from smorphi_rl.errors import Interrupted, SmorphiError
from smorphi_rl.maps import SHIPPED_MAPS
from smorphi_rl.rundir import DEFAULT_LOG_DIR, rel, write_text_atomic
from smorphi_rl.stats import Interval, median_interval, too_few
from smorphi_rl.training.presets import ENVS_PER_RUNNER

if TYPE_CHECKING:
    from smorphi_rl.compare import MethodScore
    from smorphi_rl.score import Weights
    from smorphi_rl.search.results import SearchResult
    from smorphi_rl.training.transfer import TransferRun

MAPS_DIR = SHIPPED_MAPS
TRAIN_MAPS = ("map-1", "map-2")
VAL_MAPS = ("val-1", "val-2", "val-3")


class _Cuttable(Protocol):
    @property
    def interrupted(self) -> bool: ...


_Run = TypeVar("_Run", bound=_Cuttable)


@dataclass(frozen=True)
class Budget:
    """How much of each experiment a reproduction runs."""

    train_steps: int
    pretrain_steps: int
    transfer_steps: int
    val_maps: tuple[str, ...]
    algorithms: tuple[str, ...]
    train_maps: tuple[str, ...]
    random_samples: int
    nsga2_pop: int
    nsga2_generations: int
    exhaustive_step: float
    envs_per_runner: int = ENVS_PER_RUNNER
    """Envs per env runner (the tiny budget uses few, so whole 200-step episodes end within it)."""
    env_runners: int | None = None
    """Remote env runners of every training run; None: the preset's (2). The tiny budget samples in the trial
    process (0): a smoke check of the pipeline, not of the layout, in a third of the time."""
    transfer_seeds: tuple[int, ...] = (0, 1, 2)
    """Seeds of the transfer job: each held-out map is fine-tuned and trained from scratch once per seed."""
    train_seeds: tuple[int, ...] = (0, 1, 2)
    """Seeds of each algorithm on each training map: the claims compare them over seeds, with intervals; the tables
    and figures show the first seed's run."""


BUDGETS = {
    # 10 minutes on 2 cores (9 min 35 s measured on 2026-12-04: 12 training runs, the searches, 18 transfer runs).
    "small": Budget(30_000, 50_000, 20_000, VAL_MAPS, ("ppo", "impala"), TRAIN_MAPS, 1000, 40, 50, 1.0),
    # The paper's scale: 3 x 10^5 steps a run (its Figure 5); hours on 2 cores.
    "paper": Budget(300_000, 300_000, 300_000, VAL_MAPS, ("ppo", "impala"), TRAIN_MAPS, 1000, 100, 100, 1.0),
    # A smoke test of the whole pipeline (the test suite): minutes, results meaningless.
    "tiny": Budget(
        1000,
        1000,
        1000,
        ("val-1",),
        ("ppo", "impala"),
        ("map-1",),
        100,
        10,
        3,
        10.0,
        envs_per_runner=2,
        env_runners=0,
        transfer_seeds=(0,),
        train_seeds=(0,),
    ),
}


class ReportWhole(Interrupted):
    """A stop that came as the report was written: the job waited for it, and the report is whole."""


PAPER_REWARD = "paper"
"""`reproduce` trains on the paper's reward (R1 + R2), whatever `train`'s default is."""


def _map(name: str) -> str:
    return str(MAPS_DIR / f"{name}.yaml")


def _whole(run: _Run) -> _Run:
    """`run`, unless a stop request cut it short: then the job stops too (KeyboardInterrupt), keeping what it wrote,
    rather than go on from a cut-short policy and report claims on it; a stop held until a run's results were
    written (`RunSummary.stop_held`) stops the job there too."""
    if run.interrupted or getattr(run, "stop_held", False):
        raise KeyboardInterrupt
    return run


def reproduce(
    budget_name: str, name: str, log_dir: str | Path = DEFAULT_LOG_DIR, out: Any = None, stamped: bool = False
) -> Path:
    """Run every experiment of `budget_name`; returns the report's path. `stamped`: `name` is one the command made
    from the time, so a job started in the same second takes `<name>-2`. A stop request names the job's folder."""
    from smorphi_rl import cluster
    from smorphi_rl.rundir import MARKER, discard_run_dir, prepare_run_dir, prepare_stamped_run_dir

    if budget_name not in BUDGETS:
        raise SmorphiError(f"unknown budget '{budget_name}' (choose from {', '.join(BUDGETS)})")
    b = BUDGETS[budget_name]
    cluster.check_reachable(None, client=False)  # a local Ray that cannot start (its temp folder): one line, no folder
    root = (prepare_stamped_run_dir if stamped else prepare_run_dir)(log_dir, name)
    try:
        return _run_job(b, budget_name, root, log_dir, out)
    except cluster.ClusterError:  # Ray did not start: nothing ran, and the name stays free
        if all(p.name == MARKER for p in root.iterdir()):
            discard_run_dir(root)
        raise
    except KeyboardInterrupt as exc:  # Ctrl-C, or a run a stop request cut short: what was written stays
        if isinstance(exc, ReportWhole) or not root.is_dir():  # a run's own word is not the job's
            raise
        raise Interrupted(f"what it wrote is kept in {rel(root)}") from None


def _run_job(b: Budget, budget_name: str, root: Path, log_dir: str | Path, out: Any) -> Path:
    """`reproduce`'s experiments in their order, under `root`; the report's path."""
    from smorphi_rl import cluster
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import load_map
    from smorphi_rl.rundir import prepare_run_dir, safe_name
    from smorphi_rl.search.exhaustive import run_exhaustive
    from smorphi_rl.search.nsga2 import run_nsga2
    from smorphi_rl.search.random import run_random
    from smorphi_rl.search.results import save
    from smorphi_rl.training.config import TrainConfig
    from smorphi_rl.training.run import train
    from smorphi_rl.training.transfer import TransferJob, run_transfer

    defaults = EnvConfig()
    weights = {m: defaults.weights_on(load_map(_map(m))) for m in b.train_maps}  # R1 on each map, as the env ranks
    t0 = time.monotonic()
    say = lambda text: print(text, file=out or sys.stderr, flush=True)  # noqa: E731

    with cluster.ray_session(None):  # every run of the job on one local Ray, started once
        training: dict[tuple[str, str], list[Path]] = {}
        for map_name in b.train_maps:
            for algo in b.algorithms:
                say(f"[reproduce] {algo.upper()} on {map_name}, {b.train_steps:,} env steps, seeds "
                    f"{', '.join(map(str, b.train_seeds))}")  # fmt: skip
                env = EnvConfig.from_dict({"maps": [_map(map_name)], "reward": PAPER_REWARD})
                for seed in b.train_seeds:
                    cfg = TrainConfig(algo=algo, env=env, timesteps=b.train_steps, seed=seed,
                                      envs_per_runner=b.envs_per_runner, num_env_runners=b.env_runners)  # fmt: skip
                    run = train(cfg, name=f"{algo}-{map_name}-seed{seed}", log_dir=root, out=out,
                                label=f"{algo.upper()} {map_name} seed {seed}", optima_log_dir=log_dir)  # fmt: skip
                    training.setdefault((algo, map_name), []).append(_whole(run).run_dir)
        exact: dict[str, SearchResult] = {}
        for map_name in b.train_maps:  # the searches with the training seeds: the claims compare seed by seed
            say(f"[reproduce] random search and NSGA-II (seeds {', '.join(map(str, b.train_seeds))}) and the "
                f"exhaustive front on {map_name}")  # fmt: skip
            for seed in b.train_seeds:
                for result in (run_random(_map(map_name), b.random_samples, seed=seed),
                               run_nsga2(_map(map_name), b.nsga2_pop, b.nsga2_generations, seed=seed)):  # fmt: skip
                    save(result, prepare_run_dir(root, search_dirname(result.method, map_name, seed)),
                         weights[map_name])  # fmt: skip
            exact[map_name] = run_exhaustive(_map(map_name), b.exhaustive_step)
            save(exact[map_name], prepare_run_dir(root, safe_name(f"exhaustive-{map_name}")), weights[map_name])
        say(f"[reproduce] pretraining PPO on {' + '.join(TRAIN_MAPS)}, {b.pretrain_steps:,} env steps")
        pre_env = EnvConfig.from_dict({"maps": [_map(m) for m in TRAIN_MAPS], "reward": PAPER_REWARD})
        pre_cfg = TrainConfig(env=pre_env, timesteps=b.pretrain_steps, envs_per_runner=b.envs_per_runner,
                              num_env_runners=b.env_runners)  # fmt: skip
        pre = _whole(train(pre_cfg, name="pretrain", log_dir=root, out=out, label="PPO pretrain",
                           optima_log_dir=log_dir))  # fmt: skip
        say(
            f"[reproduce] transfer to {', '.join(b.val_maps)}: fine-tuned and from scratch, {b.transfer_steps:,} each, "
            f"seeds {', '.join(map(str, b.transfer_seeds))}"
        )
        job = TransferJob(pre.run_dir, tuple(_map(m) for m in b.val_maps), tuple(b.transfer_seeds), b.transfer_steps,
                          envs_per_runner=b.envs_per_runner, num_env_runners=b.env_runners)  # fmt: skip
        job_dir, transfer_runs = run_transfer(job, name="transfer", log_dir=root, out=out, optima_log_dir=log_dir)
        for transfer_run in transfer_runs:
            _whole(transfer_run)
    with interrupts.writes_held() as late:  # a stop as the report is written waits for it
        report = _write_report(budget_name, b, root, time.monotonic() - t0, training, exact, weights, job_dir,
                               transfer_runs)  # fmt: skip
    if late.is_set():
        raise ReportWhole(f"as the job ended: its report is whole ({rel(report)})")
    return report


def _write_report(budget_name: str, b: Budget, root: Path, wall_s: float, training: dict[tuple[str, str], list[Path]],
                  exact: dict[str, SearchResult], weights: dict[str, Weights], job_dir: Path,
                  transfer_runs: list[TransferRun]) -> Path:  # fmt: skip
    """report.md, from the job's runs and searches: the tables, figures and claims, each run's compared."""
    from smorphi_rl.compare import points_of_run, score_methods, write_report
    from smorphi_rl.env_config import EnvConfig
    from smorphi_rl.maps import load_map
    from smorphi_rl.planning import PAPER_PLANNING
    from smorphi_rl.rundir import prepare_run_dir, safe_name
    from smorphi_rl.score import Weights
    from smorphi_rl.training.transfer import summary_curve, write_transfer_report

    defaults = EnvConfig()
    transfer_files = write_transfer_report(job_dir, transfer_runs)

    sections = [
        f"# Reproduction of Kalimuthu et al. (2023), budget '{budget_name}'",
        "",
        f"{Weights(defaults.w1, defaults.w2).formula()} (the env's defaults). Every figure below was measured "
        f"in this run ({wall_s / 60:.0f} min on "
        f"{len(b.algorithms) * len(b.train_maps) * len(b.train_seeds)} training runs, the searches and the transfer "
        f"job). Each algorithm trains with seeds {', '.join(map(str, b.train_seeds))} on each map: the claims compare "
        f"them over seeds (median [95 % interval]); the tables and figures show seed {b.train_seeds[0]}'s run.",
    ]
    claims: list[str] = []
    for map_name in b.train_maps:
        keys = [(a, i) for a in b.algorithms for i in range(len(b.train_seeds))]
        dirs = [training[(a, map_name)][i] for a, i in keys]
        keys += [(m, i) for m in ("nsga2", "random") for i in range(len(b.train_seeds))]
        dirs += [root / search_dirname(m, map_name, b.train_seeds[i]) for m, i in keys[len(dirs) :]]
        exact_score, every = score_methods(exact[map_name], [points_of_run(d, map_name) for d in dirs],
                                           weights[map_name])  # fmt: skip
        by_seed = dict(zip(keys, every, strict=True))
        scores = [by_seed[(m, 0)] for m in (*b.algorithms, "nsga2", "random")]  # the tables: the first seed's
        cmp_dir = prepare_run_dir(root, safe_name(f"compare-{map_name}"))
        planning = PAPER_PLANNING.describe(load_map(_map(map_name)))  # the paper's planner, as every run here
        files = write_report(exact_score, scores, map_name, weights[map_name], planning, cmp_dir)
        curves = {a.upper(): summary_curve(training[(a, map_name)][0]) for a in b.algorithms}
        sections += _map_section(map_name, training, b, exact_score, scores, files, curves, root)
        seeds = {a: [_seed_figures(d) for d in training[(a, map_name)]] for a in b.algorithms}
        claims += _claims(map_name, b, by_seed, seeds)
    sections += ["", "## Transfer to unseen maps (Table 5)", "",
                 transfer_files["md"].read_text().rstrip(), "",
                 f"![transfer curves]({transfer_files['png'].relative_to(root)})"]  # fmt: skip
    claims += _transfer_claims(transfer_runs)
    sections += ["", "## The paper's claims, one by one", "", *claims, ""]
    report = root / "report.md"
    write_text_atomic(report, "\n".join(sections))
    return report


def _map_section(map_name: str, training: dict[tuple[str, str], list[Path]], b: Budget, exact: MethodScore,
                 scores: list[MethodScore], files: dict[str, Path], curves: dict[str, Any],
                 root: Path) -> list[str]:  # fmt: skip
    """Tables 2-4 and 6 and Figures 5-7 for one map."""
    from smorphi_rl.compare import method_table
    from smorphi_rl.plots import plot_learning_curves

    curve_png = plot_learning_curves(curves, root / f"curves-{map_name}.png", exact.best_R1)
    lines = ["", f"## {map_name}", "", "### Top morphologies found by RL (Tables 2-3, Figure 6)", ""]
    for algo in b.algorithms:
        run_dir = training[(algo, map_name)][0]
        lines += [(run_dir / "top_morphologies.md").read_text().rstrip(), "",
                  f"![top {algo}]({(run_dir / 'top_morphologies.png').relative_to(root)})", ""]  # fmt: skip
    lines += ["### Every method against the exact front (Tables 4 and 6, Figure 7)", "",
              *method_table(exact, scores), "",
              f"![pareto]({files['plot'].relative_to(root)})", "",
              "### Learning curves (Figure 5)", "", f"![curves]({curve_png.relative_to(root)})"]  # fmt: skip
    return lines


def _final_return(curve: dict[str, list[float]]) -> float:
    values = np.asarray(curve["episode_return_mean"], dtype=float)
    tail = values[np.isfinite(values)][-10:]
    return float(np.mean(tail)) if tail.size else float("nan")


@dataclass(frozen=True)
class SeedFigures:
    """What the claims compare of one training run: its final mean episode return, the best R1 it visited, and the
    share of the protocol's starts its final policy settles within 1 % of the exact optimum (NaN: not evaluated)."""

    final_return: float
    best_R1: float
    share_within: float = math.nan


def _seed_figures(run_dir: Path) -> SeedFigures:
    from smorphi_rl.inputs import read_json_object
    from smorphi_rl.training.transfer import summary_curve

    summary = read_json_object(run_dir / "summary.json", "run summary")
    best, evaluation = summary.get("best") or {}, summary.get("evaluation") or {}
    share = evaluation.get("share_within_1pct")
    return SeedFigures(_final_return(summary_curve(run_dir)), float(best.get("R1", math.nan)),
                       float(share) if isinstance(share, int | float) else math.nan)  # fmt: skip


def above(a: Interval, b: Interval | float) -> str:
    """The verdict on "a is higher than b" over seeds (`b` a number: one fixed reference, such as a search run once):
    agrees when a's 95 % interval lies wholly above b's, does not agree when wholly below, else undecided; fewer than
    `VERDICT_SEEDS` decide nothing."""
    low, high = (b.lo, b.hi) if isinstance(b, Interval) else (float(b), float(b))
    n = min(a.n, b.n) if isinstance(b, Interval) else a.n
    if too_few(n):
        return f"**undecided** ({too_few(n)})"
    return "**agrees**" if a.lo > high else "**does not agree**" if a.hi < low else "**undecided**"


def _claims(map_name: str, b: Budget, by_seed: dict[tuple[str, int], MethodScore],
            seeds: dict[str, list[SeedFigures]]) -> list[str]:  # fmt: skip
    """Claim by claim, on one map: agree, disagree or undecided over the seeds, with the numbers. `by_seed`: every
    training run and search by (algorithm or search method, seed index); each search ran with the training seeds,
    so RL and the searches are compared over the same number of seeds, and each algorithm on its own."""
    count = len(b.train_seeds)
    n = f"{count} seed{'s' if count > 1 else ''}"

    def over_seeds(method: str, figure: str) -> Interval:
        return median_interval([float(getattr(by_seed[(method, i)], figure)) for i in range(count)])

    out = []
    if "ppo" in seeds and "impala" in seeds:
        ppo, imp = (median_interval([f.final_return for f in seeds[a]]) for a in ("ppo", "impala"))
        out.append(f"- {map_name}: *PPO reaches a higher mean reward than A3C.* Final mean episode return over {n}, "
                   f"PPO {ppo.text(',.0f')}, IMPALA {imp.text(',.0f')}: {above(ppo, imp)}.")  # fmt: skip
        ppo, imp = (median_interval([f.share_within for f in seeds[a]]) for a in ("ppo", "impala"))
        out.append(f"- {map_name}: *The same on the evaluation protocol (beyond the paper).* Share of the protocol's "
                   f"starts the final policy settles within 1 % of the exact optimum, over {n}, PPO {ppo.text()}, "
                   f"IMPALA {imp.text()}: {above(ppo, imp)}.")  # fmt: skip
    rnd = over_seeds("random", "best_R1")
    each = "; ".join(f"{a.upper()} {over_seeds(a, 'best_R1').text()}: {above(over_seeds(a, 'best_R1'), rnd)}"
                     for a in b.algorithms)  # fmt: skip
    out.append(f"- {map_name}: *RL finds better shapes than random shapes.* Best R1 over {n}, random search "
               f"{rnd.text()} ({by_seed[('random', 0)].budget} a seed) against {each}.")  # fmt: skip
    verdicts = []
    for a in b.algorithms:
        dominated = [_dominated(by_seed[(a, i)], by_seed[("nsga2", i)]) for i in range(count)]
        verdict = (f"**undecided** ({too_few(count)})" if too_few(count) else "**agrees**" if not any(dominated)
                   else "**does not agree**" if all(dominated) else "**undecided**")  # fmt: skip
        verdicts.append(f"{a.upper()}'s best is dominated by a shape of NSGA-II's front (same seed) on "
                        f"{sum(dominated)} of {count}: {verdict}")  # fmt: skip
    out.append(f"- {map_name}: *The RL shape dominates NSGA-II's Pareto front.* {'; '.join(verdicts)} "
               "(strictly dominating a whole front is more than either can show; we test the weaker, checkable "
               "form).")  # fmt: skip
    gaps = ", ".join(f"{label} {over_seeds(m, 'gap_R1').text()}" for m, label in
                     [*((a, a.upper()) for a in b.algorithms), ("nsga2", "NSGA-II"), ("random", "random")])  # fmt: skip
    fractions = " / ".join(over_seeds(m, "hv_fraction").text(".4f") for m in (*b.algorithms, "nsga2", "random"))
    out.append(f"- {map_name}: *Beyond the paper: gap to the exact optimum.* Over {n}: {gaps} (R1 points); "
               f"hypervolume fractions {fractions}.")  # fmt: skip
    return out


def _dominated(rl: MethodScore, nsga: MethodScore) -> bool:
    """Whether some shape of NSGA-II's front is at least as good as RL's best shape in P_c and P_len, and better in
    one."""
    better_pc, shorter = nsga.front_pc >= rl.best_P_c, nsga.front_len <= rl.best_P_len
    strictly = (nsga.front_pc > rl.best_P_c) | (nsga.front_len < rl.best_P_len)
    return bool(np.any(better_pc & shorter & strictly))


def search_dirname(method: str, map_name: str, seed: int) -> str:
    """A reproduction's search run folder, named as `search` names it: `random-map-1-seed0`."""
    from smorphi_rl.search.config import SearchConfig

    return SearchConfig(method=method, map_path=_map(map_name), seed=seed).run_name


def _transfer_claims(runs: list[Any]) -> list[str]:
    """Table 5's claim per held-out map, over seeds: the speed-up with its interval, judged as `bench_transfer.py`
    judges it (`transfer.speedup`); a run that never converged counts as past its budget, and a map where the
    medians of both modes lie past it gives no ratio."""
    from smorphi_rl.training.transfer import by_map, equal_steps, speedup

    out = []
    claim = "*A pretrained policy converges about five times faster.*"
    equal = equal_steps(runs)
    for m in by_map(runs):
        tuned, scratch = m.gaps_at(equal)
        out.append(f"- {m.map_name}: *A pretrained policy adapts faster.* Greedy median gap at {equal:,} env steps "
                   f"fine-tuned {tuned.text()} vs scratch {scratch.text()}: {above(scratch, tuned)}.")  # fmt: skip
        counts = f"converged: fine-tuned {m.counts[0]}, scratch {m.counts[1]}"
        ratio = m.ratio
        if not ratio.n:  # no ratio where both medians lie past the budget (MapTransfer.ratio)
            out.append(f"- {m.map_name}: {claim} Not testable here ({counts}).")
            continue
        verdict = speedup(ratio)
        seeds = f" ({too_few(ratio.n)})" if too_few(ratio.n) else ""
        out.append(f"- {m.map_name}: {claim} Fine-tuned {m.tuned_steps.text(',.0f')} vs scratch "
                   f"{m.scratch_steps.text(',.0f')} env steps to converge (medians; {counts}), {verdict.text}: "
                   f"{verdict.word}{seeds}.")  # fmt: skip
    return out
