"""Loading a checkpoint never runs code: every classic pickle payload, planted into a real RLlib checkpoint of our
module, is refused in one line by every loader, and its payload never runs."""

from __future__ import annotations

import collections
import json
import os
import pickle
import re
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from smorphi_rl.cli import main
from smorphi_rl.env import MorphologyEnv
from smorphi_rl.env_config import EnvConfig
from smorphi_rl.training.checkpoints import (
    MODULE_SUBDIR,
    CheckpointError,
    build_module,
    find_checkpoint,
    load_module,
    safe_unpickle,
)

STATE = "module_state.pkl"
ROOT = Path(__file__).resolve().parents[2]
MAP_1 = str(ROOT / "maps" / "map-1.yaml")


def write_checkpoint(path: Path) -> Path:
    """A checkpoint directory holding a real (untrained) MorphologyModule, written by RLlib's own save_to_path."""
    return written_checkpoint(path)[0]


def written_checkpoint(path: Path) -> tuple[Path, dict[str, np.ndarray]]:
    """`write_checkpoint`, with the weights of the module it saved (the truth a loader is held to)."""
    env_config = EnvConfig().to_dict()
    env = MorphologyEnv(env_config)
    model_config = {"value_offset": 0.0, "value_scale": 1.0, "policy_angle_frequencies": 0,
                    "env_config": env_config, "algorithm": "ppo"}  # fmt: skip
    module = build_module(env.observation_space, env.action_space, model_config)
    module.save_to_path(str(path / MODULE_SUBDIR))
    weights = {name: value.detach().numpy().copy() for name, value in module.state_dict().items()}
    (path / "rllib_checkpoint.json").write_text(json.dumps(
        {"class_and_ctor_args_file": "class_and_ctor_args.pkl", "state_file": "algorithm_state",
         "ray_version": "2.60.0", "checkpoint_version": "2.1"}))  # fmt: skip
    return path, weights


@pytest.fixture(scope="module")
def genuine(tmp_path_factory) -> Path:
    return write_checkpoint(tmp_path_factory.mktemp("genuine") / "checkpoint_000000")


class Reduce:
    """An object that pickles as `func(*args)`: the classic payload."""

    def __init__(self, func, *args) -> None:
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


def payloads(marker: Path) -> dict[str, tuple[str, bytes]]:
    """name -> (file to replace, the crafted bytes), each of which would create `marker` if it ran."""
    import builtins
    import subprocess

    code = f"open({str(marker)!r}, 'w').close()"
    state = {"_pi.head.bias": np.zeros(9, dtype=np.float32)}
    return {
        "exec": ("module_state.pkl", pickle.dumps(Reduce(builtins.exec, code))),
        "eval": ("module_state.pkl", pickle.dumps(Reduce(builtins.eval, code))),
        "os.system": ("module_state.pkl", pickle.dumps(Reduce(os.system, f"touch {marker}"))),
        "subprocess.Popen": ("module_state.pkl", pickle.dumps(Reduce(subprocess.Popen, ["touch", str(marker)]))),
        "torch.hub.load": ("module_state.pkl", pickle.dumps(Reduce(torch.hub.load, str(marker), "model"))),
        "nested __reduce__": ("module_state.pkl", pickle.dumps(state | {"x": [Reduce(os.system, f"touch {marker}")]})),
        "in class_and_ctor_args.pkl": (
            "class_and_ctor_args.pkl",
            pickle.dumps({"class": Reduce(builtins.exec, code), "ctor_args_and_kwargs": ((), {})}),
        ),
    }


def plant(genuine: Path, where: Path, file: str, data: bytes) -> Path:
    checkpoint = where / "checkpoint_000000"
    shutil.copytree(genuine, checkpoint)
    (checkpoint / MODULE_SUBDIR / file).write_bytes(data)
    return checkpoint


def read_planted(genuine: Path, where: Path, data: bytes) -> object:
    """`data` planted as a checkpoint's `class_and_ctor_args.pkl`, read back as every loader reads it."""
    return safe_unpickle(
        plant(genuine, where, "class_and_ctor_args.pkl", data) / MODULE_SUBDIR / "class_and_ctor_args.pkl"
    )


def spy_on_hub(monkeypatch) -> None:
    """torch.hub.load creates the marker if it is ever called (so the test needs no network to see it run)."""
    monkeypatch.setattr(torch.hub, "load", lambda repo, *a, **k: Path(repo).write_text("ran"))


