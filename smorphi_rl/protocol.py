"""The one evaluation protocol (docs/spec/env.md section 6): fixed seeded starts, the settled shape,
its gap to the exact optimum, and a map's summary. No torch, no Ray: policies and baselines share it.

Every policy and baseline is started from the same `eval_starts()` on each map; an outcome is the
shape it settles on (the committed shape in `commit` mode, else the one held most often over the
last SETTLE_WINDOW steps), that shape's R1, and the FBCPP evaluations spent (distinct shapes
scored). A map's summary is the median gap to the exact optimum R1* of the 1-degree lattice and the
share of starts that end within 1 % of it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smorphi_rl import jsontext
from smorphi_rl.errors import SmorphiError
from smorphi_rl.geometry import lattice_axis, lattice_size
from smorphi_rl.score import Weights

if TYPE_CHECKING:
    from smorphi_rl.maps import Map
    from smorphi_rl.planning import Planning

EVAL_KEY = "eval"
"""The training result key of the periodic greedy evaluation (TensorBoard: ray/tune/eval/...)."""
TRAINED_KEY = "trained"
"""Under EVAL_KEY, in the last row of a run that ends on an earlier, better policy: the TRAINED_FIGURES of the
policy training ended with, which the learning curves and convergence read (the row's own figures are the chosen
policy's)."""
TRAINED_FIGURES = ("median_gap", "share_within_1pct", "settled_R1_mean")
POOLED_KEYS = (*TRAINED_FIGURES, "starts", "measured_starts", "policy_env_steps", TRAINED_KEY, "kept")
"""Keys under EVAL_KEY beside each evaluated map's summary (which is under the map's name), with those starting
`design_`, and TensorBoard's `kept` (the policy a run ends on, `training/tensorboard.py`): a map may not be named
like one."""


def clashing_map_name(name: str) -> bool:
    """Whether a map of this name would overwrite, or be overwritten by, a pooled figure under EVAL_KEY."""
    return name in POOLED_KEYS or name.startswith("design_")


EVAL_EVERY = 5
"""Training iterations between periodic evaluations (and the first iteration)."""
EVAL_STARTS = 20
"""Seeded start shapes per map (the same for every policy and baseline)."""
EVAL_SEED = 20_231_101
"""The starts' own seed: independent of every training seed."""
SELECT_SEED = EVAL_SEED + 1
"""Seeds the start shapes on which a run chooses its final policy (`selection_starts`)."""
SETTLE_WINDOW = 20
"""The settled shape is the one held most often over the last this many steps."""
WITHIN = 0.01
"""An outcome 'reaches the optimum' when its R1 is within this fraction of R1*."""


def eval_starts(n: int = EVAL_STARTS, step_deg: float = 1.0, seed: int = EVAL_SEED) -> np.ndarray:
    """(n, 3) start shapes, uniform on the `step_deg` lattice, from their own seeded stream."""
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"evaluation starts must be a positive integer, got {n!r}")
    axis = lattice_axis(step_deg)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    return axis[rng.integers(0, len(axis), size=(n, 3))]


def selection_starts(n: int, step_deg: float, protocol: np.ndarray) -> np.ndarray:
    """(n, 3) start shapes from SELECT_SEED's stream, none of them one of the `protocol`'s starts (a run reported on
    those would otherwise be chosen on them too: 3 of 20 at a 45-degree step) while the lattice has a shape to spare;
    at the default 1-degree step none collides, and these are the stream's first n."""
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"selection starts must be a positive integer, got {n!r}")
    axis = lattice_axis(step_deg)
    taken = {tuple(t) for t in protocol.tolist()}
    spare = lattice_size(step_deg) > len(taken)  # one shape left is enough: starts may repeat, as its own do
    rng = np.random.default_rng(np.random.SeedSequence(SELECT_SEED))
    out: list[np.ndarray] = []
    while len(out) < n:
        theta = axis[rng.integers(0, len(axis), size=3)]
        if not spare or tuple(theta.tolist()) not in taken:
            out.append(theta)
    return np.array(out)


