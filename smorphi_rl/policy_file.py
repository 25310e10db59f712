"""A trained policy as two plain files that cannot run code when read: `policy.json` and `weights.npz`.

`weights.npz` holds the module's parameters as float32 arrays by name (read with `allow_pickle=False`, so a
crafted file can hold numbers only); `policy.json` holds what is needed to use them: the observation's
shapes, the action sizes, the module's configuration (with the env configuration it was trained for), and
where it came from (the command that trained it, its held-out figures). No Ray and no torch here: the
`design` command reads a policy with NumPy alone.
"""

from __future__ import annotations

import json
import math
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.env_config import MAX_MOVE_SIZES
from smorphi_rl.errors import SmorphiError
from smorphi_rl.inputs import MAX_TREE_NODES, is_finite_number, is_plain_tree

POLICY_JSON = "policy.json"
WEIGHTS_NPZ = "weights.npz"
FORMAT = "smorphi-rl policy"
VERSION = 1
MAX_JSON_BYTES = 1 << 20
MAX_WEIGHTS_BYTES = 64 << 20
SHIPPED_DESIGNER = Path(__file__).resolve().parent / "policies" / "designer"
"""The generalist designer shipped with the package (`smorphi-rl design` uses it by default)."""


class PolicyFileError(SmorphiError):
    """A folder that holds no readable smorphi-rl policy."""


LAYOUT_KEYS = ("format", "version", "observation", "action_nvec", "model_config")
"""The keys of policy.json that `write_policy` writes from the weights themselves; every other key is `about`."""


@dataclass(frozen=True)
class PolicyFile:
    """A policy read from disk: its description and its weights."""

    path: Path
    meta: dict[str, Any]
    weights: dict[str, np.ndarray]

    @property
    def about(self) -> dict[str, Any]:
        """What the description says of where the weights came from and what was measured of them (its checkpoint,
        command, env steps, the designer's `accepts` and `held_out`): all but the format and the nets' layout."""
        return {k: v for k, v in self.meta.items() if k not in LAYOUT_KEYS}

    @property
    def observation_shapes(self) -> dict[str, tuple[int, ...]]:
        return {k: tuple(v) for k, v in self.meta["observation"].items()}

    @property
    def action_nvec(self) -> tuple[int, ...]:
        return tuple(self.meta["action_nvec"])

    @property
    def model_config(self) -> dict[str, Any]:
        return dict(self.meta["model_config"])

    @property
    def env_config(self) -> dict[str, Any]:
        return dict(self.model_config.get("env_config") or {})


def is_policy_dir(path: Path) -> bool:
    """Whether `path` holds an exported policy (policy.json and weights.npz)."""
    return (path / POLICY_JSON).is_file() and (path / WEIGHTS_NPZ).is_file()


def write_policy(
    out_dir: Path, weights: dict[str, np.ndarray], observation: dict[str, tuple[int, ...]], action_nvec: list[int],
    model_config: dict[str, Any], about: dict[str, Any],
) -> Path:  # fmt: skip
    """Write `out_dir/weights.npz` and `out_dir/policy.json` (each to a temporary name, then renamed)."""
    import io

    from smorphi_rl.rundir import write_atomic

    buffer = io.BytesIO()
    arrays: dict[str, Any] = {k: np.asarray(v, dtype=np.float32) for k, v in weights.items()}
    np.savez_compressed(buffer, **arrays)  # float arrays: nothing is pickled
    meta = {"format": FORMAT, "version": VERSION, "observation": {k: list(v) for k, v in observation.items()},
            "action_nvec": [int(n) for n in action_nvec], "model_config": model_config, **about}  # fmt: skip
    text = json.dumps(meta, indent=2, default=_plain) + "\n"  # both made before either is written
    out_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(out_dir / WEIGHTS_NPZ, buffer.getvalue())
    write_atomic(out_dir / POLICY_JSON, text.encode())
    return out_dir


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON: {type(value).__name__}")