def run(capsys, *argv: str) -> tuple[int, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:
        code = int(exc.code or 0)
    return code, capsys.readouterr().err


LOADERS = {
    "evaluate-policy": lambda ck, tmp: ["evaluate-policy", "--checkpoint", str(ck), "--episodes", "1"],
    "train --pretrained": lambda ck, tmp: ["train", "--pretrained", str(ck), "--log-dir", str(tmp / "logs")],
    "transfer": lambda ck, tmp: ["transfer", "--pretrained", str(ck), "--maps", MAP_1, "--log-dir", str(tmp / "logs")],
    "sweep with pretrained": lambda ck, tmp: ["sweep", str(sweep_file(tmp, ck)), "--log-dir", str(tmp / "logs")],
}


def sweep_file(tmp: Path, checkpoint: Path) -> Path:
    path = tmp / "sweep.yaml"
    path.write_text(f"algorithms: [ppo]\nmaps: [{MAP_1}]\nseeds: [0]\ntimesteps: 2000\npretrained: {checkpoint}\n")
    return path


def test_the_genuine_checkpoint_loads_with_its_weights(tmp_path):
    """The weights loaded are the module's that was saved, not only what the same reader reads again."""
    checkpoint, saved = written_checkpoint(tmp_path / "checkpoint_000000")
    module = load_module(checkpoint)
    state = safe_unpickle(checkpoint / MODULE_SUBDIR / "module_state.pkl")
    assert set(state) == set(module.state_dict()) == set(saved)
    for name, value in module.state_dict().items():
        assert np.array_equal(value.numpy(), saved[name]) and np.array_equal(state[name], saved[name]), name


@pytest.mark.parametrize("loader", list(LOADERS))
@pytest.mark.parametrize("payload", list(payloads(Path("m"))))
def test_every_loader_refuses_every_payload_and_nothing_runs(genuine, tmp_path, capsys, monkeypatch, loader, payload):
    marker = tmp_path / "ran"
    file, data = payloads(marker)[payload]
    spy_on_hub(monkeypatch)
    checkpoint = plant(genuine, tmp_path, file, data)
    code, err = run(capsys, *LOADERS[loader](checkpoint, tmp_path))
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1 and "Traceback" not in err, err
    assert "refused" in lines[0] or "not a smorphi-rl policy" in lines[0], lines[0]
    assert not marker.exists()
    assert not (tmp_path / "logs").exists() or not [p for p in (tmp_path / "logs").rglob("*") if p.is_file()]


@pytest.mark.parametrize(
    "call",
    [
        Reduce(gym.spaces.Box, 0.0, 255.0, (2, 2)),  # at (30000, 30000): 7 GB of bounds, filled before any check
        Reduce(gym.spaces.MultiDiscrete, [2, 2]),
        Reduce(gym.spaces.Dict, {}),
        Reduce(np.random.SeedSequence, 0, None, 8),  # at 10**9: a pool of 4 GB, mixed word by word
        Reduce(np.random.PCG64, 0),
    ],
    ids=["Box", "MultiDiscrete", "Dict", "SeedSequence", "PCG64"],
)
def test_an_allowed_class_called_with_arguments_of_the_files_own_is_refused(genuine, tmp_path, call):
    """The allowed classes are rebuilt only as pickle writes them (an empty instance, then its state): a file that
    calls one itself is refused before the call allocates anything."""
    with pytest.raises(CheckpointError, match="refused, it constructs"):
        read_planted(genuine, tmp_path, pickle.dumps({"class": call}))


def rebuilt(cls: type, state: dict) -> object:
    """A `cls` holding `state` alone, pickled as pickle writes a space: an empty instance, then its state set."""
    item = object.__new__(cls)
    item.__dict__.update(state)
    return item


@pytest.mark.parametrize(
    ("item", "message"),
    [
        (Reduce(np.ndarray, (3000, 3000), np.dtype("f8")), "it constructs a ndarray itself"),  # 72 MB
        (Reduce(np.zeros(0).__reduce__()[0], np.ndarray, (3000, 3000), b"b"), "an array of its own shape"),
        (rebuilt(gym.spaces.MultiDiscrete, {"_shape": (3000, 3000), "dtype": np.dtype(np.int64)}), "more values"),
        (rebuilt(gym.spaces.Box, {"_shape": (2,), "dtype": np.dtype("O")}), "of dtype object, not of numbers"),
    ],
    ids=["ndarray called", "an array made at its own shape", "a MultiDiscrete without start", "an object dtype"],
)
def test_what_numpy_and_gymnasium_would_allocate_for_a_file_is_refused_first(genuine, tmp_path, item, message):
    """A 92-byte file called ndarray with its own shape; a space's state without `start` has gymnasium's
    `__setstate__` allocate its shape; each is refused before memory is taken."""
    with pytest.raises(CheckpointError, match=message):
        read_planted(genuine, tmp_path, pickle.dumps({"class": item}))


class Built:
    """An object that pickles as `func(*args)`, then BUILD with `state`: what numpy's own pickles write."""

    def __init__(self, func, args, state) -> None:
        self.func, self.args, self.state = func, args, state

    def __reduce__(self):
        return self.func, self.args, self.state


def _numpy_helper(name: str):
    from numpy.random import _pickle as random_pickle

    core = getattr(np, "_core", None) or np.core
    helpers = {"_reconstruct": core.multiarray._reconstruct, "_frombuffer": core.numeric._frombuffer,
               "__generator_ctor": random_pickle.__generator_ctor}  # fmt: skip
    return helpers[name]


@pytest.mark.parametrize(
    ("item", "message"),
    [
        (Built(_numpy_helper("_reconstruct"), (np.ndarray, (0,), b"b"), (1, (100_000,), np.dtype("O"), False, [1.0])),
         "an array of dtype object, not of numbers"),  # numpy read 100,000 pointers past a list of one
        (Built(np.dtype, ("f8", False, True), (3, ">", None, None, None, -1, -1, 0)), "it changes a dtype"),
        (Built(np.dtype, ("O8", False, True), (3, "|", None, None, None, -1, -1, 0)), "of dtype object"),
        (Built(_numpy_helper("_reconstruct"), (np.ndarray, (0,), b"b"), (1, (4,), np.dtype("f8"), False, b"x" * 8)),
         "does not hold that shape's bytes"),
        (Reduce(_numpy_helper("_frombuffer"), b"x" * 8, np.dtype("f8"), (1000,), "C"),
         "does not hold that shape's bytes"),
        (rebuilt(gym.spaces.Box, {"_shape": (2,), "dtype": np.dtype("f4"), "low": np.zeros(10**6, np.float32)}),
         "its Box low is not an array of numbers of its shape (2,)"),  # gymnasium takes its min and max
        ([gym.spaces.Box(0, 1, (1,)) for _ in range(65)], "it holds over 64 spaces"),
    ],
    ids=["an object array over a list", "a dtype changed after it is made", "an object dtype", "short bytes",
         "short bytes from a buffer", "bounds of another shape", "too many spaces"],
)  # fmt: skip
def test_what_numpy_would_read_past_its_data_is_refused(genuine, tmp_path, item, message):
    """numpy's `__setstate__` trusts the state pickle hands it: an object dtype over the file's bytes, or over a
    shorter list, read memory the file chose (a crash, or worse); many spaces sharing one large bound took most of
    an hour to load."""
    with pytest.raises(CheckpointError, match=re.escape(message)):
        read_planted(genuine, tmp_path, pickle.dumps({"class": item}, protocol=4))


@pytest.mark.parametrize("metadata", ["rllib_checkpoint.json", f"{MODULE_SUBDIR.as_posix()}/metadata.json"])
def test_metadata_pointing_at_another_file_is_refused(genuine, tmp_path, capsys, metadata):
    marker = tmp_path / "ran"
    checkpoint = plant(genuine, tmp_path, "module_state.pkl", (genuine / MODULE_SUBDIR / STATE).read_bytes())
    (tmp_path / "evil.pkl").write_bytes(payloads(marker)["exec"][1])
    doc = json.loads((checkpoint / metadata).read_text())
    (checkpoint / metadata).write_text(json.dumps(doc | {"state_file": "../../../../../../evil"}))
    for loader in LOADERS.values():
        code, err = run(capsys, *loader(checkpoint, tmp_path))
        assert code == 1 and "names files other than RLlib's" in err and err.count("\n") == 1, err
    assert not marker.exists()


def test_a_linked_state_file_is_refused(genuine, tmp_path):
    checkpoint = plant(genuine, tmp_path, "module_state.pkl", b"")
    (checkpoint / MODULE_SUBDIR / "module_state.pkl").unlink()
    (checkpoint / MODULE_SUBDIR / "module_state.pkl").symlink_to(genuine / MODULE_SUBDIR / "module_state.pkl")
    with pytest.raises(CheckpointError, match=r"module_state\.pkl: a link, refused"):
        load_module(checkpoint)
    (checkpoint / MODULE_SUBDIR / "module_state.pkl").unlink()
    with pytest.raises(CheckpointError, match=r"module_state\.pkl: missing \(not a whole checkpoint"):
        load_module(checkpoint)
    (checkpoint / MODULE_SUBDIR / "module_state.pkl").mkdir()
    with pytest.raises(CheckpointError, match=r"module_state\.pkl: not a plain file"):
        load_module(checkpoint)


@pytest.mark.parametrize(
    ("again", "message"),
    [
        ({"_shape": (3,), "dtype": np.dtype("f4"), "low": np.zeros(10**6, np.float32)}, "its Box low is not an array"),
        ({"_shape": (3,), "dtype": np.dtype("f4")}, "it sets a space's state twice"),
    ],
    ids=["unchecked", "copied again and again"],
)
def test_a_space_built_twice_is_refused(genuine, tmp_path, again, message):
    """A pickle may BUILD one object many times: the second state reached gymnasium's `__setstate__` unchecked, and
    a space set 20,000 times with a 20,000-key state took 15 s."""
    box = pickle.dumps(gym.spaces.Box(0, 1, (3,), np.float32), protocol=3)[:-1]  # without its STOP
    data = box + pickle.dumps(again, protocol=3)[2:-1] + pickle.BUILD + pickle.STOP
    with pytest.raises(CheckpointError, match=re.escape(message)):
        read_planted(genuine, tmp_path, data)


@pytest.mark.parametrize(
    ("item", "message"),
    [
        (Reduce(_numpy_helper("__generator_ctor"), 12345, np.random.PCG64), "generator_ctor with arguments of its own"),
        ({"seed": 2**2000}, "a number of over 1024 bits"),  # numpy's seed words: a division per 32 bits, each whole
        ({i * (2**61 - 1) + 7: None for i in range(3)}, "it keys a table by int 2305843009213693958"),
        ({frozenset({2**61 + 6})}, "it keys a table by int"),
        (rebuilt(gym.spaces.Box, {"shape": (2**40,), "dtype": np.dtype("f4")}), "its Box state holds 'shape'"),
        (Reduce(collections.OrderedDict, [(2**61 + 6, None)]), "it fills an OrderedDict with arguments of its own"),
        (Reduce(_numpy_helper("_frombuffer"), b"", np.dtype("f4"), (2**1000,) * 8 + (0,), "C"), "not whole sizes"),
        (rebuilt(gym.spaces.Box, {"_shape": (1,) * 33 + (0,), "dtype": np.dtype("f4")}), "is not whole sizes"),
    ],
    ids=["a generator of the file's own seed", "a huge number", "keys that hash alike", "set members", "old keys",
         "an OrderedDict's own pairs", "a shape of huge sizes", "a shape of many sizes"],
)  # fmt: skip
def test_what_would_take_numpy_or_python_hours_is_refused(genuine, tmp_path, item, message):
    """A class passed on to `__generator_ctor` was called with the file's own seed (128 KB of it took 5 s, and the
    time grows with its square); 40,000 keys that hash alike took 8 s to add; gymnasium renames `shape` after the
    check has read `_shape`."""
    with pytest.raises(CheckpointError, match=re.escape(message)):
        read_planted(genuine, tmp_path, pickle.dumps({"class": item}, protocol=4))


def test_a_list_of_itself_is_counted_as_it_is_walked(genuine, tmp_path):
    """A 2 KB list holding itself 1,000 times took 7.9 GB to walk: its entries were counted when popped, not pushed."""
    import tracemalloc

    data = b"\x80\x04]q\x00(h\x00" + b"h\x00" * 100 + b"e."  # 800 MB of pointers before the fix
    path = plant(genuine, tmp_path, "class_and_ctor_args.pkl", data)
    tracemalloc.start()
    try:
        with pytest.raises(CheckpointError, match="it holds over 1,000,000 values"):
            safe_unpickle(path / MODULE_SUBDIR / "class_and_ctor_args.pkl")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50 << 20, f"{peak:,} bytes"


def test_memo_numbers_that_hash_alike_are_refused_before_loading(genuine, tmp_path):
    """Text PUT opcodes may file values under any number: 16,000 that hash alike took 2.8 s to file."""
    data = b"\x80\x02N" + b"".join(b"p%d\n" % (7 + i * (2**61 - 1)) for i in range(1, 4)) + b"."
    with pytest.raises(CheckpointError, match="it files a value under a number no pickle of ours reaches"):
        read_planted(genuine, tmp_path, data)


def test_a_linked_module_folder_is_refused(genuine, tmp_path):
    """A link among the checkpoint's folders had its module's files read from wherever it points."""
    checkpoint = tmp_path / "checkpoint_000000"
    shutil.copytree(genuine, checkpoint)
    learner = checkpoint / MODULE_SUBDIR.parts[0]
    shutil.move(learner, tmp_path / "elsewhere")
    learner.symlink_to(tmp_path / "elsewhere")
    with pytest.raises(CheckpointError, match="a link, refused"):
        load_module(checkpoint)


def test_a_run_folder_holding_a_linked_checkpoint_is_refused(genuine, tmp_path):
    """A run folder whose checkpoint is a link had the policy it points at loaded and reported as the run's own;
    the folder the user names may itself be a link."""
    from smorphi_rl.training.checkpoints import find_checkpoint

    run, elsewhere = tmp_path / "run", tmp_path / "elsewhere"
    shutil.copytree(genuine, elsewhere / "ppo-1" / "checkpoint_000001")
    (run / "ppo-1").mkdir(parents=True)
    (run / "ppo-1" / "checkpoint_000001").symlink_to(elsewhere / "ppo-1" / "checkpoint_000001")
    with pytest.raises(CheckpointError, match="ppo-1/checkpoint_000001: a link, refused"):
        find_checkpoint(run)
    (tmp_path / "named").symlink_to(elsewhere)
    assert find_checkpoint(tmp_path / "named") == tmp_path / "named" / "ppo-1" / "checkpoint_000001"


def test_an_exported_policy_whose_file_is_a_link_is_refused(tmp_path):
    from smorphi_rl.policy_file import POLICY_JSON, SHIPPED_DESIGNER, WEIGHTS_NPZ, PolicyFileError, read_policy

    for name in (POLICY_JSON, WEIGHTS_NPZ):
        folder = tmp_path / name.replace(".", "-")
        folder.mkdir()
        for other in (POLICY_JSON, WEIGHTS_NPZ):
            if other == name:
                (folder / other).symlink_to(SHIPPED_DESIGNER / other)
            else:
                shutil.copy(SHIPPED_DESIGNER / other, folder / other)
        with pytest.raises(PolicyFileError, match=f"{name}: a link, refused"):
            read_policy(folder)


def test_weights_of_another_layout_are_refused(genuine, tmp_path):
    state = dict(safe_unpickle(genuine / MODULE_SUBDIR / "module_state.pkl"))
    state["_pi.mlp.0.weight"] = np.zeros((128, 70), dtype=np.float32)
    checkpoint = plant(genuine, tmp_path, "module_state.pkl", pickle.dumps(state))
    with pytest.raises(CheckpointError, match=r"has shape \(128, 70\).*another observation layout"):
        load_module(checkpoint)
    del state["_pi.mlp.0.weight"]
    (checkpoint / MODULE_SUBDIR / "module_state.pkl").write_bytes(pickle.dumps(state))
    with pytest.raises(CheckpointError, match="another layout"):
        load_module(checkpoint)


@pytest.mark.parametrize("data", [b"", b"not a pickle", pickle.dumps([1, 2, 3])[:-3], pickle.dumps("a string")])
def test_damaged_state_files_say_so_in_one_line(genuine, tmp_path, data):
    checkpoint = plant(genuine, tmp_path, "module_state.pkl", data)
    with pytest.raises(CheckpointError, match=r"not a readable checkpoint file|not a table of float weights"):
        load_module(checkpoint)


def test_non_finite_weights_are_refused(genuine, tmp_path, capsys):
    """A diverged or damaged policy (NaN or infinite weights) is named, not rolled out or exported as a shape."""
    state = dict(safe_unpickle(genuine / MODULE_SUBDIR / "module_state.pkl"))
    name = next(k for k in sorted(state) if state[k].size)
    state[name] = np.full_like(state[name], np.nan)
    checkpoint = plant(genuine, tmp_path, "module_state.pkl", pickle.dumps(state))
    for argv in (["evaluate-policy", "--checkpoint", str(checkpoint), "--episodes", "1"],
                 ["export-policy", "--checkpoint", str(checkpoint), "--out", str(tmp_path / "out")]):  # fmt: skip
        code, err = run(capsys, *argv)
        assert code == 1 and len(err.strip().splitlines()) == 1 and f"weight {name} holds NaN" in err
    assert not (tmp_path / "out").exists()


def test_weights_named_many_times_in_their_pickle_are_refused_before_they_are_walked(genuine, tmp_path):
    """18 MB on disk named one 16 MB array 200,000 times: every check walked each, for 10 to 20 minutes."""
    shared = np.zeros(1 << 16, dtype=np.float32)
    checkpoint = plant(genuine, tmp_path, "module_state.pkl", pickle.dumps({f"w{i}": shared for i in range(100)}))
    with pytest.raises(CheckpointError, match=r"refused, its arrays, counted where they are named, hold far more"):
        load_module(checkpoint)


def _nested_tuple_key(depth: int, build_every: int = 0, head: bytes = b"") -> bytes:
    """A pickle of `{t: 1}`, t a tuple holding the one below twice, `depth` levels: about 7 bytes a level;
    `build_every` levels a `NONE BUILD` that leaves the tuple as it is; `head`: opcodes before it all."""
    out = bytearray(b"\x80\x02" + head + b")q\x00")  # PROTO 2, (head), EMPTY_TUPLE, BINPUT 0
    for level in range(1, depth + 1):  # BINGET twice, TUPLE2, (NONE BUILD), BINPUT
        out += b"h" + bytes([level - 1]) + b"h" + bytes([level - 1]) + b"\x86"
        out += b"Nb" if build_every and level % build_every == 0 else b""
        out += b"q" + bytes([level])
    return bytes(out + b"}h" + bytes([depth]) + b"K\x01s.")  # EMPTY_DICT, BINGET, BININT1 1, SETITEM, STOP


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (_nested_tuple_key(40), "its values nest over 16 deep"),
        (_nested_tuple_key(40, build_every=10), "its values nest over 16 deep"),  # BUILD kept its depth
        (_nested_tuple_key(40, head=b"I0x1\n0"), "not a readable checkpoint file \\(its opcodes cannot be read"),
    ],  # the unpickler reads 0x1, pickletools does not: the scan was skipped
    ids=["plain", "a BUILD every 10 levels", "an INT pickletools cannot read"],
)
def test_a_tuple_key_nested_too_deep_to_hash_is_refused_before_it_is_built(genuine, tmp_path, data, message):
    """Python hashes a tuple through every level, twice a level here: 300 bytes of 40 levels hashed for hours."""
    checkpoint = plant(genuine, tmp_path, "module_state.pkl", data)
    with pytest.raises(CheckpointError, match=message):
        load_module(checkpoint)
    assert pickle.loads(_nested_tuple_key(3, build_every=2))  # the same pickles, shallow, are a dict of a tuple key


