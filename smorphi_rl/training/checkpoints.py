"""The one place that knows where RLlib puts things in a checkpoint, and how to load our module back
without running anything a checkpoint file says.

RLlib's checkpoints are pickles, and a pickle can name any callable to run while it loads. So nothing
here calls `pickle.load` or RLlib's own loaders: the module's two files are read by `safe_pickle`, which
admits an exact list of (module, name) pairs and refuses every other global; our module's class is read
as a marker, never called. The module is then built by our own code
from the checked spaces and configuration, and the weights are checked against its parameters, name by
name and shape by shape, before they are set.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.inputs import check_not_special
from smorphi_rl.policy_file import (
    POLICY_JSON,
    WEIGHTS_NPZ,
    PolicyFile,
    PolicyFileError,
    action_problem,
    is_policy_dir,
    policy_problem,
    read_policy,
    weights_problem,
)
from smorphi_rl.training.safe_pickle import (  # re-exported: the loaders' one place for them
    MODULE_CLASS,
    CheckpointError,
    safe_unpickle,
)

MODULE_SUBDIR = Path("learner_group") / "learner" / "rl_module" / "default_policy"
"""Where a (new API stack) Algorithm checkpoint keeps the RLModule's state."""
CTOR_FILE = "class_and_ctor_args.pkl"
STATE_FILE = "module_state.pkl"
METADATA_FILE = "metadata.json"
ROOT_METADATA_FILE = "rllib_checkpoint.json"
TARGET_PREFIX = "_target_pi."
"""APPO's target policy network (`MorphologyModule.make_target_networks`)."""
STAGING_PREFIX = ".checkpoint-staging-"
"""A trial writes each checkpoint into such a folder in its own trial folder (so on the disk it names, never
$TMPDIR) before Tune copies it to `checkpoint_NNNNNN`; one a stopped or killed trial left is removed when the run
ends (`failures.fit`)."""


def is_checkpoint(path: Path) -> bool:
    """Whether `path` is an RLlib Algorithm checkpoint (it holds the RLModule's state folder)."""
    return (path / MODULE_SUBDIR).is_dir()


def checkpoints_under(path: Path) -> list[Path]:
    """Every checkpoint directory at or below `path`, oldest first (by modification time, then name)."""
    if is_checkpoint(path):
        return [path]
    found = [p for p in path.rglob("checkpoint_*") if p.is_dir() and is_checkpoint(p)]
    return sorted(found, key=lambda p: (p.stat().st_mtime, str(p)))


def find_checkpoint(path: str | Path) -> Path:
    """A checkpoint directory itself, or the newest one under a trial or run directory, or an exported policy's
    folder (`policy_file.py`: the shipped designer is one)."""
    root = Path(path)
    if not root.exists():
        raise CheckpointError(f"checkpoint not found: {root}")
    if not root.is_dir():
        folder = f": give the folder that holds it, {root.parent}" if root.name in (POLICY_JSON, WEIGHTS_NPZ) else ""
        raise CheckpointError(f"{root}: not a directory (give a checkpoint, trial or run folder, or an exported "
                              f"policy's){folder}")  # fmt: skip
    if is_policy_dir(root):
        return root
    half = [n for n in (POLICY_JSON, WEIGHTS_NPZ) if (root / n).is_file()]
    if half:  # one of an exported policy's two files: the other is missing, not a checkpoint
        other = WEIGHTS_NPZ if half == [POLICY_JSON] else POLICY_JSON
        raise CheckpointError(f"{root}: an exported policy's {half[0]} without its {other} (export-policy writes both)")
    try:
        found = checkpoints_under(root)
    except (OSError, RuntimeError) as exc:  # a symlink loop, an unreadable folder
        raise CheckpointError(f"{root}: cannot be searched for checkpoints ({exc})") from None
    if not found:
        inside = next((p for p in list(root.resolve().parents)[: len(MODULE_SUBDIR.parts)] if is_checkpoint(p)), None)
        if inside is not None:  # learner_group/..., a part of one checkpoint: the checkpoint is what loads
            raise CheckpointError(f"{root}: a part of the checkpoint {inside}; give that folder")
        raise CheckpointError(f"{root}: holds no RLlib checkpoint of ours (no {MODULE_SUBDIR.as_posix()} below it)")
    linked = next((q for p in found if (q := _link_below(p, root)) is not None), None)
    if linked is not None:  # its files would be read from wherever the link points, reported as this folder's
        raise CheckpointError(f"{linked}: a link, refused (a run's checkpoints and folders are never links)")
    trials = sorted({_trial_of(p, root) for p in found}, key=lambda t: (t == root, str(t)))
    if len(trials) > 1:  # the newest of several trials would be a choice by clock, not by the user
        raise CheckpointError(f"{root}: holds the checkpoints of {len(trials)} trials (a sweep, or a job of several "
                              f"runs); give one trial's folder, such as {trials[0]}")  # fmt: skip
    return found[-1]