def settled_theta(history: Sequence[tuple[float, float, float]]) -> tuple[float, float, float]:
    """The shape held most often over the last SETTLE_WINDOW steps (the latest of equally frequent ones)."""
    tail = list(history[-SETTLE_WINDOW:])
    return max(set(tail), key=lambda t: (tail.count(t), -tail[::-1].index(t)))


@dataclass(frozen=True)
class Outcome:
    """Where one roll-out (or one baseline run) from one start ended."""

    start: tuple[float, float, float]
    settled: tuple[float, float, float]
    R1: float
    P_c: float
    P_len: int
    evaluations: int
    """FBCPP evaluations used: distinct shapes scored."""


@dataclass(frozen=True)
class Optimum:
    """The exact best R1 over the 1-degree lattice of a map and weights."""

    theta: tuple[float, float, float]
    R1: float
    P_c: float
    P_len: int
    step_deg: float = 1.0

    @classmethod
    def of(cls, thetas: np.ndarray, P_c: np.ndarray, P_len: np.ndarray, weights: Weights,
           step_deg: float = 1.0) -> Optimum:  # fmt: skip
        """The best row by R1 of a scored lattice (the first of equal ones)."""
        scores = weights.r1(P_c, P_len)
        i = int(np.argmax(scores))
        t1, t2, t3 = (float(v) for v in thetas[i])
        return cls((t1, t2, t3), float(scores[i]), float(P_c[i]), int(P_len[i]), step_deg)


NO_OPTIMUM = Optimum((math.nan, math.nan, math.nan), math.nan, math.nan, 0)
"""Stands for an optimum not computed (a map too large to enumerate): gaps are NaN."""
OPTIMUM_MAX_CELLS = 250_000
"""Maps with more cells than this (500 x 500) get no exact optimum during training: it would take minutes."""


TIE = 1e-9
"""A gap to R1* this small is float rounding: the shape ties the optimum (a tied run printed a gap of -0.00)."""


def gaps_to(optimum_R1: float, r1: Sequence[float] | np.ndarray | float) -> np.ndarray:
    """R1* minus each R1 (0 at the optimum), a tie within TIE exactly 0."""
    gaps = optimum_R1 - np.asarray(r1, dtype=float)
    return np.where(np.abs(gaps) <= TIE, 0.0, gaps)


def within_band(gaps: np.ndarray, optimum_R1: float) -> np.ndarray:
    """Which gaps to R1* count as 'reaches the optimum' (within WITHIN of |R1*|): the protocol's one rule."""
    return np.asarray(gaps, dtype=float) <= WITHIN * abs(optimum_R1) + 1e-9


@dataclass(frozen=True)
class MapEvaluation:
    """Every start's outcome on one map, against that map's exact optimum."""

    map: str
    method: str
    optimum: Optimum
    outcomes: tuple[Outcome, ...]

    @property
    def measured(self) -> bool:
        """Whether the map has an exact optimum to measure gaps and shares against (NaN R1*: not measured)."""
        return math.isfinite(self.optimum.R1)

    @property
    def gaps(self) -> np.ndarray:
        """R1* minus each settled shape's R1 (0 at the optimum)."""
        return gaps_to(self.optimum.R1, [o.R1 for o in self.outcomes])

    @property
    def median_gap(self) -> float:
        return float(np.median(self.gaps))

    @property
    def within(self) -> int:
        """Starts whose settled shape is within WITHIN of R1*."""
        return int(np.sum(within_band(self.gaps, self.optimum.R1)))

    @property
    def mean_R1(self) -> float:
        return float(np.mean([o.R1 for o in self.outcomes]))

    @property
    def mean_evaluations(self) -> float:
        return float(np.mean([o.evaluations for o in self.outcomes]))

    def summary(self) -> dict[str, float]:
        """The figures logged and tabulated (TensorBoard's eval/... tags)."""
        share = self.within / len(self.outcomes) if self.measured else math.nan
        return {"median_gap": self.median_gap, "share_within_1pct": share, "settled_R1_mean": self.mean_R1,
                "evaluations_mean": self.mean_evaluations, "optimum_R1": self.optimum.R1}  # fmt: skip

    def to_dict(self) -> dict[str, object]:
        return {"map": self.map, "method": self.method, "optimum": asdict(self.optimum), **self.summary(),
                "within": self.within, "starts": len(self.outcomes),
                "outcomes": [asdict(o) for o in self.outcomes]}  # fmt: skip