def _wide_tuple_key(depth: int, fan_out: int) -> bytes:
    """A pickle of `{t: 0}`, t a tuple holding the one below `fan_out` times, `depth` levels (fan_out ** depth
    leaves in about 13 bytes a level; 4 x 15 levels: a billion)."""
    out = bytearray(b"\x80\x02}K\x01\x85q\x000")  # EMPTY_DICT, (1,) as memo 0, POP
    for level in range(1, depth):  # MARK, BINGET fan_out times, TUPLE, BINPUT, POP
        out += b"(" + (b"h" + bytes([level - 1])) * fan_out + b"tq" + bytes([level]) + b"0"
    return bytes(out + b"h" + bytes([depth - 1]) + b"K\x00s.")  # BINGET the top, BININT1 0, SETITEM, STOP


def test_a_refused_key_is_named_without_spelling_it_out(genuine, tmp_path):
    """The refusal of a tuple key spelt the whole tuple before cutting it to 40 characters: 210 bytes of a tuple
    sharing its parts held every loader for minutes (and gigabytes). The same pickle, shallow, is a dict."""
    with pytest.raises(CheckpointError, match="it keys a table by a tuple of 4 items"):
        read_planted(genuine, tmp_path, _wide_tuple_key(15, 4))
    assert len(str(next(iter(pickle.loads(_wide_tuple_key(3, 4)))))) > 40


