"""What the trial does to its env runners through RLlib's public runner group: copy the learner's policy into
them, reseed their envs, and digest the policy they hold (so a test can see the weights arrived)."""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

POLICY_PREFIX = "_pi."
"""The policy network's parameters (the value net is not used for sampling)."""


def policy_digest(state: dict[str, Any]) -> str:
    """A digest of the policy network's parameters in a module state dict."""
    h = hashlib.blake2b(digest_size=16)
    for key in sorted(k for k in state if k.startswith(POLICY_PREFIX)):
        h.update(key.encode())
        h.update(np.ascontiguousarray(np.asarray(state[key], dtype=np.float32)).tobytes())
    return h.hexdigest()


def push_module_to_runners(algorithm: Any) -> list[str]:
    """Copy the learner's module into every env runner that samples (the remote ones, or the trial's own when
    there are none), waiting for each; returns their policy digests."""
    state = algorithm.learner_group.get_state(components="learner/rl_module", inference_only=True)
    runner_state = state["learner"]  # {"rl_module": {module id: module state}}
    runners = algorithm.env_runner_group
    local = runners.num_remote_env_runners() == 0
    runners.foreach_env_runner(lambda r: r.set_state(runner_state), local_env_runner=local)
    return runners.foreach_env_runner(lambda r: policy_digest(r.module.get_state()), local_env_runner=local)


def reseed_runners(algorithm: Any, generation: int) -> None:
    """Give every sampling env its `generation` of independent streams (after a restore)."""
    runners = algorithm.env_runner_group
    local = runners.num_remote_env_runners() == 0

    def reseed(runner: Any) -> None:
        env: Any = getattr(runner.env, "unwrapped", None)
        if env is not None and hasattr(env, "reseed"):
            env.reseed(generation)

    runners.foreach_env_runner(reseed, local_env_runner=local)