def read_policy(path: str | Path) -> PolicyFile:
    """The policy in folder `path`, checked: its description names our format and version, its weights are
    finite float arrays (nothing in either file can run code)."""
    folder = Path(path)
    if not folder.exists():
        raise PolicyFileError(f"{folder}: not found (give an exported policy's folder)")
    if folder.is_file():
        ours = folder.name in (POLICY_JSON, WEIGHTS_NPZ)
        inside = f"; give the folder that holds it, {folder.parent}" if ours else ""
        raise PolicyFileError(f"{folder}: a file, not a policy's folder ({POLICY_JSON} and {WEIGHTS_NPZ}){inside}")
    if not is_policy_dir(folder):
        levels = ("", "*/", "*/*/")  # a checkpoint, a trial, a run: not a walk of whatever folder was given
        trained = folder.is_dir() and any(next(folder.glob(f"{k}rllib_checkpoint.json"), None) for k in levels)
        export = f"`smorphi-rl export-policy --checkpoint {shlex.quote(str(folder))} --out DIR` writes one"
        hint = f"; it holds a training run's checkpoints: {export}" if trained else ""
        raise PolicyFileError(f"{folder}: holds no smorphi-rl policy ({POLICY_JSON} and {WEIGHTS_NPZ}){hint}")
    meta_file, weights_file = folder / POLICY_JSON, folder / WEIGHTS_NPZ
    for file, limit in ((meta_file, MAX_JSON_BYTES), (weights_file, MAX_WEIGHTS_BYTES)):
        if file.is_symlink():  # read from wherever it points, yet reported as this folder's policy
            raise PolicyFileError(f"{file}: a link, refused (export-policy writes both files in the folder)")
        if file.stat().st_size > limit:
            raise PolicyFileError(f"{file}: {file.stat().st_size:,} bytes, more than a policy holds ({limit:,})")
    try:
        meta = json.loads(meta_file.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:  # RecursionError: nested far too deep
        raise PolicyFileError(f"{meta_file}: not readable JSON ({type(exc).__name__})") from None
    _check_meta(meta, meta_file)
    _check_inflated_size(weights_file)
    try:
        with np.load(weights_file, allow_pickle=False) as npz:
            weights = {name: npz[name] for name in npz.files}
    except Exception as exc:  # a damaged or foreign archive, or one that holds objects
        raise PolicyFileError(f"{weights_file}: not readable weights ({type(exc).__name__}: {exc})") from None
    for name, value in weights.items():
        if not isinstance(value, np.ndarray):  # numpy hands an entry that is no .npy file over as its raw bytes
            raise PolicyFileError(f"{weights_file}: entry {name} is not an array")
        if value.dtype != np.float32:
            raise PolicyFileError(f"{weights_file}: weight {name} is not float32")
    problem = weights_problem(weights)
    if problem:
        raise PolicyFileError(f"{weights_file}: {problem}")
    return PolicyFile(folder, meta, weights)


def _check_inflated_size(weights_file: Path) -> None:
    """Refuse an archive whose entries declare more than MAX_WEIGHTS_BYTES unpacked, before any is inflated (a few
    MB of deflated zeros can declare gigabytes; zipfile never inflates past what an entry declares)."""
    import zipfile

    try:
        with zipfile.ZipFile(weights_file) as archive:
            declared = sum(info.file_size for info in archive.infolist())
    except (OSError, zipfile.BadZipFile, ValueError) as exc:
        raise PolicyFileError(f"{weights_file}: not readable weights ({type(exc).__name__}: {exc})") from None
    if declared > MAX_WEIGHTS_BYTES:
        raise PolicyFileError(f"{weights_file}: its arrays unpack to {declared:,} bytes, more than a policy holds "
                              f"({MAX_WEIGHTS_BYTES:,})")  # fmt: skip


def _check_meta(meta: Any, where: Path) -> None:
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise PolicyFileError(f"{where}: not a {FORMAT} description")
    version = meta.get("version")
    if type(version) is not int:
        raise PolicyFileError(f"{where}: 'version' must be the number {VERSION}, got {version!r}")
    if version != VERSION:
        raise PolicyFileError(f"{where}: version {version}; this smorphi-rl reads version {VERSION}")
    obs, nvec, model = meta.get("observation"), meta.get("action_nvec"), meta.get("model_config")
    shapes_ok = isinstance(obs, dict) and all(
        isinstance(s, list) and all(type(d) is int and 0 < d < 4096 for d in s) for s in obs.values()
    )
    if not shapes_ok or not isinstance(obs, dict) or "map" not in obs or "angles" not in obs:
        raise PolicyFileError(f"{where}: 'observation' must give the map's and the angles' shapes")
    problem = action_problem(nvec)
    if problem:
        raise PolicyFileError(f"{where}: 'action_nvec' {problem}")
    problem = policy_problem(obs, model)
    if problem or not isinstance(model, dict):
        raise PolicyFileError(f"{where}: {problem}")
    if not isinstance(model.get("env_config", {}), dict):
        raise PolicyFileError(f"{where}: 'model_config' must be a table holding 'env_config'")


MAX_OBSERVATION_VALUES = 4 * 512 * 512 + 4096
"""An env's observation: a map picture of at most 4 channels of 512 x 512 (obs_size's limit) and small vectors."""
MAX_SHAPE_INPUTS = 1024
"""Values a policy's network reads beside the map picture: an env's 3 angles in 64 frequencies (387) and its
metrics and scale, a dozen."""
MAX_FREQUENCIES = 64
"""Fourier frequencies of the angles a policy may see (the presets use 0 or 8)."""
MAX_WEIGHT = 1e6
"""A trained policy's weights are at most a few tens (the shipped designer's: 25); beyond this a forward pass
overflows float32."""


def layout_problem(observation: dict[str, tuple[int, ...]], env_observation: dict[str, tuple[int, ...]],
                   moves: list[int], env_moves: list[int]) -> str | None:  # fmt: skip
    """What keeps a policy of these observation shapes and moves a hinge from the env's, or None: a policy of another
    observation layout fails inside its first layer, one of other moves walks the wrong hinge."""
    if observation != env_observation:
        return f"the policy's observation {observation} is not the env's {env_observation} (another observation layout)"
    if moves != env_moves:
        return f"the policy chooses among {moves} moves a hinge, its env among {env_moves} (another action layout)"
    return None


def action_problem(nvec: Any) -> str | None:
    """What keeps `nvec` from being a policy's moves a hinge (three odd counts, at most an env's), or None: the
    policy's last layer is sized by their sum."""
    most = 2 * MAX_MOVE_SIZES + 1
    if isinstance(nvec, list) and len(nvec) == 3 and all(type(n) is int and 1 <= n <= most and n % 2 for n in nvec):
        return None
    return f"must be three odd, positive move counts (at most {most}), got {str(nvec)[:60]}"


def obs_size(observation: dict[str, list[int]]) -> int:
    """Values in an observation of these shapes."""
    return sum(math.prod(shape) for shape in observation.values())


def policy_problem(observation: dict[str, list[int]], model: Any) -> str | None:
    """What is wrong with a policy's observation shapes and model configuration (`model_config_problem`), or None;
    checked for checkpoints and policy files alike before a module is built."""
    for key, shape in observation.items():  # the network reads a picture and vectors: no other shape builds it
        dims = 3 if key == "map" else 1
        if len(shape) != dims:
            what = "[channels, height, width]" if dims == 3 else "one length (a vector)"
            return f"its observation's '{str(key)[:40]}' must have the shape {what}, got {list(shape)[:8]}"
    if obs_size(observation) > MAX_OBSERVATION_VALUES:
        return (
            f"its observation holds {obs_size(observation):,} values, more than any env's ({MAX_OBSERVATION_VALUES:,})"
        )
    problem = model_config_problem(model)
    if problem is None:  # the first layer's width, before a module is built: 30,000 angles x 129 took 2.7 GB
        from smorphi_rl.training.presets import ANGLE_FREQUENCIES  # the critic's

        angles = math.prod(observation.get("angles") or [1])
        frequencies = max(model.get("policy_angle_frequencies", 0), ANGLE_FREQUENCIES)
        width = angles * 2 * frequencies + obs_size(observation) - math.prod(observation.get("map") or [1])
        if width > MAX_SHAPE_INPUTS:
            return f"its network reads {width:,} values beside the map, more than any env's ({MAX_SHAPE_INPUTS:,})"
    return problem


def model_config_problem(model: Any) -> str | None:
    """What is wrong with a policy's model configuration (a checkpoint's or a policy file's), or None: plain data
    (bounded, so a crafted pickle of shared references or a cycle cannot blow it up), finite value scaling, a
    known algorithm, a bounded number of angle frequencies."""
    from smorphi_rl.training.presets import ALGORITHMS

    if not isinstance(model, dict) or not is_plain_tree(model):
        return f"'model_config' is not a table of plain values (strings, finite numbers, lists; at most " \
               f"{MAX_TREE_NODES:,})"  # fmt: skip
    for key in ("value_offset", "value_scale"):
        if not is_finite_number(model.get(key, 0.0)):
            return f"model_config '{key}' must be a finite number"
    if model.get("algorithm", ALGORITHMS[0]) not in ALGORITHMS:
        return (
            f"model_config 'algorithm' must be one of {', '.join(ALGORITHMS)}, got {str(model.get('algorithm'))[:40]!r}"
        )
    frequencies = model.get("policy_angle_frequencies", 0)
    if type(frequencies) is not int or not 0 <= frequencies <= MAX_FREQUENCIES:
        got = str(frequencies)[:40]
        return f"model_config 'policy_angle_frequencies' must be an integer in 0..{MAX_FREQUENCIES}, got {got}"
    return None


def weights_problem(weights: dict[str, np.ndarray]) -> str | None:
    """What is wrong with a policy's weights, or None: each finite and at most MAX_WEIGHT in size."""
    for name, value in weights.items():
        if not np.isfinite(value).all():
            return f"weight {name} holds NaN or infinite values (a diverged or damaged policy)"
        if value.size and float(np.abs(value).max()) > MAX_WEIGHT:
            return (
                f"weight {name} holds values beyond {MAX_WEIGHT:g} (no trained policy's are; a forward pass overflows)"
            )
    return None