def test_a_pickle_setting_the_state_of_what_it_names_is_refused_and_changes_nothing(genuine, tmp_path):
    """BUILD on a marker renamed it for every later load of the process (and its refusal then spelt the name)."""
    renamed = b"\x80\x02cnumpy\nndarray\n}X\x04\x00\x00\x00nameX\x03\x00\x00\x00XYZsb0N."
    with pytest.raises(CheckpointError, match="it sets the state of a class or function it names"):
        read_planted(genuine, tmp_path / "a", renamed)
    with pytest.raises(CheckpointError, match="it constructs a ndarray itself"):
        read_planted(genuine, tmp_path / "b", b"\x80\x02cnumpy\nndarray\n)R.")


def _ctor_with_model_config(genuine: Path, model_config: object) -> bytes:
    ctor = pickle.loads((genuine / MODULE_SUBDIR / "class_and_ctor_args.pkl").read_bytes())  # our own test file
    kwargs = dict(ctor["ctor_args_and_kwargs"][1]) | {"model_config": model_config}
    return pickle.dumps(ctor | {"ctor_args_and_kwargs": ((), kwargs)})


def _laughs(levels: int) -> list:
    """A list of 2^levels leaves in a few hundred bytes of pickle (each level holds the one below twice)."""
    item: list = []
    for _ in range(levels):
        item = [item, item]
    return item


