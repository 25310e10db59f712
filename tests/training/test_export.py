"""An exported policy: plain files that hold numbers only, read back by torch and by NumPy to the same actions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from ray.rllib.core.columns import Columns

from smorphi_rl.env import MorphologyEnv
from smorphi_rl.numpy_policy import NumpyPolicy
from smorphi_rl.policy_file import PolicyFileError, read_policy
from smorphi_rl.training.checkpoints import MODULE_SUBDIR, build_module, find_checkpoint, load_module
from smorphi_rl.training.export import export_policy
from smorphi_rl.training.module import observation_tensors
from smorphi_rl.vector_env import stack_observations

FLOOR = {"maps": ["generate:mixed"], "observation": "floor", "moves": [1, 4, 16], "path_term": "per_area",
         "max_steps": 12}  # fmt: skip


def module_for(env: MorphologyEnv, frequencies: int = 0):
    torch.manual_seed(3)
    model = {"value_offset": 1.0, "value_scale": 2.0, "policy_angle_frequencies": frequencies,
             "env_config": env.config.to_dict(), "algorithm": "ppo"}  # fmt: skip
    module = build_module(env.observation_space, env.action_space, model)
    with torch.no_grad():  # the head starts near zero (gain 0.01): make its logits tell actions apart
        module._pi.head.weight.mul_(100.0)
    return module


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    env = MorphologyEnv(FLOOR)
    module = module_for(env)
    ckpt = tmp_path_factory.mktemp("ck") / "checkpoint_000000"
    module.save_to_path(str(ckpt / MODULE_SUBDIR))
    out = export_policy(ckpt, tmp_path_factory.mktemp("policy") / "designer", {"trained": {"env_steps": 0}})
    return env, module, out


def observations(env: MorphologyEnv, n: int = 24) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        obs, _ = env.reset(seed=i)
        for _ in range(int(rng.integers(0, 4))):
            obs = env.step(rng.integers(0, 7, size=3))[0]
        out.append(obs)
    return out


def test_numpy_logits_are_torch_logits(exported):
    env, module, out = exported
    policy = read_policy(out)
    net = NumpyPolicy(policy.weights, policy.action_nvec, 0, policy.observation_shapes)
    obs = observations(env)
    with torch.no_grad():
        want = module.forward_inference({Columns.OBS: observation_tensors(stack_observations(obs))})
    want = want[Columns.ACTION_DIST_INPUTS].numpy()
    got = np.stack([net.logits(o) for o in obs])
    assert np.allclose(got, want, atol=1e-5), np.abs(got - want).max()
    greedy = np.stack([want[:, 7 * h : 7 * h + 7].argmax(axis=1) for h in range(3)], axis=1)
    assert np.array_equal(net.act(obs), greedy)


def test_numpy_policy_with_angle_frequencies_matches_too(tmp_path):
    env = MorphologyEnv(FLOOR)
    module = module_for(env, frequencies=8)
    weights = {k: v.detach().numpy() for k, v in module.state_dict().items()}
    shapes = {k: tuple(s.shape) for k, s in env.observation_space.spaces.items()}
    net = NumpyPolicy(weights, [7, 7, 7], 8, shapes)
    obs = observations(env, 6)
    with torch.no_grad():
        want = module.forward_inference({Columns.OBS: observation_tensors(stack_observations(obs))})
    assert np.allclose(np.stack([net.logits(o) for o in obs]), want[Columns.ACTION_DIST_INPUTS].numpy(), atol=1e-5)


def test_the_exported_folder_loads_as_a_torch_module_with_every_weight(exported):
    _, module, out = exported
    assert find_checkpoint(out) == out
    loaded = load_module(out)
    for name, value in module.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], value), name
    meta = json.loads((out / "policy.json").read_text())
    assert meta["action_nvec"] == [7, 7, 7] and meta["observation"]["scale"] == [9]


def test_weights_that_hold_objects_are_refused(exported, tmp_path):
    _, _, out = exported
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "policy.json").write_text((out / "policy.json").read_text())
    np.savez(bad / "weights.npz", x=np.array([object()], dtype=object))
    with pytest.raises(PolicyFileError, match="not readable weights"):
        read_policy(bad)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda m: m | {"format": "other"}, "not a smorphi-rl policy description"),
    (lambda m: m | {"version": 2}, "this smorphi-rl reads version 1"),
    (lambda m: m | {"version": "1"}, "'version' must be the number 1, got '1'"),
    (lambda m: m | {"action_nvec": [7, 7]}, "three odd, positive move counts"),
    (lambda m: m | {"action_nvec": [-3, 5, 5]}, r"three odd, positive move counts \(at most 9\), got \[-3, 5, 5\]"),
    (lambda m: m | {"observation": {"map": [2, 64, 64]}}, "the map's and the angles' shapes"),
    (lambda m: m | {"observation": m["observation"] | {"angles": [True]}}, "the map's and the angles' shapes"),
    (lambda m: m | {"observation": m["observation"] | {"map": [4095, 4095, 4095]}},
     r"its observation holds 68,\d+,\d+,\d+ values, more than any env's \(1,052,672\)"),
    (lambda m: m | {"model_config": m["model_config"] | {"policy_angle_frequencies": 10**9}},
     r"'policy_angle_frequencies' must be an integer in 0..64, got 1000000000"),
    (lambda m: m | {"model_config": m["model_config"] | {"algorithm": "__import__('os')"}},
     "'algorithm' must be one of ppo, impala, appo"),
    (lambda m: m | {"observation": m["observation"] | {"angles": [4000]}},  # [100, 300]: 2.7 GB of first layer once
     r"its network reads 68,0\d\d values beside the map, more than any env's \(1,024\)"),
    (lambda m: m | {"observation": m["observation"] | {"map": [2]}},  # torch's loaders failed in a traceback
     r"its observation's 'map' must have the shape \[channels, height, width\], got \[2\]"),
    (lambda m: m | {"observation": m["observation"] | {"map": [2, 64, 64, 1]}}, r"'map' must have the shape"),
    (lambda m: m | {"observation": m["observation"] | {"angles": [3, 1]}},
     r"its observation's 'angles' must have the shape one length \(a vector\), got \[3, 1\]"),
])  # fmt: skip
def test_a_foreign_description_is_refused(exported, tmp_path, edit, message):
    _, _, out = exported
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "weights.npz").write_bytes((out / "weights.npz").read_bytes())
    (bad / "policy.json").write_text(json.dumps(edit(json.loads((out / "policy.json").read_text()))))
    with pytest.raises(PolicyFileError, match=message):
        read_policy(bad)


def test_a_description_nested_past_pythons_limit_is_refused(exported, tmp_path):
    _, _, out = exported
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "weights.npz").write_bytes((out / "weights.npz").read_bytes())
    (bad / "policy.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(PolicyFileError, match=r"not readable JSON \(RecursionError\)"):
        read_policy(bad)


def test_export_policy_writes_a_folder_once(exported, tmp_path, capsys):
    from smorphi_rl.cli import main

    _, _, out = exported
    checkpoint = json.loads((out / "policy.json").read_text())
    assert "model_config" in checkpoint
    ck = tmp_path / "ck"
    env = MorphologyEnv(FLOOR)
    module_for(env).save_to_path(str(ck / MODULE_SUBDIR))
    assert main(["export-policy", "--checkpoint", str(ck), "--out", str(tmp_path / "p"), "--command", "a b"]) == 0
    assert json.loads((tmp_path / "p" / "policy.json").read_text())["command"] == "a b"
    capsys.readouterr()
    assert main(["export-policy", "--checkpoint", str(ck), "--out", str(tmp_path / "p")]) == 1
    assert "is a folder that holds files already" in capsys.readouterr().err
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    assert main(["export-policy", "--checkpoint", str(ck), "--out", str(tmp_path / "dangling")]) == 1
    assert "dangling is a link to" in capsys.readouterr().err and not (tmp_path / "nowhere").exists()


def test_export_records_the_runs_env_steps_when_its_summary_names_the_checkpoint(tmp_path, capsys):
    """A designer a user trained and exported said "PPO on ..." where the shipped one says how long it trained."""
    from smorphi_rl.cli import main

    trial = tmp_path / "run" / "ppo-x_00000"
    env = MorphologyEnv(FLOOR)
    for name in ("checkpoint_000000", "checkpoint_000001"):
        module_for(env).save_to_path(str(trial / name / MODULE_SUBDIR))
    final = trial / "checkpoint_000001"
    summary = {"checkpoint": str(final), "env_steps": 12_345, "wall_s": 67.8}
    (tmp_path / "run" / "summary.json").write_text(json.dumps(summary))
    assert main(["export-policy", "--checkpoint", str(final), "--out", str(tmp_path / "final")]) == 0
    assert json.loads((tmp_path / "final" / "policy.json").read_text())["trained"] == {
        "env_steps": 12_345,
        "wall_s": 68,
    }
    assert main(["export-policy", "--checkpoint", str(trial / "checkpoint_000000"), "--out", str(tmp_path / "e")]) == 0
    assert "trained" not in json.loads((tmp_path / "e" / "policy.json").read_text())  # not the policy it ended on
    (tmp_path / "run" / "summary.json").write_text("[not a summary")
    assert main(["export-policy", "--checkpoint", str(final), "--out", str(tmp_path / "broken")]) == 0
    assert "trained" not in json.loads((tmp_path / "broken" / "policy.json").read_text())
    capsys.readouterr()


def test_export_records_the_kept_policys_steps_and_the_policy_a_fine_tune_started_from(tmp_path, capsys):
    """A run that ended on the policy of 2,000 steps it evaluated best exported as "12,000 env steps", and a designer
    fine-tuned on one 5 m floor said nothing of its start and warned of floors 5-5 m a side."""
    from smorphi_rl.cli import main
    from smorphi_rl.designer import load_designer

    designer = Path(__file__).resolve().parents[2] / "smorphi_rl" / "policies" / "designer"
    trial = tmp_path / "run" / "ppo-x_00000"
    env = MorphologyEnv(FLOOR | {"maps": [str(Path(__file__).resolve().parents[2] / "maps" / "map-2.yaml")]})
    module_for(env).save_to_path(str(trial / "checkpoint_000005" / MODULE_SUBDIR))
    summary = {"checkpoint": str(trial / "checkpoint_000005"), "env_steps": 12_000, "pretrained": str(designer),
               "evaluation": {"policy_env_steps": 2_000, "median_gap": 6.54}}  # fmt: skip
    (tmp_path / "run" / "summary.json").write_text(json.dumps(summary))
    assert main(["export-policy", "--checkpoint", str(trial / "checkpoint_000005"), "--out", str(tmp_path / "p")]) == 0
    trained = json.loads((tmp_path / "p" / "policy.json").read_text())["trained"]
    assert trained == {"env_steps": 2_000, "run_env_steps": 12_000, "pretrained": str(designer)}
    exported, shipped = load_designer(tmp_path / "p"), load_designer(designer)
    assert exported.trained_sides == shipped.trained_sides  # map-2's 5 m lie within the designer's floors
    assert exported.summary.endswith("on " + env.config.maps[0] + ", fine-tuned from designer")
    assert "PPO, 2,000 env steps" in exported.summary
    capsys.readouterr()


def test_a_plot_never_replaces_the_image_of_a_map_the_policy_rolls_out_on(tmp_path, capsys):
    """Without --map, the policy's own maps were not counted as inputs, and --force replaced the training map's image
    with the plot."""
    import shutil

    from smorphi_rl.cli import main

    root = Path(__file__).resolve().parents[2] / "maps" / "designer" / "held-out"
    for suffix in (".yaml", ".png"):
        shutil.copy(root / f"mixed-1000001{suffix}", tmp_path / f"mixed-1000001{suffix}")
    image = (tmp_path / "mixed-1000001.png").read_bytes()
    env = MorphologyEnv({**FLOOR, "maps": [str(tmp_path / "mixed-1000001.yaml")]})
    module_for(env).save_to_path(str(tmp_path / "ck" / MODULE_SUBDIR))
    argv = ["evaluate-policy", "--checkpoint", str(tmp_path / "ck"), "--episodes", "1"]
    assert main([*argv, "--plot", str(tmp_path / "mixed-1000001.png"), "--force"]) == 1
    assert "is one of this command's inputs" in capsys.readouterr().err
    assert (tmp_path / "mixed-1000001.png").read_bytes() == image


def _with_weights(out, folder, arrays: dict[str, np.ndarray]):
    folder.mkdir()
    (folder / "policy.json").write_text((out / "policy.json").read_text())
    np.savez_compressed(folder / "weights.npz", **arrays)
    return folder


def test_weights_that_unpack_to_more_than_a_policy_are_refused_before_unpacking(exported, tmp_path):
    """A few hundred KB of deflated zeros declaring 512 MB: refused from the archive's directory, never inflated."""
    _, _, out = exported
    bad = _with_weights(out, tmp_path / "bad", {"x": np.zeros(128 << 20, dtype=np.float32)})
    assert (bad / "weights.npz").stat().st_size < 2 << 20
    with pytest.raises(PolicyFileError, match=r"unpack to 536,871,\d+ bytes, more than a policy holds"):
        read_policy(bad)