def key_of(map_source: str | Path | Map, weights: Weights, planning: Planning) -> str:
    """A digest of the map's cells and resolution (a Map, or a map file's), the weights and the planning: what the
    optimum depends on (the paper planner's default keys are those from before there was a choice: their cached
    optima stay). A start given in metres (`--start-xy`) lands on a cell through the map's origin, so the cell it
    lands on is keyed with it: a map saved again with another origin starts its plans elsewhere (and an optimum
    cached before a point on a cell's edge counted in the cell that edge starts is not taken for one from that
    cell)."""
    from smorphi_rl.maps import as_map

    grid_map = as_map(map_source)
    h = hashlib.blake2b(digest_size=12)
    h.update(np.ascontiguousarray(grid_map.cells).tobytes())
    fields = [grid_map.cells.shape, grid_map.resolution_m, weights.w1, weights.w2, *planning.key()]
    if planning.start_xy is not None:
        fields.append(["start cell", *grid_map.cell_of(*planning.start_xy)])
    h.update(json.dumps(fields).encode())
    return h.hexdigest()


_IN_PROCESS: dict[str, Optimum] = {}
"""Optima found in this process, by `key_of` (the map's content, the weights, the planning)."""
IN_PROCESS_KEPT = 32


def _optimum_in_process(
    key: str, grid_map: Map, weights: Weights, planning: Planning, progress: Callable[[int, int], None] | None = None
) -> Optimum:
    from smorphi_rl.search.exhaustive import run_exhaustive

    if key not in _IN_PROCESS:
        result = run_exhaustive(grid_map, 1.0, planning, best_for=weights, progress=progress)  # the best R1 alone
        if len(_IN_PROCESS) >= IN_PROCESS_KEPT:
            del _IN_PROCESS[next(iter(_IN_PROCESS))]  # the oldest
        _IN_PROCESS[key] = Optimum.of(result.thetas, result.P_c, result.P_len, weights)
    return _IN_PROCESS[key]


OPTIMUM_CACHE = ".cache"
"""Folder under --log-dir holding each map's exact optimum (a small JSON per map and weights)."""
CACHE_ENV = "SMORPHI_RL_CACHE_DIR"
"""If set, the exact optima are cached there instead (the test suite shares one cache this way)."""


def optimum_cache(log_dir: str | Path) -> Path:
    """Where every command caches exact optima: $SMORPHI_RL_CACHE_DIR, else LOG_DIR/.cache."""
    import os

    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    try:
        root = Path(log_dir).resolve()
    except (RuntimeError, OSError) as exc:  # a symlink loop, an unreadable folder (as rundir.check_run_dir says)
        raise SmorphiError(f"log directory {log_dir} cannot be used ({exc})") from None
    if root.exists() and not root.is_dir():
        raise SmorphiError(f"log directory {log_dir} is not a folder (exact optima are cached under it)")
    if (root / OPTIMUM_CACHE).is_symlink():  # the optima would be written wherever it points
        raise SmorphiError(f"{root / OPTIMUM_CACHE} is a link: exact optima are cached only under --log-dir (remove "
                           f"the link, or set {CACHE_ENV} to a cache folder)")  # fmt: skip
    return root / OPTIMUM_CACHE


def make_cache(folder: Path, writing: bool = False) -> Path:
    """The optimum cache `folder`, made if need be; one line naming the option to change where it cannot be made,
    or, `writing` (an optimum is about to be computed), written into: else every run would compute it again, unsaid.
    A folder read-only but holding the optimum serves it."""
    from smorphi_rl.rundir import make_writable

    try:
        if writing:
            make_writable(folder)
        else:
            folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a read-only working folder under the default --log-dir: name the option
        import os

        fix = f"set {CACHE_ENV} to" if os.environ.get(CACHE_ENV) else "give --log-dir"
        raise SmorphiError(f"cannot cache exact optima in {folder} ({exc.strerror or exc}): {fix} a folder this "
                           "process can write into") from None  # fmt: skip
    return folder