def _cycle() -> list:
    item: list = []
    item.append(item)
    return item


@pytest.mark.parametrize("extra", [_laughs(40), _cycle(), {1: 2}, np.zeros(3), float("nan")],
                         ids=["shared references", "a cycle", "a non-string key", "an array", "NaN"])  # fmt: skip
def test_a_model_config_that_is_not_plain_data_is_refused(genuine, tmp_path, capsys, extra):
    """A model configuration whose pickle expands to 2^40 values, refers to itself or holds other than plain values
    is refused in one line by every reader: it once hung export-policy in json.dumps and left a half export."""
    model_config = {"value_offset": 0.0, "value_scale": 1.0, "env_config": {}, "extra": extra}
    checkpoint = plant(genuine, tmp_path, "class_and_ctor_args.pkl", _ctor_with_model_config(genuine, model_config))
    for argv in (["evaluate-policy", "--checkpoint", str(checkpoint), "--episodes", "1"],
                 ["export-policy", "--checkpoint", str(checkpoint), "--out", str(tmp_path / "out")]):  # fmt: skip
        code, err = run(capsys, *argv)
        assert code == 1 and len(err.strip().splitlines()) == 1
        assert "not a table of plain values" in err or "refused, it holds over 1,000,000 values" in err  # (as read)
    assert not (tmp_path / "out").exists()


