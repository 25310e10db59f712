"""The shared RLModule: its forward passes and what lets it skip RLlib's train/eval switching."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from ray.rllib.core.columns import Columns
from torch import nn

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.training.learners import CompactMaps
from smorphi_rl.training.module import INDEX, MorphologyModule, pack_maps, unpack_maps

MAPS = Path(__file__).resolve().parents[2] / "maps"
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
    """The learners may hand the module int64-packed maps (CompactMaps); both layouts must read the same."""
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


def _two_map_batch(rows: int = 200) -> dict:
    """A learner-sized batch over two maps (the index form needs at least MIN_GROUPED_ROWS rows)."""
    envs = [MorphologyEnv(maps=[m]) for m in (str(MAPS / "map-1.yaml"), str(MAPS / "map-2.yaml"))]
    observations = [envs[i % 2].reset(seed=i)[0] for i in range(rows)]
    return {Columns.OBS: {k: torch.from_numpy(np.stack([o[k] for o in observations])) for k in observations[0]}}


def test_compact_maps_hands_the_module_map_numbers_that_read_the_same():
    """With a module, CompactMaps turns the maps into each row's number in the module's table of distinct maps;
    forward passes, values and gradients are those of the plain batch."""
    module, _ = _module_and_batch()
    batch = _two_map_batch()
    maps = batch[Columns.OBS]["map"]
    compact = {Columns.OBS: dict(batch[Columns.OBS])}
    CompactMaps()(batch={"default_policy": compact}, rl_module={"default_policy": module}, episodes=[])
    numbers = compact[Columns.OBS]["map"]
    assert numbers.dtype == INDEX and numbers.shape == (200,) and numbers.tolist() == [0, 1] * 100
    with torch.no_grad():
        assert torch.allclose(module._forward(batch)[Columns.ACTION_DIST_INPUTS],
                              module._forward(compact)[Columns.ACTION_DIST_INPUTS])  # fmt: skip
        assert torch.allclose(module.compute_values(batch), module.compute_values(compact))
        assert torch.allclose(module.compute_values(batch)[1::2], module.compute_values({Columns.OBS: {
            k: v[1::2] for k, v in compact[Columns.OBS].items()}}))  # a minibatch of map 1 alone  # fmt: skip
    grads = []
    for b in (batch, compact):
        module.zero_grad()
        module.compute_values(b).sum().backward()
        grads.append(module._vf.cnn[0].weight.grad.clone())
    assert torch.allclose(grads[0], grads[1], atol=1e-5) and grads[0].abs().sum() > 0
    assert torch.equal(maps, batch[Columns.OBS]["map"])  # the plain batch is untouched


def test_the_map_table_numbers_maps_for_good_and_refuses_to_overflow():
    """Numbers never change (a batch queued for IMPALA's learner thread stays readable); past MAX_MAPS the batch
    keeps its maps; a module that never numbered a map says so."""
    module, _ = _module_and_batch()
    maps = _two_map_batch()[Columns.OBS]["map"]
    with pytest.raises(RuntimeError, match="holds no map table"):
        module._forward({Columns.OBS: dict(_two_map_batch()[Columns.OBS], map=torch.zeros(200, dtype=INDEX))})
    assert module.index_maps(maps[1::2].contiguous()).tolist() == [0] * 100  # map-2 first: number 0
    assert module.index_maps(maps).tolist() == [1, 0] * 100  # map-1 joins as 1, map-2 keeps 0
    table = module._pi.map_table
    table.MAX_MAPS = 2
    fresh = maps.clone()
    fresh[0, 0, 0, 0] ^= 1  # a third map
    assert module.index_maps(fresh) is None and module.index_maps(maps) is not None


def test_compact_maps_packs_words_without_a_module_or_for_a_small_batch():
    _, batch = _module_and_batch()
    maps = batch[Columns.OBS]["map"].clone()
    out = CompactMaps()(batch={"default_policy": {Columns.OBS: batch[Columns.OBS]}}, rl_module=None, episodes=[])
    packed = out["default_policy"][Columns.OBS]["map"]
    assert packed.dtype == torch.int64 and torch.equal(unpack_maps(packed, (2, 64, 64)), maps)


def test_kept_map_features_follow_the_map_and_the_weights():
    """Outside autograd one map's CNN features are kept; a new map or an optimiser step recomputes them."""
    module, batch = _module_and_batch()
    one = {Columns.OBS: {k: v[:1] for k, v in batch[Columns.OBS].items()}}
    other = {Columns.OBS: dict(one[Columns.OBS], map=_two_map_batch(2)[Columns.OBS]["map"][1:])}
    with torch.no_grad():
        first = module.forward_inference(one)[Columns.ACTION_DIST_INPUTS]
        assert torch.equal(module.forward_inference(one)[Columns.ACTION_DIST_INPUTS], first)
        assert not torch.equal(module.forward_inference(other)[Columns.ACTION_DIST_INPUTS], first)
        module._pi.map_fc[0].bias.add_(1.0)  # in place, as an optimiser step or a weight load
        moved = module.forward_inference(one)[Columns.ACTION_DIST_INPUTS]
    module._pi._kept = None
    with torch.no_grad():
        assert torch.equal(module.forward_inference(one)[Columns.ACTION_DIST_INPUTS], moved)
        assert not torch.equal(moved, first)


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


def test_a_broadcast_map_reads_as_its_stacked_copies():
    """The vector env hands one shared map as a read-only broadcast (stride 0): the module reads it as the same map
    in every row, without a warning or a copy of the batch, and gives the outputs of the stacked copies."""
    import warnings

    from smorphi_rl.training.module import distinct_rows, observation_tensors
    from smorphi_rl.vector_env import make_env

    venv = make_env({"num_envs": 6, "run_seed": 0})
    arrays, _ = venv.reset()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs = observation_tensors(arrays)
    assert obs["map"].stride(0) == 0 and obs["map"].data_ptr() == arrays["map"].ctypes.data
    first, rows = distinct_rows(obs["map"])  # type: ignore[misc]
    assert first.tolist() == [0] and rows.tolist() == [0] * 6
    copies = dict(obs, map=obs["map"].clone())
    assert copies["map"].stride(0) != 0
    module, _ = _module_and_batch()
    with torch.no_grad():
        assert torch.equal(module._forward({Columns.OBS: obs})[Columns.ACTION_DIST_INPUTS],
                           module._forward({Columns.OBS: copies})[Columns.ACTION_DIST_INPUTS])  # fmt: skip
        assert torch.equal(module.compute_values({Columns.OBS: obs}), module.compute_values({Columns.OBS: copies}))
