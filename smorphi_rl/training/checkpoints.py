"""The one place that knows where RLlib puts things in a checkpoint, and how to load our module back
without running anything a checkpoint file says.

RLlib's checkpoints are pickles, and a pickle can name any callable to run while it loads. So nothing
here calls `pickle.load` or RLlib's own loaders: the module's two files are read by `SafeUnpickler`,
which admits an exact list of (module, name) pairs (numpy arrays and dtypes, gymnasium's spaces, numpy's
random generator state, an ordered dict) and refuses every other global, persistent id and extension
code; our module's class is read as a marker, never called. The module is then built by our own code
from the checked spaces and configuration, and the weights are checked against its parameters, name by
name and shape by shape, before they are set.
"""

from __future__ import annotations

import io
import json
import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from smorphi_rl.errors import SmorphiError
from smorphi_rl.inputs import check_not_special
from smorphi_rl.policy_file import (
    PolicyFile,
    PolicyFileError,
    action_problem,
    is_policy_dir,
    policy_problem,
    read_policy,
    weights_problem,
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
MAX_PICKLE_BYTES = 64 << 20
"""A module's files are a few hundred KB; anything larger is not one of ours (and is not read)."""


class CheckpointError(SmorphiError):
    """A path that holds no checkpoint of ours."""


def is_checkpoint(path: Path) -> bool:
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
        raise CheckpointError(f"{root}: not a directory (give a checkpoint, trial or run directory)")
    if is_policy_dir(root):
        return root
    try:
        found = checkpoints_under(root)
    except (OSError, RuntimeError) as exc:  # a symlink loop, an unreadable folder
        raise CheckpointError(f"{root}: cannot be searched for checkpoints ({exc})") from None
    if not found:
        raise CheckpointError(f"{root}: holds no RLlib checkpoint of ours (no {MODULE_SUBDIR.as_posix()} below it)")
    trials = sorted({_trial_of(p, root) for p in found}, key=lambda t: (t == root, str(t)))
    if len(trials) > 1:  # the newest of several trials would be a choice by clock, not by the user
        raise CheckpointError(f"{root}: holds the checkpoints of {len(trials)} trials (a sweep, or a job of several "
                              f"runs); give one trial's folder, such as {trials[0]}")  # fmt: skip
    return found[-1]


def _trial_of(checkpoint: Path, root: Path) -> Path:
    """The trial folder `checkpoint` belongs to: its nearest folder at or below `root` holding Tune's params.json
    (a resumed sweep's set-aside checkpoints belong to their trial); when none does, the folder holding it."""
    for folder in checkpoint.parents:
        if (folder / "params.json").is_file():
            return folder
        if folder == root:
            break
    return checkpoint.parent


class _ModuleClass:
    """What the checkpoint's reference to our module class reads as: a marker, not the class (so nothing in the
    file can construct a module with arguments of its own)."""


MODULE_CLASS = _ModuleClass()
SAFE_GLOBALS: dict[tuple[str, str], Any] = {}
"""Every (module, name) a checkpoint's pickles may name, and what it reads as; filled by `_safe_globals`."""


def _safe_globals() -> dict[tuple[str, str], Any]:
    """The exact pairs RLlib 2.60 writes for our module (numpy 1.x and 2.x spell the array helpers differently)."""
    if SAFE_GLOBALS:
        return SAFE_GLOBALS
    import collections

    import gymnasium.spaces as spaces
    from numpy.random import PCG64, SeedSequence

    from smorphi_rl import rllib_compat

    allowed: dict[tuple[str, str], Any] = {
        ("collections", "OrderedDict"): collections.OrderedDict,
        ("numpy", "dtype"): np.dtype,
        ("gymnasium.spaces.box", "Box"): _unbuilt(spaces.Box),
        ("gymnasium.spaces.dict", "Dict"): _unbuilt(spaces.Dict),
        ("gymnasium.spaces.multi_discrete", "MultiDiscrete"): _unbuilt(spaces.MultiDiscrete),
        ("smorphi_rl.training.module", "MorphologyModule"): MODULE_CLASS,
    }
    # numpy's own (private) helpers for arrays and Generators; the three classes they rebuild are only ever their
    # arguments, so the classes read as markers the helpers swap back (a pickle calling SeedSequence or ndarray
    # itself could ask for gigabytes).
    classes: tuple[type, ...] = (SeedSequence, PCG64, np.ndarray)
    markers: dict[_Marker, type] = {_Marker(cls): cls for cls in classes}
    for (module, name), helper in rllib_compat.numpy_unpickle_helpers().items():
        allowed[(module, name)] = _unmarking(helper, markers, empty_first=name == "_reconstruct")
    where: dict[type, str] = {SeedSequence: "numpy.random.bit_generator", PCG64: "numpy.random._pcg64",
                              np.ndarray: "numpy"}  # fmt: skip
    allowed |= {(where[cls], cls.__name__): marker for marker, cls in markers.items()}
    SAFE_GLOBALS.update(allowed)
    return SAFE_GLOBALS


class _Marker:
    """What a class that a pickle may only pass to numpy's helpers reads as: refused when the pickle calls it."""

    def __init__(self, cls: type) -> None:
        self.name = cls.__name__

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        raise Refused(f"it constructs a {self.name} itself, which a smorphi-rl checkpoint never does")


def _unmarking(helper: Any, markers: dict[_Marker, type], empty_first: bool = False) -> Any:
    """`helper`, called with each marker among its arguments replaced by its class; `empty_first`: numpy's
    `_reconstruct`, which its pickles call for an empty array whose state then holds the data (any other shape
    would be allocated before the file's data is seen)."""

    def call(*args: Any) -> Any:
        if empty_first and (len(args) < 2 or args[1] != (0,)):
            raise Refused("it makes an array of its own shape before its data, which numpy's pickles never do")
        return helper(*(markers.get(a, a) if isinstance(a, _Marker) else a for a in args))

    return call


MAX_SPACE_VALUES = 1 << 22
"""More values than any space of ours holds (the largest observation, 2 x 512 x 512, holds 524,288)."""


def _unbuilt(cls: type) -> type:
    """A stand-in for a gymnasium space class that a pickle can only rebuild the way pickle writes it: an empty
    instance whose state is then set. Never constructed with arguments of the file's own (`Box(0, 255, (30000,
    30000))` would fill gigabytes before any check could run), and its state is checked before gymnasium's
    `__setstate__` reads it (which, for a MultiDiscrete without `start`, allocates the state's shape)."""

    def __new__(stand_in: type, *args: Any, **kwargs: Any) -> Any:
        if args or kwargs:
            raise Refused(f"it constructs a {cls.__name__} with arguments, which a smorphi-rl checkpoint never does")
        space: Any = object.__new__(cls)

        def checked(state: Any) -> None:  # pickle looks `__setstate__` up on the instance: this one runs first
            del space.__dict__["__setstate__"]
            problem = _space_state_problem(state)
            if problem:
                raise Refused(f"its {cls.__name__} {problem}")
            cls.__setstate__(space, state)  # type: ignore[attr-defined]

        space.__dict__["__setstate__"] = checked
        return space

    return type(f"Unbuilt{cls.__name__}", (cls,), {"__new__": __new__})


def _space_state_problem(state: Any) -> str:
    """What is wrong with a space's pickled state (a dict whose shape is whole sizes of at most MAX_SPACE_VALUES
    values, whose dtype is numeric), or ''."""
    if not isinstance(state, dict):
        return "state is not a table"
    shape, dtype = state.get("_shape"), state.get("dtype")
    if shape is not None and not (isinstance(shape, tuple) and all(type(d) is int and d >= 0 for d in shape)):
        return f"shape {str(shape)[:40]} is not whole sizes"
    if shape is not None and math.prod(shape) > MAX_SPACE_VALUES:
        return f"shape {shape} holds more values than any space of ours ({MAX_SPACE_VALUES:,})"
    if dtype is not None and not (isinstance(dtype, np.dtype) and dtype.kind in "biuf"):
        return f"dtype {str(dtype)[:40]} is not numeric"
    return ""


class Refused(pickle.UnpicklingError):
    """A pickle that names something a smorphi-rl checkpoint never holds."""


class SafeUnpickler(pickle.Unpickler):
    """An unpickler that resolves only the exact pairs of `SAFE_GLOBALS` and nothing else."""

    def find_class(self, module: str, name: str) -> Any:
        found = _safe_globals().get((module, name))
        if found is None:
            raise Refused(f"it names {module}.{name}, which a smorphi-rl checkpoint never does")
        return found

    def persistent_load(self, pid: Any) -> Any:
        raise Refused("it holds a persistent reference, which a smorphi-rl checkpoint never does")


def safe_unpickle(path: Path) -> Any:
    """The object a checkpoint pickle holds, read by `SafeUnpickler`; refused in one line otherwise."""
    try:
        if path.is_symlink() or not path.is_file():
            raise CheckpointError(f"{path}: missing or not a plain file (a checkpoint's files are never links)")
        if path.stat().st_size > MAX_PICKLE_BYTES:
            raise CheckpointError(f"{path}: {path.stat().st_size:,} bytes, larger than any smorphi-rl policy "
                                  f"({MAX_PICKLE_BYTES:,} at most)")  # fmt: skip
        data = path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        nesting = _tuple_nesting_problem(data)
        if nesting:
            raise Refused(nesting)
        obj = SafeUnpickler(io.BytesIO(data)).load()
    except Refused as exc:
        raise CheckpointError(f"{path}: refused, {exc} (load only checkpoints written by smorphi-rl)") from None
    except Exception as exc:
        raise CheckpointError(f"{path}: not a readable checkpoint file ({type(exc).__name__})") from None
    problem = _shared_problem(obj, len(data))
    if problem:
        raise CheckpointError(f"{path}: refused, {problem} (load only checkpoints written by smorphi-rl)")
    return obj


MAX_TUPLE_NESTING = 16
"""Tuples within tuples a checkpoint's pickle may build: ours nest 3 deep (an array's state). Python hashes a tuple
key through every level, so a 300-byte pickle of 40 levels, each naming the one below twice, hashed for hours."""
_TUPLE_OPS = frozenset({"TUPLE", "TUPLE1", "TUPLE2", "TUPLE3", "FROZENSET"})
_MEMO_PUTS = frozenset({"PUT", "BINPUT", "LONG_BINPUT"})
_MEMO_GETS = frozenset({"GET", "BINGET", "LONG_BINGET"})


def _tuple_nesting_problem(data: bytes) -> str | None:
    """Why a pickle's tuples nest too deep (MAX_TUPLE_NESTING), found from its opcodes before anything is built, or
    None (also for a pickle the opcodes cannot be read from: the unpickler names that damage). Each stack item is
    followed by how deep its tuples nest, through the memo too."""
    import pickletools

    stack: list[int] = []
    marks: list[int] = []
    memo: dict[int, int] = {}
    try:
        for op, arg, _ in pickletools.genops(data):
            name = op.name
            if name == "MARK":
                marks.append(len(stack))
            elif name in _MEMO_PUTS or name == "MEMOIZE":
                memo[len(memo) if name == "MEMOIZE" else int(arg or 0)] = stack[-1] if stack else 0
            elif name in _MEMO_GETS:
                stack.append(memo.get(int(arg or 0), 0))
            elif name == "DUP":
                stack.append(stack[-1] if stack else 0)
            else:
                before = op.stack_before
                if pickletools.markobject in before:  # the items above the mark, and any below it the op takes
                    start = marks.pop() if marks else 0
                    popped, below = stack[start:], before.index(pickletools.markobject)
                    del stack[start:]
                else:
                    popped, below = [], len(before)
                if below:
                    popped += stack[-below:]
                    del stack[-below:]
                depth = 1 + max(popped, default=0) if name in _TUPLE_OPS else 0
                if depth > MAX_TUPLE_NESTING:
                    return f"its tuples nest over {MAX_TUPLE_NESTING} deep, which a smorphi-rl checkpoint's never do"
                stack.extend([depth] * len(op.stack_after))
    except (ValueError, IndexError):
        return None
    return None


MAX_PICKLE_NODES = 1_000_000
"""Values in an unpickled state: ours hold a few thousand (a module's weights about 50, a sweep's state 2,000)."""


def _shared_problem(obj: Any, file_bytes: int) -> str | None:
    """What makes `obj` far larger than its file, or None: a pickle may name one array or table many times (its
    memo), so 18 MB on disk read as 200,000 arrays of 16 MB, and every later check walked each of them. Ours
    share nothing: the arrays, counted each time they are named, hold about the file's bytes."""
    stack, nodes, array_bytes = [obj], 0, 0
    while stack:
        item = stack.pop()
        nodes += 1
        if nodes > MAX_PICKLE_NODES:
            return f"it holds over {MAX_PICKLE_NODES:,} values"
        if isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, list | tuple):
            stack.extend(item)
        elif isinstance(item, np.ndarray):
            array_bytes += item.nbytes
            if array_bytes > 2 * file_bytes + (1 << 20):
                return f"its arrays, counted where they are named, hold far more than its {file_bytes:,} bytes"
    return None


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