def _link_below(path: Path, root: Path) -> Path | None:
    """The first link on the way up from `path` to `root` (the folder the user named, which may be one), or None."""
    for folder in (path, *path.parents):
        if folder == root:
            return None
        if folder.is_symlink():
            return folder
    return None


def _trial_of(checkpoint: Path, root: Path) -> Path:
    """The trial folder `checkpoint` belongs to: its nearest folder at or below `root` holding Tune's params.json
    (a resumed sweep's set-aside checkpoints belong to their trial); when none does, the folder holding it."""
    for folder in checkpoint.parents:
        if (folder / "params.json").is_file():
            return folder
        if folder == root:
            break
    return checkpoint.parent


def check_metadata(meta: Path, state_file: str) -> None:
    """RLlib's metadata files name the files to read: refuse one that points anywhere but the usual two (our
    loader reads only those; a file that says otherwise was not written by RLlib for us)."""
    if not meta.exists():
        return
    check_not_special(meta, "checkpoint metadata", CheckpointError)
    try:
        doc = json.loads(meta.read_text()) if meta.stat().st_size < 1 << 16 else None
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        doc = None
    want = {"class_and_ctor_args_file": CTOR_FILE, "state_file": state_file}
    if not isinstance(doc, dict):
        raise CheckpointError(f"{meta}: not RLlib's metadata (not a JSON object of at most 64 KB)")
    if any(doc.get(k, v) != v for k, v in want.items()):
        raise CheckpointError(f"{meta}: refused, it names files other than RLlib's {CTOR_FILE} and {state_file}")