def test_flattened_weights_are_refused_in_one_line_by_design(exported, tmp_path, capsys):
    """Every weight flattened to one dimension under its own name: `design` names the misfit (it was an IndexError)."""
    from smorphi_rl.cli import main

    _, _, out = exported
    flat = {k: v.reshape(-1) for k, v in read_policy(out).weights.items()}
    bad = _with_weights(out, tmp_path / "flat", flat)
    val_1 = str(Path(__file__).resolve().parents[2] / "maps" / "val-1.yaml")
    code = main(["design", "--map", val_1, "--policy", str(bad), "--budget", "20"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and f"{bad}: the policy's layers do not fit" in err[0]  # the folder named


def test_layers_wider_than_the_nets_are_refused_in_one_line_by_design(exported, tmp_path, capsys):
    """A first convolution of 50,000 channels (and a second that takes them) chained, in a 400 KB file: `design`
    took 1.1 GB to run it, and more with a larger picture (5,000 here)."""
    from smorphi_rl.cli import main

    _, _, out = exported
    weights = dict(read_policy(out).weights)
    c0, c1 = "_pi.cnn.0.weight", "_pi.cnn.2.weight"
    weights |= {c0: np.zeros((5000, *weights[c0].shape[1:]), np.float32), "_pi.cnn.0.bias": np.zeros(5000, np.float32),
                c1: np.zeros((weights[c1].shape[0], 5000, 3, 3), np.float32)}  # fmt: skip
    bad = _with_weights(out, tmp_path / "wide", weights)
    val_1 = str(Path(__file__).resolve().parents[2] / "maps" / "val-1.yaml")
    code = main(["design", "--map", val_1, "--policy", str(bad), "--budget", "20"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and f"{bad}: the policy's layers do not fit" in err[0]


def test_weights_too_large_for_float32_arithmetic_are_refused(exported, tmp_path):
    """Finite weights of 3e38 overflowed the forward pass and `design` printed a shape from it."""
    _, _, out = exported
    huge = {k: np.full_like(v, 3e38) for k, v in read_policy(out).weights.items()}
    bad = _with_weights(out, tmp_path / "huge", huge)
    with pytest.raises(PolicyFileError, match=r"holds values beyond 1e\+06"):
        read_policy(bad)


def test_a_source_whose_env_configuration_is_not_one_is_refused(exported, tmp_path, capsys):
    """A source whose env configuration is not one (maps: 5) exported with exit 0; evaluate-policy then refused it."""
    from smorphi_rl.cli import main

    _, _, out = exported
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "weights.npz").write_bytes((out / "weights.npz").read_bytes())
    doc = json.loads((out / "policy.json").read_text())
    doc["model_config"]["env_config"]["maps"] = 5
    (bad / "policy.json").write_text(json.dumps(doc))
    assert main(["export-policy", "--checkpoint", str(bad), "--out", str(tmp_path / "p")]) == 1
    assert f"{bad}: env_config 'maps': bad value 5" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()
    del doc["model_config"]["env_config"]  # a policy written before policies carried one: still exported
    (bad / "policy.json").write_text(json.dumps(doc))
    assert main(["export-policy", "--checkpoint", str(bad), "--out", str(tmp_path / "p")]) == 0
