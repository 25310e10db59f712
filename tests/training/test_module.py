"""The shared RLModule: its forward passes and what lets it skip RLlib's train/eval switching."""

from __future__ import annotations

import numpy as np
import torch
from ray.rllib.core.columns import Columns
from torch import nn

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.training.learners import PackMaps
from smorphi_rl.training.module import MorphologyModule, pack_maps, unpack_maps

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


def test_packed_maps_give_the_same_outputs():
    """The learners hand the module int64-packed maps (PackMaps); both layouts must read the same."""
    module, batch = _module_and_batch()
    packed = {Columns.OBS: dict(batch[Columns.OBS], map=pack_maps(batch[Columns.OBS]["map"]))}
    assert packed[Columns.OBS]["map"].dtype == torch.int64
    assert packed[Columns.OBS]["map"].shape == (4, 2 * 64 * 64 // 8)
    with torch.no_grad():
        assert torch.equal(module._forward(batch)[Columns.ACTION_DIST_INPUTS],
                           module._forward(packed)[Columns.ACTION_DIST_INPUTS])  # fmt: skip
        assert torch.equal(module.compute_values(batch), module.compute_values(packed))


def test_pack_maps_leaves_what_it_cannot_pack():
    odd = torch.zeros(3, 1, 3, 3, dtype=torch.uint8)  # 9 bytes a row: not whole words
    floats = torch.zeros(3, 2, 4, 4)
    assert pack_maps(odd) is odd and pack_maps(floats) is floats


def test_pack_maps_connector_packs_every_module_batch():
    _, batch = _module_and_batch()
    maps = batch[Columns.OBS]["map"].clone()
    out = PackMaps()(batch={"default_policy": {Columns.OBS: batch[Columns.OBS]}}, rl_module=None, episodes=[])
    packed = out["default_policy"][Columns.OBS]["map"]
    assert packed.dtype == torch.int64 and torch.equal(unpack_maps(packed, (2, 64, 64)), maps)


def test_the_policy_sees_plain_angles_and_old_checkpoints_keep_their_layout():
    """The preset sets `policy_angle_frequencies` (PPO's fast: 0, the policy is smooth in the angles, the critic is
    not); a module built from a model_config without it has the layout of checkpoints written before it existed."""
    from smorphi_rl.training.config import TrainConfig, algorithm_config
    from smorphi_rl.training.module import ANGLE_FREQUENCIES, MAP_FEATURES

    env = MorphologyEnv()
    model_config = algorithm_config(TrainConfig()).rl_module_spec.model_config
    assert model_config["policy_angle_frequencies"] == 0  # the fast PPO preset's
    impala = algorithm_config(TrainConfig(algo="impala")).rl_module_spec.model_config
    assert impala["policy_angle_frequencies"] == ANGLE_FREQUENCIES
    new = MorphologyModule(observation_space=env.observation_space, action_space=env.action_space,
                           model_config=model_config)  # fmt: skip
    old, _ = _module_and_batch()
    width = lambda net, k: net.mlp[0].in_features == MAP_FEATURES + 3 * (1 + 2 * k) + 2  # noqa: E731
    assert width(new._pi, 0) and width(new._vf, ANGLE_FREQUENCIES)
    assert width(old._pi, ANGLE_FREQUENCIES) and width(old._vf, ANGLE_FREQUENCIES)