def read_module_files(checkpoint: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(the module's constructor keywords, its weights as float arrays by parameter name), read safely and
    checked for the types our module writes."""
    folder = checkpoint / MODULE_SUBDIR
    parts = MODULE_SUBDIR.parts
    linked = next((p for i in range(len(parts)) if (p := checkpoint.joinpath(*parts[: i + 1])).is_symlink()), None)
    if linked is not None:  # its files would be read from wherever the link points
        raise CheckpointError(f"{linked}: a link, refused (a checkpoint's folders are never links)")
    check_metadata(checkpoint / ROOT_METADATA_FILE, "algorithm_state")
    check_metadata(folder / METADATA_FILE, STATE_FILE.removesuffix(".pkl"))
    ctor = safe_unpickle(folder / CTOR_FILE)
    if not (isinstance(ctor, dict) and ctor.get("class") is MODULE_CLASS):
        raise CheckpointError(f"{checkpoint}: not a smorphi-rl policy (its module class is not MorphologyModule)")
    args = ctor.get("ctor_args_and_kwargs")
    if not (isinstance(args, tuple) and len(args) == 2 and args[0] == () and isinstance(args[1], dict)):
        raise CheckpointError(f"{folder / CTOR_FILE}: not the constructor record RLlib writes")
    state = safe_unpickle(folder / STATE_FILE)
    if not isinstance(state, dict) or not all(
        isinstance(k, str) and isinstance(v, np.ndarray) and v.dtype.kind == "f" for k, v in state.items()
    ):
        raise CheckpointError(f"{folder / STATE_FILE}: not a table of float weights by parameter name")
    problem = weights_problem(state)
    if problem:
        raise CheckpointError(f"{folder / STATE_FILE}: {problem}")
    return args[1], state


def _plain_shape(space: Any) -> bool:
    """Whether a space read from a file has a shape of whole, non-negative sizes (its state is the file's)."""
    try:
        shape = space.shape
    except Exception:  # a property reading state the file left out
        return False
    return isinstance(shape, tuple) and all(type(d) is int and d >= 0 for d in shape)


def _checked_spaces(kwargs: dict[str, Any], where: Path) -> tuple[Any, Any, dict[str, Any]]:
    """(observation space, action space, model_config) of the constructor keywords, each of the kind ours is."""
    import gymnasium as gym

    obs, act, model = kwargs.get("observation_space"), kwargs.get("action_space"), kwargs.get("model_config")
    boxes = getattr(obs, "spaces", None) if isinstance(obs, gym.spaces.Dict) else None
    if not (isinstance(boxes, dict) and all(isinstance(s, gym.spaces.Box) and _plain_shape(s) for s in boxes.values())):
        raise CheckpointError(f"{where}: its observation space is not the env's (a Dict of Boxes)")
    nvec = getattr(act, "nvec", None)
    if not (isinstance(act, gym.spaces.MultiDiscrete) and _plain_shape(act) and isinstance(nvec, np.ndarray)
            and nvec.dtype.kind in "iu" and nvec.shape == act.shape):  # fmt: skip
        raise CheckpointError(f"{where}: its action space is not the env's (MultiDiscrete)")
    moves = action_problem(nvec.tolist())  # the last layer is sized by their sum: 4,000,001 took 7 GB
    if moves:
        raise CheckpointError(f"{where}: its action space {moves}")
    problem = policy_problem({k: list(s.shape or ()) for k, s in boxes.items()}, model)
    if problem or not isinstance(model, dict):
        raise CheckpointError(f"{where}: {problem}")
    return obs, act, model


def build_module(observation_space: Any, action_space: Any, model_config: dict[str, Any]) -> Any:
    """A fresh MorphologyModule (CPU, untrained) for these spaces and configuration."""
    from smorphi_rl.training.module import MorphologyModule

    return MorphologyModule(observation_space=observation_space, action_space=action_space,
                            inference_only=False, learner_only=False, model_config=model_config)  # fmt: skip


def set_weights(module: Any, state: dict[str, np.ndarray], where: Path | str) -> None:
    """Set `state` into `module` after checking it holds exactly the module's parameters and shapes (RLlib's
    own `set_state` ignores missing and extra names)."""
    import torch

    own = module.state_dict()
    if set(own) != set(state):
        missing, extra = sorted(set(own) - set(state)), sorted(set(state) - set(own))
        raise CheckpointError(f"{where}: its weights are of another layout (missing {missing[:2]}, extra "
                              f"{extra[:2]}); it was written by another version of smorphi-rl")  # fmt: skip
    for name, value in own.items():
        if tuple(value.shape) != tuple(state[name].shape):
            raise CheckpointError(f"{where}: weight {name} has shape {tuple(state[name].shape)}, the policy's is "
                                  f"{tuple(value.shape)} (another observation layout)")  # fmt: skip
    module.load_state_dict({k: torch.from_numpy(np.array(v, dtype=np.float32)) for k, v in state.items()})


def policy_spaces(policy: PolicyFile) -> tuple[Any, Any]:
    """The observation and action spaces an exported policy was trained on (the env's, from their shapes)."""
    import gymnasium as gym

    entries: dict[str, gym.Space[Any]] = {
        k: gym.spaces.Box(0, 255, shape, np.uint8) if k == "map" else gym.spaces.Box(0.0, 1.0, shape, np.float32)
        for k, shape in policy.observation_shapes.items()
    }
    return gym.spaces.Dict(entries), gym.spaces.MultiDiscrete(list(policy.action_nvec))


def load_module(checkpoint: Path) -> Any:
    """The trained MorphologyModule of a checkpoint (or of an exported policy's folder), on the CPU, ready for
    `forward_inference`; nothing the files say is run (module docstring)."""
    from smorphi_rl.quiet import quiet

    quiet()
    if is_policy_dir(checkpoint):
        try:
            policy = read_policy(checkpoint)
        except PolicyFileError as exc:
            raise CheckpointError(str(exc)) from None
        obs, act = policy_spaces(policy)
        module = build_module(obs, act, policy.model_config)
        set_weights(module, {k: v for k, v in policy.weights.items()}, checkpoint)
        return module
    kwargs, state = read_module_files(checkpoint)
    obs, act, model = _checked_spaces(kwargs, checkpoint)
    try:
        module = build_module(obs, act, model)
    except (TypeError, ValueError, KeyError) as exc:
        raise CheckpointError(f"{checkpoint}: its configuration builds no policy ({exc})") from None
    if any(k.startswith(TARGET_PREFIX) for k in state):  # APPO keeps a target copy of the policy net
        module.make_target_networks()
    set_weights(module, state, checkpoint)
    return module


def load_module_state(checkpoint: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The module weights of a checkpoint (read safely and checked by `load_module`) and its model configuration,
    for fine-tuning."""
    module = load_module(checkpoint)
    return {k: v.detach().numpy().copy() for k, v in module.state_dict().items()}, dict(module.model_config or {})