def _cached_optimum(file: Path, weights: Weights) -> Optimum | None:
    """The optimum a cache file holds, if it is one `exact_optimum` could have written: three angles in 0-180,
    P_c in 0-100, a whole P_len not below 0 and the R1 `weights` give them (else None: a doctored entry would
    print any gap)."""
    from smorphi_rl.inputs import is_finite_number

    try:
        raw = json.loads(file.read_text()) if file.stat().st_size < 1 << 12 else None
        theta, r1, p_c, p_len = raw["theta"], raw["R1"], raw["P_c"], raw["P_len"]  # type: ignore[index]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    angles = isinstance(theta, list) and len(theta) == 3 and all(is_finite_number(t) and 0 <= t <= 180 for t in theta)
    if not (angles and is_finite_number(r1) and is_finite_number(p_c) and 0 <= p_c <= 100 and type(p_len) is int
            and 0 <= p_len <= 2**53):  # fmt: skip
        return None
    if not math.isclose(float(weights.r1(p_c, p_len)), r1, rel_tol=1e-9, abs_tol=1e-9):
        return None
    return Optimum((float(theta[0]), float(theta[1]), float(theta[2])), float(r1), float(p_c), p_len)


def exact_optimum(
    map_source: str | Path | Map,
    weights: Weights,
    planning: Planning,
    cache_dir: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Optimum:
    """R1* of the map over every 1-degree triple (seconds on 2 cores the first time), cached in this
    process and, given `cache_dir`, in a small JSON file there keyed by the map's content, the weights and
    the planning. `progress(done, total)` is called as the search goes (two passes: shapes keyed, settled). The map:
    a map_server YAML's path, or a Map."""
    from smorphi_rl.maps import as_map

    grid_map = as_map(map_source)
    key = key_of(grid_map, weights, planning)
    file = None if cache_dir is None else Path(cache_dir) / f"optimum-{key}.json"
    if file is not None and file.is_file():
        cached = _cached_optimum(file, weights)
        if cached is not None and _as_planned(cached, grid_map, planning):
            return cached  # else a damaged or doctored entry: recomputed and rewritten
    if file is not None:  # before the computation: a folder that cannot hold it is named in seconds, not minutes
        make_cache(file.parent, writing=True)
    optimum = _optimum_in_process(key, grid_map, weights, planning, progress)
    if file is not None:
        _write_entry(file, optimum)
    return optimum


def cached_optimum(grid_map: Map, weights: Weights, planning: Planning, cache_dir: Path) -> Optimum | None:
    """The optimum cached for `grid_map` under `cache_dir`, or None: how `train` reads, on a map too large for it to
    search, the one a `search optimum` run found."""
    file = Path(cache_dir) / f"optimum-{key_of(grid_map, weights, planning)}.json"
    cached = _cached_optimum(file, weights) if file.is_file() else None
    return cached if cached is not None and _as_planned(cached, grid_map, planning) else None


def _as_planned(optimum: Optimum, grid_map: Map, planning: Planning) -> bool:
    """Whether a cached optimum's shape plans to the P_c and P_len its entry holds (one plan): an entry doctored
    to a shape and scores that agree with each other, but not with the map, would print any gap."""
    again = planning.evaluator(grid_map, cache=False).evaluate_many(np.array([optimum.theta], dtype=float))
    return (bool(again.feasible[0]) and int(again.P_len[0]) == optimum.P_len
            and math.isclose(float(again.P_c[0]), optimum.P_c, rel_tol=1e-9, abs_tol=1e-9))  # fmt: skip


def remember_optimum(grid_map: Map, weights: Weights, planning: Planning, cache_dir: Path, optimum: Optimum) -> None:
    """Cache an optimum found elsewhere (`search optimum` at 1 degree) on `grid_map`, the map as it was searched, so
    `train` on it need not search again."""
    file = Path(cache_dir) / f"optimum-{key_of(grid_map, weights, planning)}.json"
    with contextlib.suppress(SmorphiError):  # the search's own results stand; the cache is a convenience
        make_cache(file.parent)
        _write_entry(file, optimum)


def _write_entry(file: Path, optimum: Optimum) -> None:
    from smorphi_rl.rundir import write_atomic

    with contextlib.suppress(OSError):  # a full disk: the optimum stands, the next call computes it again
        write_atomic(file, jsontext.dumps(asdict(optimum)).encode())
