"""The shared RLModule: its forward passes and what lets it skip RLlib's train/eval switching."""

from __future__ import annotations

import numpy as np
import torch
from ray.rllib.core.columns import Columns
from torch import nn

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.training.module import MorphologyModule

MODE_DEPENDENT = (nn.modules.dropout._DropoutNd, nn.modules.batchnorm._NormBase)


def _module_and_batch() -> tuple[MorphologyModule, dict]:
    env = MorphologyEnv()
    module = MorphologyModule(observation_space=env.observation_space, action_space=env.action_space, model_config={})
    observations = [env.reset(seed=s)[0] for s in range(4)]
    batch = {Columns.OBS: {k: torch.from_numpy(np.stack([o[k] for o in observations])) for k in observations[0]}}
    return module, batch


def test_no_layer_behaves_differently_in_train_and_eval_mode():
    """forward_exploration/inference skip RLlib's eval() switch; that is only sound while no layer cares."""
    module, _ = _module_and_batch()
    assert not [m for m in module.modules() if isinstance(m, MODE_DEPENDENT)]


def test_sampling_passes_leave_the_mode_alone_and_match_the_plain_forward():
    module, batch = _module_and_batch()
    module.train()
    with torch.no_grad():
        plain = module._forward(batch)[Columns.ACTION_DIST_INPUTS]
    for forward in (module.forward_exploration, module.forward_inference):
        out = forward(batch)[Columns.ACTION_DIST_INPUTS]
        assert module.training and torch.equal(out, plain) and not out.requires_grad
