"""The exact optimal policy of the morphology MDP on one map, by value iteration over the whole lattice.

Transitions are deterministic and every hinge moves by -1, 0 or +1 lattice steps, clipped to the box,
so the states one action can reach from s are exactly its 3 x 3 x 3 neighbourhood with the box's edge
repeated: one Bellman backup is a 3-D maximum filter. This is the ceiling of every learner for a
reward mode and discount: where greedy roll-outs of the *optimal* policy settle from the protocol's
starts. It needs R1 of every lattice point (the exhaustive search) and ignores truncation (the
infinite-horizon optimum, rolled out for `max_steps`).

`level` and `improvement` share one optimal policy when level has no move cost: with phi = R1 / sigma,
improvement's values are U - phi where U solves level's equation for the reward (1 - gamma) phi, a
positive rescaling.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy import ndimage

from smorphi_rl.env import peak_reward
from smorphi_rl.env_config import EnvConfig, RewardMode
from smorphi_rl.protocol import settled_theta

IDEAL_MODES = ("level", "improvement", "peak", "paper")
TOLERANCE = 1e-4
"""Stop when no value moves by more than this fraction of the reward's spread in one backup (the greedy
policy has long stopped changing by then)."""
MAX_SWEEPS = 20_000
_MOVES = np.array(list(itertools.product((-1, 0, 1), repeat=3)))
_NOT_SELF = np.ones((3, 3, 3), dtype=bool)
_NOT_SELF[1, 1, 1] = False


def move_values(
    r1: np.ndarray,
    mode: str,
    gamma: float,
    beta: float = EnvConfig.beta,
    move_cost: float = EnvConfig.move_cost,
) -> np.ndarray:
    """W[s'] = reward of arriving at s' + gamma V(s') (paper mode: for a move that changes the shape; level and
    peak: before the move cost), for R1 on the full (n, n, n) lattice; the optimal action from s moves to its
    best neighbour by W, a move that changes the shape paying `move_cost` (level, peak) and standing still
    paying `beta` (paper)."""
    if mode not in IDEAL_MODES:
        raise ValueError(f"no value iteration for reward mode '{mode}' (choose from {', '.join(IDEAL_MODES)})")
    if not 0 < gamma < 1:
        raise ValueError(f"value iteration needs a discount in (0, 1), got {gamma}")
    reward = r1.astype(np.float64)
    spread = max(float(reward.std()), 1e-9)
    if mode == RewardMode.PEAK:
        # the env's transform, with the whole lattice's figures rather than its 256-shape sample
        reward = peak_reward(reward, float(np.quantile(reward, 0.9)), spread)
    elif mode != RewardMode.PAPER:  # level and improvement: the same policy (module docstring); scale irrelevant
        reward = (reward - reward.mean()) / spread
    tol = TOLERANCE * max(float(np.ptp(reward)), 1e-9)
    values = np.full_like(reward, float(reward.max()) / (1 - gamma))  # from above: fewer sweeps
    for _ in range(MAX_SWEEPS):
        arrive = reward + gamma * values
        stay, move = stay_move_costs(mode, beta, move_cost)
        if stay or move:  # standing still (or pushing into the box's edge) and moving pay differently
            moved = ndimage.maximum_filter(arrive, footprint=_NOT_SELF, mode="constant", cval=-np.inf)
            new = np.maximum(moved - move, arrive - stay)
        else:
            new = ndimage.maximum_filter(arrive, size=3, mode="nearest")
        delta = float(np.abs(new - values).max())
        values = new
        if delta < tol:
            break
    return reward + gamma * values


def stay_move_costs(mode: str, beta: float, move_cost: float) -> tuple[float, float]:
    """What standing still and what a move that changes the shape cost on top of the arrival reward, by mode."""
    if mode == RewardMode.PAPER:
        return beta, 0.0
    return 0.0, (move_cost if mode in (RewardMode.LEVEL, RewardMode.PEAK) else 0.0)


def greedy_settled(
    w: np.ndarray, starts: np.ndarray, max_steps: int, stay: float = 0.0, move: float = 0.0
) -> list[tuple[int, int, int]]:
    """Lattice index each start settles on when the optimal policy for `w` is followed for `max_steps`
    (the protocol's settled shape: the one held most often over the last steps). `stay` and `move`
    (`stay_move_costs`) charge standing still and changing the shape."""
    top = w.shape[0] - 1
    settled = []
    for start in starts:
        s = np.asarray(start, dtype=int)
        history: list[tuple[float, float, float]] = []
        for _ in range(max_steps):
            cand = np.clip(s + _MOVES, 0, top)
            vals = w[cand[:, 0], cand[:, 1], cand[:, 2]].copy()
            same = (cand == s).all(axis=1)
            vals -= np.where(same, stay, move)
            s = cand[int(vals.argmax())]
            history.append((float(s[0]), float(s[1]), float(s[2])))
        i, j, k = settled_theta(history)
        settled.append((int(i), int(j), int(k)))
    return settled