def test_a_folder_of_several_trials_names_them_instead_of_choosing_by_clock(genuine, tmp_path):
    """A sweep's folder holds one trial's checkpoints per trial: the newest would be a choice by clock, so every
    loader asks for one trial's folder; a trial's own folder, with a resume's set-aside checkpoints, is one trial."""
    from smorphi_rl.training.checkpoints import find_checkpoint

    for trial in ("ppo-seed0_00000", "ppo-seed1_00001"):
        (tmp_path / trial).mkdir()
        (tmp_path / trial / "params.json").write_text("{}")
        shutil.copytree(genuine, tmp_path / trial / "checkpoint_000000")
    shutil.copytree(genuine, tmp_path / "ppo-seed0_00000" / "before-resume-1" / "checkpoint_000001")
    assert find_checkpoint(tmp_path / "ppo-seed0_00000").is_relative_to(tmp_path / "ppo-seed0_00000")
    with pytest.raises(CheckpointError, match=r"holds the checkpoints of 2 trials .* such as .*ppo-seed0_00000$"):
        find_checkpoint(tmp_path)
    shutil.copytree(genuine, tmp_path / "checkpoint_000009")  # one beside them, in no trial: never the hint
    with pytest.raises(CheckpointError, match=r"holds the checkpoints of 3 trials .* such as .*ppo-seed0_00000$"):
        find_checkpoint(tmp_path)


