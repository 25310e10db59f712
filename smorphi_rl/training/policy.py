"""Greedy roll-outs of a policy: the evaluation protocol's policy side (`evaluate-policy`, the periodic
evaluation during training, transfer, sweeps and the benchmarks all call `evaluate_policy`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import EnvConfig, RewardMode
from smorphi_rl.policy_file import layout_problem
from smorphi_rl.protocol import MapEvaluation, Optimum, Outcome, settled_theta
from smorphi_rl.score import Scored
from smorphi_rl.training.checkpoints import CheckpointError
from smorphi_rl.vector_env import stack_observations


@dataclass(frozen=True)
class Rollout:
    """One greedy episode: the start, the shape it settles on, and the best it visited."""

    start: dict[str, Any]
    settled: Scored
    best: dict[str, Any]
    final: dict[str, Any]
    steps: int
    episode_return: float
    thetas: list[tuple[float, float, float]]


def env_config_of(module: Any, maps: list[str] | None) -> EnvConfig:
    """The env the policy was trained for (carried in the checkpoint), on `maps` if given."""
    raw = (module.model_config or {}).get("env_config")
    if not raw:
        raise CheckpointError("the checkpoint carries no env configuration (not trained by smorphi-rl)")
    if not isinstance(raw, dict):
        raise CheckpointError(f"the checkpoint's env configuration is a {type(raw).__name__}, not a table")
    cfg = EnvConfig.recorded(dict(raw))
    if maps:
        cfg = replace(cfg, maps=EnvConfig.from_dict({"maps": maps}).maps)
    return cfg


def unseen_warning(trained: EnvConfig, given: EnvConfig) -> str | None:
    """A warning when a policy trained on map files alone is rolled out on a floor that is none of them (told by
    name: an exported policy's files may lie elsewhere now): it proposes what it learned for its own floors, and
    nothing measured says how near the best that lies here. None for a policy trained on generated floors: it is
    trained for floors it has not seen (`design` warns of one outside the sides of its floors)."""
    from pathlib import Path

    from smorphi_rl.map_sources import is_generator

    if any(is_generator(m) for m in trained.maps):
        return None
    own = [Path(m).stem for m in trained.map_files]
    unseen = [Path(m).stem for m in given.map_files if Path(m).stem not in own]
    if not unseen:
        return None
    return (f"warning: the policy was trained on {', '.join(own)} alone; {', '.join(unseen)} "
            f"{'is not one of them' if len(unseen) == 1 else 'are not among them'}: it walks to the shapes it learned "
            "there, however far from this floor's best (`design` proposes for floors it has not seen)")  # fmt: skip


def check_fits(module: Any, env: MorphologyEnv) -> None:
    """The policy's observation and action spaces must be the env's (its obs_size, layout and moves), else say so
    in one line: a policy of another layout fails inside torch, one of other moves walks the wrong hinge."""
    want = {k: tuple(s.shape) for k, s in module.observation_space.spaces.items()}
    have = {k: tuple(s.shape) for k, s in env.observation_space.spaces.items()}  # type: ignore[attr-defined]
    if want.get("map") != have.get("map"):
        raise CheckpointError(f"the policy expects map observations of shape {want.get('map')}, the env gives "
                              f"{have.get('map')}")  # fmt: skip
    moves, env_moves = [int(n) for n in module.action_space.nvec], [int(n) for n in env.action_space.nvec]  # type: ignore[attr-defined]
    problem = layout_problem(want, have, moves, env_moves)
    if problem:
        raise CheckpointError(problem)


def action_logits(module: Any, observations: list[dict[str, np.ndarray]]) -> torch.Tensor:
    """The policy's action logits for every observation, in one forward pass."""
    from ray.rllib.core.columns import Columns

    from smorphi_rl.training.module import observation_tensors

    batch = {Columns.OBS: observation_tensors(stack_observations(observations))}
    with torch.no_grad():
        return module.forward_inference(batch)[Columns.ACTION_DIST_INPUTS]


def greedy_actions(module: Any, observations: list[dict[str, np.ndarray]]) -> np.ndarray:
    """The most likely action of each hinge for every observation, in one forward pass (deterministic): the
    argmax of each hinge's logits, which is what the module's MultiCategorical gives `to_deterministic`."""
    logits = action_logits(module, observations)
    sizes = [int(n) for n in module.action_space.nvec]
    return torch.stack([part.argmax(dim=-1) for part in torch.split(logits, sizes, dim=-1)], dim=-1).numpy()


def greedy_action(module: Any, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The most likely action of each hinge for one observation."""
    return greedy_actions(module, [obs])[0]


def greedy_outcomes(module: Any, envs: list[Any], starts: np.ndarray) -> list[Outcome]:
    """One greedy episode per start, all stepped together (one forward pass a step for every live
    episode); `envs` are MorphologyEnvs of one map (or wrapped for recording), one per start."""
    observations = [env.reset(seed=0, options={"theta": tuple(float(t) for t in start)})[0]
                    for env, start in zip(envs, starts, strict=True)]  # fmt: skip
    histories = [[env.unwrapped.theta] for env in envs]
    seen = [{history[0]: 0} for history in histories]
    committed: list[tuple[float, float, float] | None] = [None] * len(envs)
    live = list(range(len(envs)))
    while live:
        actions = greedy_actions(module, [observations[i] for i in live])
        still = []
        for action, i in zip(actions, live, strict=True):
            observations[i], _, terminated, truncated, info = envs[i].step(action)
            theta = tuple(info["theta"])
            histories[i].append(theta)
            if terminated and envs[i].unwrapped.config.reward == RewardMode.COMMIT.value:
                committed[i] = theta
            if terminated or truncated:
                continue
            if theta in seen[i] and envs[i] is envs[i].unwrapped:
                repeat_cycle(histories[i], seen[i][theta], envs[i].config.max_steps)
                continue
            seen[i][theta] = len(histories[i]) - 1
            still.append(i)
        live = still
    outcomes = []
    for env, start, history, commit in zip(envs, starts, histories, committed, strict=True):
        theta = commit if commit is not None else settled_theta(history)
        scored = env.unwrapped.score(theta)
        outcomes.append(Outcome(tuple(float(t) for t in start), theta, float(scored.R1),  # type: ignore[arg-type]
                                float(scored.P_c), int(scored.P_len), len(set(history))))  # fmt: skip
    return outcomes


def repeat_cycle(history: list[Any], first: int, max_steps: int) -> None:
    """Extend a greedy roll-out whose last shape was also its shape at step `first` to its truncation.

    The observation is a function of the shape and the map alone, and the greedy policy is deterministic,
    so from a revisited shape the roll-out repeats the same cycle until `max_steps`: the rest of its
    history is known without stepping (a settled policy stops after its first step in place). Not used
    when the env records its episodes."""
    period = len(history) - 1 - first
    while len(history) < max_steps + 1:
        history.append(history[len(history) - period])


def evaluate_policy(
    module: Any, env_config: EnvConfig, starts: np.ndarray, optima: dict[str, Optimum], method: str = "policy",
    wrap: Any = None,
) -> list[MapEvaluation]:  # fmt: skip
    """The protocol on every map of `env_config`: greedy from each start, against that map's optimum
    (`optima` by map name). `wrap(env)`, if given, wraps each env (recording)."""
    return GreedyRollouts(env_config, starts, optima, method, wrap)(module)


class GreedyRollouts:
    """The protocol's greedy roll-outs, run again and again (training evaluates every few iterations): each map's
    envs are built once, so shapes scored by one evaluation are free for the next (the roll-outs of a settling
    policy revisit them). `wrap(env)`, if given, wraps each env (recording) and closes it after each run."""

    def __init__(
        self, env_config: EnvConfig, starts: np.ndarray, optima: dict[str, Optimum], method: str = "policy",
        wrap: Any = None,
    ) -> None:  # fmt: skip
        self.env_config, self.starts, self.optima, self.method, self.wrap = env_config, starts, optima, method, wrap
        self._envs: dict[str, list[MorphologyEnv]] = {}

    def _envs_on(self, path: str) -> list[MorphologyEnv]:
        if path not in self._envs:
            first = MorphologyEnv(replace(self.env_config, maps=(path,)).to_dict())
            self._envs[path] = [first] + [first.sibling() for _ in range(len(self.starts) - 1)]
        return self._envs[path]

    def __call__(self, module: Any) -> list[MapEvaluation]:
        evaluations = []
        for path in self.env_config.maps:
            envs = self._envs_on(path)
            wrapped = [self.wrap(e) for e in envs] if self.wrap is not None else envs
            try:
                outcomes = greedy_outcomes(module, wrapped, self.starts)
            finally:
                if self.wrap is not None:
                    for e in wrapped:
                        e.close()
            name = envs[0].grid_map.name
            evaluations.append(MapEvaluation(name, self.method, self.optima[name], tuple(outcomes)))
        return evaluations


def rollout(module: Any, env: Any, seed: int) -> Rollout:
    """One greedy episode from the env's seeded start (`env`: a MorphologyEnv, or one wrapped for recording)."""
    obs, info = env.reset(seed=seed)
    start, thetas, total = info, [info["theta"]], 0.0
    done = terminated = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(greedy_action(module, obs))
        thetas.append(info["theta"])
        total += reward
        done = terminated or truncated
    committed = terminated and env.unwrapped.config.reward == RewardMode.COMMIT.value
    settled = env.unwrapped.score(thetas[-1] if committed else settled_theta(thetas))  # the protocol's rule
    best = {k.removeprefix("best_"): v for k, v in info.items() if k.startswith("best_")}
    return Rollout(start, settled, best, info, len(thetas) - 1, total, thetas)


class DesignEvaluation:
    """The designer's figures on each evaluated map: `design.run_design` with the greedy policy and `budget`
    planner evaluations, its best shape's gap to the map's exact optimum in per cent of the optimum's R1. Each
    map's env is built once, so later evaluations reuse its plans."""

    def __init__(self, env_config: EnvConfig, optima: dict[str, Optimum], budget: int) -> None:
        self.env_config, self.optima, self.budget = env_config, optima, budget
        self._envs: dict[str, MorphologyEnv] = {}

    def gaps_pct(self, module: Any) -> dict[str, float]:
        """Every map's design gap (per cent of R1*), by map name."""
        from smorphi_rl.design import run_design

        def logits(observations: Any) -> np.ndarray:
            return action_logits(module, list(observations)).numpy()

        out = {}
        for path in self.env_config.maps:
            if path not in self._envs:
                self._envs[path] = MorphologyEnv(replace(self.env_config, maps=(path,), reward="paper").to_dict())
            env = self._envs[path]
            design = run_design(env, logits, self.budget)
            optimum = self.optima[env.grid_map.name]
            out[env.grid_map.name] = 100 * (optimum.R1 - design.best.R1) / abs(optimum.R1)
        return out

    def __call__(self, module: Any) -> dict[str, float]:
        """The design figures logged each evaluation (TensorBoard eval/design_...)."""
        gaps = np.array(list(self.gaps_pct(module).values()))
        return {"design_median_gap_pct": float(np.median(gaps)), "design_p90_gap_pct": float(np.percentile(gaps, 90)),
                "design_share_within_1pct": float(np.mean(gaps <= 1.0)), "design_budget": self.budget}  # fmt: skip
