"""Fine-tuning from a pretrained checkpoint, with the weights provably in the env runners from the start.

RLlib's own weight sync after a restore is fire-and-forget; the notes saw it silently dropped in
2 of 3 runs, so the runners sampled with untrained weights. Here the restored module state is
pushed to every runner with a blocking call, and each runner's policy weights are digested and
reported in the first results (`smorphi_pretrained_in_runners`: 1.0 when every runner holds
exactly the checkpoint's policy). Used by `train --pretrained`, `transfer` and `sweep`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from smorphi_rl.training.callbacks import MorphologyCallbacks
from smorphi_rl.training.checkpoints import (
    TARGET_PREFIX,
    CheckpointError,
    find_checkpoint,
    load_module,
    load_module_state,
)
from smorphi_rl.training.runners import POLICY_PREFIX, policy_digest, push_module_to_runners

PRETRAINED_KEY = "smorphi_pretrained_in_runners"
VALUE_PREFIX = "_vf."
"""The critic's weights in a module state (`module.MorphologyModule._vf`)."""


def _layout(observation_space: Any, action_space: Any) -> dict[str, str]:
    """What a policy's input and output look like: each observation's shape and the action's choices."""
    layout = {f"observation '{k}'": str(tuple(v.shape)) for k, v in observation_space.spaces.items()}
    layout["actions"] = str([int(n) for n in getattr(action_space, "nvec", [])])
    return layout


def check_pretrained(checkpoint: Path, env_config: dict[str, Any]) -> str:
    """Before Ray starts: the checkpoint is ours and its observations fit the env; returns its policy digest."""
    from smorphi_rl.env import MorphologyEnv

    module = load_module(checkpoint)
    env = MorphologyEnv(env_config)
    want, have = _layout(module.observation_space, module.action_space), _layout(env.observation_space,
                                                                              env.action_space)  # fmt: skip
    if want != have:
        differ = sorted(k for k in set(want) | set(have) if want.get(k) != have.get(k))
        told = "; ".join(f"{k}: the policy's {want.get(k, 'none')}, the env's {have.get(k, 'none')}" for k in differ)
        raise CheckpointError(f"{checkpoint}: the pretrained policy does not fit this env ({told}); train with the "
                              "env options it was trained with (observation, moves, obs_size)")  # fmt: skip
    return policy_digest(module.get_state())


def set_learner_weights(algorithm: Any, state: dict[str, Any]) -> None:
    """Start the learner's module from `state` (weights read safely by `checkpoints.load_module_state`); a state
    without a target network starts APPO's target as a copy of the policy, as APPO builds it."""
    from ray.rllib.core import COMPONENT_LEARNER, COMPONENT_RL_MODULE, DEFAULT_MODULE_ID

    if not any(k.startswith(TARGET_PREFIX) for k in state):
        state = state | {
            TARGET_PREFIX + k[len(POLICY_PREFIX) :]: v for k, v in state.items() if k.startswith(POLICY_PREFIX)
        }
    algorithm.learner_group.set_state({COMPONENT_LEARNER: {COMPONENT_RL_MODULE: {DEFAULT_MODULE_ID: state}}})


def critic_renormalised(state: dict[str, Any], trained_with: dict[str, Any], now: dict[str, Any]) -> dict[str, Any]:
    """`state` with its critic's last layer re-expressed for this run's value normalisation: the critic outputs
    `value_offset + value_scale * head`, both set from the maps it trains on (`config.value_normalisation`), so
    the pretrained critic under the new run's offset and scale would predict other values; rescaled, it predicts
    on every observation what it did when pretrained."""
    old_offset, old_scale = float(trained_with.get("value_offset", 0.0)), float(trained_with.get("value_scale", 1.0))
    offset, scale = float(now["value_offset"]), float(now["value_scale"])  # every run sets both (config.py)
    weight, bias = state[VALUE_PREFIX + "head.weight"], state[VALUE_PREFIX + "head.bias"]
    return state | {
        VALUE_PREFIX + "head.weight": weight * (old_scale / scale),
        VALUE_PREFIX + "head.bias": (bias * old_scale + old_offset - offset) / scale,
    }


MAP_FIELDS = ("maps", "start_xy")
"""Env fields of a pretrained policy that belong to the floors it was trained on, so a run on other floors does not
take them."""


def pretrained_setup(pretrained: str | Path) -> tuple[str | None, dict[str, Any]]:
    """The algorithm and env configuration the policy `pretrained` names was trained with (its model config carries
    them; None and empty for one written before it did), less its floors and start point (`MAP_FIELDS`): `train
    --pretrained` and `transfer` start from them."""
    return model_setup(load_module(find_checkpoint(pretrained)).model_config)


def model_setup(model_config: dict[str, Any]) -> tuple[str | None, dict[str, Any]]:
    """`pretrained_setup` of a loaded policy's model config (only the env fields this version knows)."""
    from smorphi_rl.env_config import EnvConfig

    known = set(EnvConfig.__dataclass_fields__) - set(MAP_FIELDS)
    env = {k: v for k, v in dict(model_config.get("env_config") or {}).items() if k in known}
    return model_config.get("algorithm"), env


def fine_tune_from(pretrained: str | Path, env_config: dict[str, Any]) -> tuple[Path, type[MorphologyCallbacks]]:
    """The checkpoint `pretrained` names (a checkpoint, trial or run directory), checked against the env, and the
    callbacks that start training from it; a bad one fails here, before anything trains."""
    checkpoint = find_checkpoint(pretrained)
    return checkpoint, fine_tune_callbacks(checkpoint, check_pretrained(checkpoint, env_config))


def fine_tune_callbacks(checkpoint: Path, digest: str) -> type[MorphologyCallbacks]:
    """MorphologyCallbacks that start the algorithm from `checkpoint`'s policy and value networks."""

    class FineTuneCallbacks(MorphologyCallbacks):
        pretrained = str(checkpoint.resolve())
        expected = digest
        in_runners = float("nan")

        def on_algorithm_init(self, *, algorithm: Any, **kwargs: Any) -> None:
            super().on_algorithm_init(algorithm=algorithm, **kwargs)
            state, trained_with = load_module_state(Path(self.pretrained))
            now = dict(algorithm.config.rl_module_spec.model_config or {})
            set_learner_weights(algorithm, critic_renormalised(state, trained_with, now))
            digests = push_module_to_runners(algorithm)
            self.in_runners = float(bool(digests) and all(d == self.expected for d in digests))

        def on_train_result(self, *, algorithm: Any, result: dict[str, Any], **kwargs: Any) -> None:
            super().on_train_result(algorithm=algorithm, result=result, **kwargs)
            result[PRETRAINED_KEY] = self.in_runners

    return FineTuneCallbacks
