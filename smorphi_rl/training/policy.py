"""`smorphi-rl evaluate-policy`: roll a trained policy out greedily and report where it settles."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from smorphi_rl.env import EnvConfig, MorphologyEnv
from smorphi_rl.training.checkpoints import CheckpointError

SETTLE_WINDOW = 20
"""The settled morphology is the one the policy holds most often over its last steps."""


@dataclass(frozen=True)
class Rollout:
    """One greedy episode: the start, the shape it settles on, and the best it visited."""

    start: dict[str, Any]
    settled: dict[str, Any]
    best: dict[str, Any]
    final: dict[str, Any]
    steps: int
    episode_return: float
    thetas: list[tuple[float, float, float]]


def env_config_of(module: Any, maps: list[str] | None) -> EnvConfig:
    """The env the policy was trained for (carried in the checkpoint), on `maps` if given."""
    raw = dict((module.model_config or {}).get("env_config") or {})
    if not raw:
        raise CheckpointError("the checkpoint carries no env configuration (not trained by smorphi-rl)")
    cfg = EnvConfig.from_dict(raw)
    if maps:
        cfg = replace(cfg, maps=EnvConfig.from_dict({"maps": maps}).maps)
    return cfg


def check_fits(module: Any, env: MorphologyEnv) -> None:
    """The policy's observation space must be the env's (same obs_size), else say so in one line."""
    want = module.observation_space["map"].shape
    have = env.observation_space["map"].shape
    if tuple(want) != tuple(have):
        raise CheckpointError(
            f"the policy expects map observations of shape {tuple(want)}, the env gives {tuple(have)}"
        )


def greedy_action(module: Any, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The most likely action of each hinge (deterministic)."""
    from ray.rllib.core.columns import Columns

    batch = {Columns.OBS: {k: torch.tensor(v).unsqueeze(0) for k, v in obs.items()}}
    with torch.no_grad():
        out = module.forward_inference(batch)
    dist = module.get_inference_action_dist_cls().from_logits(out[Columns.ACTION_DIST_INPUTS])
    return dist.to_deterministic().sample()[0].numpy()


def rollout(module: Any, env: Any, seed: int) -> Rollout:
    """One greedy episode from the env's seeded start (`env`: a MorphologyEnv, or one wrapped for recording)."""
    obs, info = env.reset(seed=seed)
    start, thetas, total = info, [info["theta"]], 0.0
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(greedy_action(module, obs))
        thetas.append(info["theta"])
        total += reward
        done = terminated or truncated
    tail = thetas[-SETTLE_WINDOW:]
    settled_theta = max(set(tail), key=lambda t: (tail.count(t), -tail[::-1].index(t)))
    settled = env.unwrapped.score(settled_theta)
    best = {k.removeprefix("best_"): v for k, v in info.items() if k.startswith("best_")}
    return Rollout(start, settled, best, info, len(thetas) - 1, total, thetas)
