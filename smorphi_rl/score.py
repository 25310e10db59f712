"""R1 = w1 P_c - w2 P_len: the one formula that ranks shapes everywhere (env rewards, searches, compare,
the protocol's optimum, the critic's scale). Scalars or numpy arrays alike.

P_c is a percentage, the same on any floor; P_len counts tile moves, which grow with the floor's area, so
with the paper's fixed w2 the ranking on a large floor collapses to "shortest path". The path term
`per_area` charges w2 per tile move per REFERENCE_AREA_M2 of free floor instead: the weight in effect on
a map is w2 * REFERENCE_AREA_M2 / (its free area), so the same w2 means the same trade-off on every floor
(on the shipped 5 m x 5 m maps, nearly the paper's)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

PATH_TERMS = ("moves", "per_area")
"""How w2 charges the path: per tile move (the paper's), or per tile move per REFERENCE_AREA_M2 of floor."""
REFERENCE_AREA_M2 = 25.0
"""The floor area `per_area` weights are stated for: the shipped maps' 5 m x 5 m."""

MAX_P_LEN = 250_000_000
"""More tile moves than a coverage path of the largest map we read (25 M pixels) takes ten times over."""


def effective_w2(w2: float, path_term: str, free_area_m2: float) -> float:
    """The weight of P_len in effect on a floor of `free_area_m2` free square metres."""
    if path_term == "moves":
        return w2
    if path_term == "per_area":
        return w2 * REFERENCE_AREA_M2 / free_area_m2
    raise ValueError(f"unknown path term {path_term!r} (choose from {', '.join(PATH_TERMS)})")


@dataclass(frozen=True)
class Weights:
    """R1's weights in effect on one map (w2 after `path_term`): the one value that ranks shapes, passed to the
    env, the searches, compare, the protocol's optimum and the critic's scale. The reward *mode* is not part of
    it: it only shapes the env's training signal, while everything that ranks shapes ranks by R1."""

    w1: float
    w2: float

    def r1(self, p_c: Any, p_len: Any) -> Any:
        """R1 of one result (floats) or of arrays of them (float64 arrays)."""
        return self.w1 * p_c - self.w2 * p_len

    def formula(self) -> str:
        """`R1 = w1 P_c - w2 P_len` with the numbers, as reports print it."""
        return f"R1 = {self.w1:g} P_c - {self.w2:g} P_len"


@dataclass(frozen=True)
class Scored:
    """One shape's FBCPP metrics and R1 on one map: what a step's `info` reports, and what everything that ranks
    shapes reads (the env, local searches, the evaluation protocol)."""

    theta: tuple[float, float, float]
    P_c: float
    coverage_free_pct: float
    P_len: int
    path_length_m: float
    feasible: bool
    R1: float
    map: str

    @cached_property
    def info(self) -> dict[str, Any]:
        """The fields as `info` carries them (built once: the env memoises a shape's Scored, and steps are hot)."""
        return {f: getattr(self, f) for f in INFO_FIELDS}

    @cached_property
    def best_info(self) -> dict[str, Any]:
        """The fields `info` carries for the episode's best shape so far (`best_` keys)."""
        return {f"best_{f}": getattr(self, f) for f in BEST_FIELDS}


INFO_FIELDS = ("theta", "P_c", "coverage_free_pct", "P_len", "path_length_m", "feasible", "R1", "map")
BEST_FIELDS = ("theta", "P_c", "P_len", "R1", "coverage_free_pct", "path_length_m")


PATH_SHARE_WARNED = 0.5
"""The best shape's path term (w2 P_len) above this share of its coverage term (w1 P_c): the path, not coverage,
ranks the shapes."""


LOW_COVERAGE_WARNED = 50.0
"""The best shape covering less of the floor than this (P_c, %): part of the floor is out of its reach."""


def swamped_warning(weights: Weights, p_c: float, p_len: float, path_term: str, map_name: str,
                    whose: str = "best") -> str | None:  # fmt: skip
    """One line when a shape's path term is over half its coverage term: on that floor the path, not coverage,
    ranks the shapes (`whose` R1: the best shape's, or the one `evaluate` scored), naming the option that fixes it."""
    coverage, path = weights.w1 * p_c, weights.w2 * p_len
    if path_term == "per_area" or path <= PATH_SHARE_WARNED * coverage:
        return None
    return (
        f"warning: on {map_name} the path term swamps coverage ({whose} R1 {coverage - path:.2f}: P_c {p_c:.1f} %, "
        f"the path term {path:.2f} against coverage's {coverage:.2f}): the floor is larger than the weights were "
        "meant for; --path-term per_area states w2 per 25 m^2 of free floor"
    )


def degenerate_warning(weights: Weights, p_c: float, p_len: float, path_term: str, map_name: str) -> str | None:
    """One line when the best shape's figures make the ranking mean little on a floor, naming what fixes it: its
    path term over half its coverage term (the path, not coverage, ranks the shapes), or its coverage under half
    the floor (the rest out of its reach); None otherwise."""
    if p_c <= 0:
        return f"warning: on {map_name} no shape covers any of the floor (best P_c 0 %): is it narrower than a block?"
    swamped = swamped_warning(weights, p_c, p_len, path_term, map_name)
    if swamped:
        return swamped
    if p_c < LOW_COVERAGE_WARNED:
        return (
            f"warning: on {map_name} the best shape covers {p_c:.1f} % of the floor: the rest is out of its reach "
            "(separate free areas, or passages narrower than the robot); --start-xy X Y starts on the area to "
            "clean, and `maps crop --rect X0 Y0 X1 Y1` cuts the map down to it"
        )
    return None