def _ctor_with(genuine: Path, **changes: object) -> bytes:
    ctor = pickle.loads((genuine / MODULE_SUBDIR / "class_and_ctor_args.pkl").read_bytes())  # our own test file
    kwargs = dict(ctor["ctor_args_and_kwargs"][1])
    for key, value in changes.items():
        kwargs[key] = value(kwargs[key]) if callable(value) else value
    return pickle.dumps(ctor | {"ctor_args_and_kwargs": ((), kwargs)})


def _with_shape(space: gym.spaces.Dict, shape: object) -> gym.spaces.Dict:
    box = space.spaces["angles"]
    box._shape = shape  # what a crafted file's state can set, with bounds of that shape where it is one
    if isinstance(shape, tuple) and all(isinstance(d, int) for d in shape):
        for key in ("low", "high", "bounded_below", "bounded_above"):
            setattr(box, key, np.resize(getattr(box, key), shape))
    return space


def _with_env(model_config: dict, **env: object) -> dict:
    return model_config | {"env_config": model_config["env_config"] | env}


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"observation_space": lambda s: _with_shape(s, ("3",))}, "refused, its Box shape ('3',) is not whole sizes"),
        ({"observation_space": lambda s: _with_shape(s, 3)}, "refused, its Box shape 3 is not whole sizes"),
        ({"observation_space": lambda s: _with_shape(s, (3, 1))}, "'angles' must have the shape one length"),
        ({"model_config": lambda m: m | {"env_config": "maps"}}, "env configuration is a str, not a table"),
        ({"model_config": lambda m: _with_env(m, observation="floor")}, "is not the env's"),
        ({"model_config": lambda m: _with_env(m, moves=[1, 2, 4])}, "the policy chooses among [3, 3, 3] moves"),
        ({"model_config": lambda m: _with_env(m, maps=["/usr/*/*.yaml"])}, "'/usr/*/*.yaml' is a glob or folder"),
        ({"action_space": gym.spaces.MultiDiscrete([4_000_001, 3, 3])}, "its action space must be three odd"),
        (
            {
                "observation_space": lambda s: _with_shape(s, (30_000,)),
                "model_config": lambda m: m | {"policy_angle_frequencies": 64},
            },
            "reads 3,870,002 values beside the map",
        ),
    ],
    ids=[
        "a shape of strings",
        "a shape that is a number",
        "angles of two dimensions",
        "env_config a string",
        "another layout",
        "other moves",
        "maps to search for",
        "a huge last layer",
        "a huge first layer",
    ],
)
def test_a_policy_at_odds_with_itself_is_refused_in_one_line(genuine, tmp_path, capsys, changes, message):
    """Spaces of the wrong types, an env configuration that is no table or builds an env of another observation or
    action layout: each once failed inside torch or Python, or (other moves) walked the hinges wrongly."""
    checkpoint = plant(genuine, tmp_path, "class_and_ctor_args.pkl", _ctor_with(genuine, **changes))
    code, err = run(capsys, "evaluate-policy", "--checkpoint", str(checkpoint), "--episodes", "1")
    assert code == 1 and len(err.strip().splitlines()) == 1 and message in err, err


def test_evaluate_policy_shows_a_maps_name_escaped(genuine, tmp_path, capsys):
    """A map file's name holding an escape sequence was printed as it was, in each episode's and protocol's line."""
    odd = tmp_path / "a\x1b[2Jb.yaml"
    odd.write_text(Path(MAP_1).read_text().replace("image: ", f"image: {Path(MAP_1).parent}/"))
    code = main(["evaluate-policy", "--checkpoint", str(genuine), "--episodes", "1", "--map", str(odd)])
    out = capsys.readouterr().out  # an episode's line (the protocol's, --starts, needs the exact optimum: seconds)
    assert code == 0 and "a\\x1b[2Jb" in out and "\x1b" not in out, out


@pytest.mark.parametrize("kept", ["policy.json", "weights.npz"])
def test_half_an_exported_policy_names_the_missing_file(tmp_path, kept):
    """It was taken for a folder holding no checkpoint at all."""
    (tmp_path / kept).write_bytes((ROOT / "smorphi_rl" / "policies" / "designer" / kept).read_bytes())
    other = "weights.npz" if kept == "policy.json" else "policy.json"
    with pytest.raises(CheckpointError, match=f"an exported policy's {kept} without its {other}"):
        find_checkpoint(tmp_path)


def test_a_path_beside_or_inside_a_checkpoint_names_the_folder_to_give(tmp_path):
    """`--checkpoint pol/policy.json` said only 'not a directory'; `--checkpoint ckpt/learner_group` said it held no
    learner_group below it."""

    (tmp_path / "ckpt" / MODULE_SUBDIR).mkdir(parents=True)
    with pytest.raises(CheckpointError, match=r"learner_group: a part of the checkpoint .*ckpt; give that folder$"):
        find_checkpoint(tmp_path / "ckpt" / "learner_group")
    (tmp_path / "pol").mkdir()
    (tmp_path / "pol" / "policy.json").write_text("{}")
    with pytest.raises(CheckpointError, match=r"or an exported policy's\): give the folder that holds it, .*pol$"):
        find_checkpoint(tmp_path / "pol" / "policy.json")
