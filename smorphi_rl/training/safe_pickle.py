"""Reading a checkpoint's pickles without running anything they say, and without letting a small file fill memory
or hang the reader.

A pickle can name any callable to run while it loads. `SafeUnpickler` admits an exact list of (module, name) pairs
(numpy arrays and dtypes, gymnasium's spaces, numpy's random generator state, an ordered dict) and refuses every
other global, persistent id and extension code; our module's class is read as a marker, never called. numpy's
dtypes and arrays are of numbers only and take only the states numpy writes (numpy trusts a state: an object array
over the file's bytes reads memory the file chose). Before it runs, a pickle whose values nest deeper than ours is
refused from its opcodes; after, one whose arrays, counted where they are named, hold far more than its file.
"""

from __future__ import annotations

import contextvars
import io
import math
import pickle
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from gymnasium.spaces import Space

from smorphi_rl import rllib_compat
from smorphi_rl.errors import SmorphiError

MAX_PICKLE_BYTES = 64 << 20
"""A module's files are a few hundred KB; anything larger is not one of ours (and is not read)."""


class CheckpointError(SmorphiError):
    """A path that holds no checkpoint of ours."""


class UnreadableCheckpoint(CheckpointError):
    """A checkpoint file that does not read as a pickle at all (cut short, damaged), as opposed to one read and
    refused for what it holds."""


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

    import gymnasium.spaces as spaces
    from numpy.random import PCG64, SeedSequence

    allowed: dict[tuple[str, str], Any] = {
        ("collections", "OrderedDict"): _empty_ordered_dict,
        ("numpy", "dtype"): _numeric_dtype,
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
        allowed[(module, name)] = _as_numpy_calls(name, helper, markers)
    where: dict[type, str] = {SeedSequence: "numpy.random.bit_generator", PCG64: "numpy.random._pcg64",
                              np.ndarray: "numpy"}  # fmt: skip
    allowed |= {(where[cls], cls.__name__): marker for marker, cls in markers.items()}
    SAFE_GLOBALS.update(allowed)
    return SAFE_GLOBALS


def _empty_ordered_dict(*args: Any, **kwargs: Any) -> Any:
    """What the pickle's `collections.OrderedDict` reads as: an empty one, filled by SETITEMS as pickle writes it
    (whose keys are checked); given pairs of its own, its keys would go unchecked (keys that hash alike)."""
    import collections

    if args or kwargs:
        raise Refused("it fills an OrderedDict with arguments of its own, which a smorphi-rl checkpoint never does")
    return collections.OrderedDict()


def shown(value: Any, typed: bool = False) -> str:
    """A refused value as its refusal shows it: its first 40 characters where it is a plain value or a short tuple
    of them (after its type's name, `typed`), else its type and length. `str` of a tuple nested 15 deep, each level
    sharing the one below four times, spells a billion leaves (210 bytes of pickle); of a 5,000-digit int, fails."""

    def plain(v: Any) -> bool:
        return (v is None or type(v) in (bool, float) or (type(v) is int and abs(v) < 1 << 64)
                or (type(v) is str and len(v) <= 40) or (isinstance(v, np.dtype) and v.fields is None))  # fmt: skip

    if plain(value) or (type(value) in (tuple, list) and len(value) <= 8 and all(plain(v) for v in value)):
        return f"{type(value).__name__} {str(value)[:40]}" if typed else str(value)[:40]
    if type(value) is int:
        return f"an int of {value.bit_length():,} bits"
    if isinstance(value, tuple | list | dict | set | frozenset | str | bytes | bytearray):
        return f"a {type(value).__name__} of {len(value):,} items"
    return f"a {type(value).__name__}"


def _numbers(dtype: Any) -> bool:
    """Whether `dtype` is a plain number's or boolean's (no objects, records or sub-arrays)."""
    return isinstance(dtype, np.dtype) and dtype.kind in "biuf" and dtype.fields is None and not dtype.subdtype


def _dtype_problem(dtype: Any) -> str:
    """Why `dtype` is not one an array of ours holds (a plain number or boolean), or ''. An object dtype's array
    holds pointers: one built from a file's bytes is memory the file chose."""
    if not _numbers(dtype):
        return f"it holds an array of dtype {shown(dtype)}, not of numbers, which a smorphi-rl checkpoint never does"
    return ""


def _numeric_dtype(code: Any, align: Any = False, copy: Any = False) -> np.dtype:
    """What the pickle's `numpy.dtype` reads as: a dtype of numbers or booleans from its code ('<f4'), else refused."""
    dtype = np.dtype(code, align=bool(align), copy=bool(copy)) if isinstance(code, str) and len(code) < 8 else None
    problem = _dtype_problem(dtype)
    if problem or dtype is None:
        raise Refused(problem)
    return dtype


def _whole_sizes(shape: Any) -> bool:
    """Whether `shape` is a shape numpy could hold: at most 32 whole sizes, each under 2^31 (their product is then
    cheap; 8,000 sizes of 1,024 bits each took 25 s to multiply)."""
    return (isinstance(shape, tuple) and len(shape) <= MAX_DIMENSIONS
            and all(type(d) is int and 0 <= d < 1 << 31 for d in shape))  # fmt: skip


def _bytes_problem(data: Any, dtype: np.dtype, shape: Any) -> str:
    """Why `data` is not the bytes of an array of `shape` and `dtype`, or ''."""
    if not _whole_sizes(shape):
        return f"it gives an array the shape {shown(shape)}, not whole sizes"
    if not isinstance(data, bytes | bytearray) or len(data) != math.prod(shape) * dtype.itemsize:
        return f"its array of shape {shape} does not hold that shape's bytes"
    return ""


def _build_problem(inst: Any, state: Any) -> str:
    """Why pickle's BUILD may not hand `state` to `inst` (numpy's `__setstate__` trusts it: a dtype's flags or an
    array's data that disagree with its shape reach memory outside the file), or ''."""
    if isinstance(inst, np.dtype):  # numpy's pickles restate the dtype as it was built: nothing to change
        plain = isinstance(state, tuple) and all(type(v) in (int, str, type(None)) for v in state)
        return "" if plain and state == inst.__reduce__()[2] else "it changes a dtype after making it"
    if isinstance(inst, Space):  # each time: a second BUILD would reach gymnasium's `__setstate__` unchecked
        problem = _space_state_problem(state)
        return problem and f"its {type(inst).__name__} {problem}"
    if isinstance(inst, np.ndarray):  # (version, shape, dtype, fortran order, bytes), as `ndarray.__reduce__`
        if not (isinstance(state, tuple) and len(state) == 5 and type(state[3]) is bool):
            return "it gives an array a state numpy does not write"
        return _dtype_problem(state[2]) or _bytes_problem(state[4], state[2], state[1])
    return ""


class _Marker:
    """What a class that a pickle may only pass to numpy's helpers reads as: refused when the pickle calls it."""

    def __init__(self, cls: type) -> None:
        self.name = cls.__name__

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        raise Refused(f"it constructs a {self.name} itself, which a smorphi-rl checkpoint never does")


def _as_numpy_calls(name: str, helper: Any, markers: dict[_Marker, type]) -> Any:
    """numpy's pickling `helper`, called only as numpy's own pickles call it (`_helper_problem`), with a marker as
    its first argument swapped for its class: passed on as an argument, a class is a constructor the file would
    call with values of its own (`__generator_ctor(huge seed, PCG64)` ran for hours)."""
    named = {cls.__name__: marker for marker, cls in markers.items()}

    def call(*args: Any) -> Any:
        problem = _helper_problem(name, args, named)
        if problem:
            raise Refused(problem)
        first = markers[args[0]] if isinstance(args[0], _Marker) else args[0]
        return helper(first, *args[1:])

    return call


def _helper_problem(name: str, args: tuple[Any, ...], named: dict[str, _Marker]) -> str:
    """Why `args` are not what numpy's pickles pass its helper `name`, or ''."""
    from numpy.random import BitGenerator

    unlike = f"it calls numpy's {name.strip('_')} with arguments of its own, as numpy's pickles never do"
    if not args or any(isinstance(a, _Marker) for a in args[1:]):
        return unlike
    if name == "_reconstruct":  # an empty array, its data set by BUILD (another shape is allocated unseen)
        code_ok = len(args) == 3 and isinstance(args[2], bytes | str) and len(args[2]) < 8
        ok = code_ok and args[0] is named["ndarray"] and args[1] == (0,)
        return "" if ok else "it makes an array of its own shape before its data, which numpy's pickles never do"
    if name == "_frombuffer":
        if len(args) != 4 or args[3] not in ("C", "F"):
            return unlike
        return _dtype_problem(args[1]) or _bytes_problem(args[0], args[1], args[2])
    if name == "__generator_ctor":  # numpy 2 passes the bit generator itself, numpy 1 its name
        ok = len(args) == 1 and isinstance(args[0], BitGenerator | str)
    elif name == "__bit_generator_ctor":
        ok = len(args) == 1 and (args[0] is named["PCG64"] or isinstance(args[0], str))
    else:  # SeedSequence's: its class, a checksum, its state
        state_ok = args[2] is None or isinstance(args[2], tuple) if len(args) == 3 else False
        ok = state_ok and args[0] is named["SeedSequence"] and type(args[1]) is int
    return "" if ok else unlike


SPACE_STATE_KEYS = frozenset({"_shape", "dtype", "_np_random", "low", "high", "bounded_below", "bounded_above",
                              "low_repr", "high_repr", "nvec", "start", "spaces"})  # fmt: skip
"""What the pickled state of gymnasium's Box, Dict and MultiDiscrete holds (gymnasium 1.x)."""
MAX_DIMENSIONS = 32
"""numpy's most dimensions (ours: 3)."""
MAX_SPACE_VALUES = 1 << 22
"""More values than any space of ours holds (the largest observation, 2 x 512 x 512, holds 524,288)."""


def _unbuilt(cls: type) -> type:
    """A stand-in for a gymnasium space class that a pickle can only rebuild the way pickle writes it: an empty
    instance whose state is then set. Never constructed with arguments of the file's own (`Box(0, 255, (30000,
    30000))` would fill gigabytes before any check could run), and its state is checked at every BUILD before
    gymnasium's `__setstate__` reads it (which, for a MultiDiscrete without `start`, allocates the state's shape)."""

    def __new__(stand_in: type, *args: Any, **kwargs: Any) -> Any:
        if args or kwargs:
            raise Refused(f"it constructs a {cls.__name__} with arguments, which a smorphi-rl checkpoint never does")
        left = _SPACES_LEFT.get([0])
        left[0] -= 1
        if left[0] < 0:
            raise Refused(f"it holds over {MAX_SPACES} spaces, which a smorphi-rl checkpoint never does")
        return object.__new__(cls)  # its state is checked at every BUILD (`_build_problem`)

    return type(f"Unbuilt{cls.__name__}", (cls,), {"__new__": __new__})


def _space_state_problem(state: Any) -> str:
    """What is wrong with a space's pickled state (a dict whose shape is whole sizes of at most MAX_SPACE_VALUES
    values, whose dtype is numeric), or ''."""
    if not isinstance(state, dict):
        return "state is not a table"
    shape, dtype = state.get("_shape"), state.get("dtype")
    if shape is not None and not _whole_sizes(shape):
        return f"shape {shown(shape)} is not whole sizes"
    if shape is not None and math.prod(shape) > MAX_SPACE_VALUES:
        return f"shape {shape} holds more values than any space of ours ({MAX_SPACE_VALUES:,})"
    if dtype is not None and not _numbers(dtype):
        return f"dtype {shown(dtype)} is not numeric"
    unknown = sorted(str(k)[:40] for k in set(state) - SPACE_STATE_KEYS)
    if unknown:  # gymnasium copies every key, renaming old ones (`shape`) after this check
        return f"state holds {unknown[0]!r}, which gymnasium's spaces do not"
    for key in ("low", "high", "bounded_below", "bounded_above", "nvec", "start"):  # gymnasium reads each whole
        value = state.get(key)
        if value is not None and not (isinstance(value, np.ndarray) and value.shape == shape and _numbers(value.dtype)):
            return f"{key} is not an array of numbers of its shape {shape}"
    return ""


MAX_SPACES = 64
"""Spaces in one checkpoint pickle: ours hold fewer than 10. Gymnasium reads each one's bounds whole as it is
built, so a file naming one large bound 200,000 times read for most of an hour."""
_SPACES_LEFT: contextvars.ContextVar[list[int]] = contextvars.ContextVar("spaces_left")


class Refused(pickle.UnpicklingError):
    """A pickle that names something a smorphi-rl checkpoint never holds."""


_Unpickler: Any = rllib_compat.python_unpickler()
MAX_KEY_INT = 1 << 31
"""Dict keys and set members are strings, or whole numbers under this, or None or booleans: ours are strings and
small numbers. Numbers that differ by multiples of 2^61 - 1 hash alike, so 40,000 such keys took 8 s to add."""


def _check_keys(keys: list[Any]) -> None:
    """Refuse a dict key or set member of ours not (`MAX_KEY_INT`)."""
    for key in keys:
        if not (type(key) is str or key is None or type(key) is bool
                or (type(key) is int and -MAX_KEY_INT < key < MAX_KEY_INT)):  # fmt: skip
            raise Refused(f"it keys a table by {shown(key, typed=True)}, which a smorphi-rl checkpoint "
                          "never does")  # fmt: skip


class SafeUnpickler(_Unpickler):  # type: ignore[misc]
    """An unpickler that resolves only the exact pairs of `SAFE_GLOBALS` and nothing else, and hands numpy's
    dtypes and arrays only the states numpy writes (the pure-Python unpickler: the C one cannot check BUILD)."""

    def load(self) -> Any:
        self.built: set[int] = set()
        token = _SPACES_LEFT.set([MAX_SPACES])
        try:
            return super().load()
        finally:
            _SPACES_LEFT.reset(token)

    def load_build(self) -> None:
        inst, state = self.stack[-2:]
        if any(inst is allowed for allowed in _safe_globals().values()):  # shared by every load in the process
            raise Refused("it sets the state of a class or function it names, which a smorphi-rl checkpoint never does")
        problem = _build_problem(inst, state)
        if not problem and isinstance(inst, Space):  # once: a space set again and again copied its state each time
            problem = "it sets a space's state twice" if id(inst) in self.built else ""
            self.built.add(id(inst))
        if problem:
            raise Refused(problem)
        if isinstance(inst, np.dtype):  # its state restates it: nothing to set
            self.stack.pop()
            return
        super().load_build()

    def load_setitem(self) -> None:
        _check_keys(self.stack[-2:-1])
        super().load_setitem()

    def load_setitems(self) -> None:  # the items above the last MARK: the pure-Python unpickler's `stack`
        _check_keys(self.stack[0::2])
        super().load_setitems()

    def load_dict(self) -> None:
        _check_keys(self.stack[0::2])
        super().load_dict()

    def load_additems(self) -> None:
        _check_keys(self.stack)
        super().load_additems()

    def load_frozenset(self) -> None:
        _check_keys(self.stack)
        super().load_frozenset()

    dispatch: ClassVar[dict[int, Any]] = {
        **_Unpickler.dispatch,
        pickle.BUILD[0]: load_build,
        pickle.SETITEM[0]: load_setitem,
        pickle.SETITEMS[0]: load_setitems,
        pickle.DICT[0]: load_dict,
        pickle.ADDITEMS[0]: load_additems,
        pickle.FROZENSET[0]: load_frozenset,
    }

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
        if path.is_symlink():
            raise CheckpointError(f"{path}: a link, refused (a checkpoint's files are never links)")
        if not path.exists():
            raise CheckpointError(f"{path}: missing (not a whole checkpoint: its module's files are not all there)")
        if not path.is_file():
            raise CheckpointError(f"{path}: not a plain file, as every file of a checkpoint is")
        if path.stat().st_size > MAX_PICKLE_BYTES:
            raise CheckpointError(f"{path}: {path.stat().st_size:,} bytes, larger than any smorphi-rl policy "
                                  f"({MAX_PICKLE_BYTES:,} at most)")  # fmt: skip
        data = path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    problem = _opcode_problem(data)
    if problem == UNREADABLE:  # damaged, cut short, or read otherwise by the unpickler: never loaded
        raise UnreadableCheckpoint(f"{path}: not a readable checkpoint file ({UNREADABLE})")
    try:
        if problem:
            raise Refused(problem)
        obj = SafeUnpickler(io.BytesIO(data)).load()
    except Refused as exc:
        raise CheckpointError(f"{path}: refused, {exc} (load only checkpoints written by smorphi-rl)") from None
    except Exception as exc:
        raise UnreadableCheckpoint(f"{path}: not a readable checkpoint file ({type(exc).__name__})") from None
    problem = _shared_problem(obj, len(data))
    if problem:
        raise CheckpointError(f"{path}: refused, {problem} (load only checkpoints written by smorphi-rl)")
    return obj


MAX_NESTING = 16
"""Values within values a checkpoint's pickle may build: ours nest at most 7 deep (1,044 real files).
Python hashes a tuple key through every level, so a 300-byte pickle of 40 levels, each naming the one below twice,
hashed for hours."""
MAX_PICKLE_OPS = 1_000_000
"""Opcodes in a checkpoint's pickle: ours hold a few thousand (3,522 the most of 1,044 real files)."""
UNREADABLE = "its opcodes cannot be read"
_TUPLE_OPS = frozenset({"TUPLE", "TUPLE1", "TUPLE2", "TUPLE3", "FROZENSET"})
_LONG_OPS = frozenset({"INT", "LONG", "LONG1", "LONG4"})
MAX_INT_BITS = 1024
"""Whole numbers in a checkpoint's pickle: ours are at most 128 bits (a random generator's state). numpy turns a
seed into 32-bit words one division at a time, so a 128 KB seed took 5 s and a megabyte minutes."""
_MEMO_PUTS = frozenset({"PUT", "BINPUT", "LONG_BINPUT"})
_MEMO_GETS = frozenset({"GET", "BINGET", "LONG_BINGET"})


def _opcode_problem(data: bytes) -> str | None:
    """Why a pickle is refused from its opcodes before anything is built (values nested over MAX_NESTING deep, over
    MAX_PICKLE_OPS opcodes, opcodes that cannot be read), or None. Each stack item is followed by how deep it nests
    (every op's result as deep as the deepest value it takes, a tuple one deeper), through the memo too."""
    import pickletools

    stack: list[int] = []
    marks: list[int] = []
    memo: dict[int, int] = {}
    try:
        for count, (op, arg, _) in enumerate(pickletools.genops(data)):
            if count >= MAX_PICKLE_OPS:
                return f"it holds over {MAX_PICKLE_OPS:,} opcodes, which a smorphi-rl checkpoint never does"
            name = op.name
            if name in _LONG_OPS and isinstance(arg, int) and abs(arg).bit_length() > MAX_INT_BITS:
                return f"it holds a number of over {MAX_INT_BITS} bits, which a smorphi-rl checkpoint never does"
            if (name in _MEMO_PUTS or name in _MEMO_GETS) and not 0 <= int(arg or 0) < MAX_PICKLE_OPS:
                return "it files a value under a number no pickle of ours reaches"  # numbers that hash alike
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
                depth = max(popped, default=0) + (name in _TUPLE_OPS)  # BUILD, REDUCE, SETITEMS keep what they take
                if depth > MAX_NESTING:
                    return f"its values nest over {MAX_NESTING} deep, which a smorphi-rl checkpoint's never do"
                stack.extend([depth] * len(op.stack_after))
    except Exception:  # pickletools reads some opcodes more strictly than the unpickler (`I0x1`): refuse them
        return UNREADABLE
    return None


MAX_PICKLE_NODES = 1_000_000
"""Values in an unpickled state: ours hold a few thousand (a module's weights about 50, a sweep's state 2,000)."""


def _shared_problem(obj: Any, file_bytes: int) -> str | None:
    """What makes `obj` far larger than its file, or None: a pickle may name one array or table many times (its
    memo), so 18 MB on disk read as 200,000 arrays of 16 MB, and every later check walked each of them. Ours
    share nothing: the arrays, counted each time they are named, hold about the file's bytes."""
    stack, nodes, array_bytes = [obj], 1, 0
    while stack:
        item = stack.pop()
        if isinstance(item, dict | list | tuple):  # counted as they are pushed: a list of itself 1,000 times
            nodes += len(item)  # held a billion pointers by the time a million had been popped
            if nodes > MAX_PICKLE_NODES:
                return f"it holds over {MAX_PICKLE_NODES:,} values"
            stack.extend(item.values() if isinstance(item, dict) else item)
        elif isinstance(item, np.ndarray):
            array_bytes += item.nbytes
            if array_bytes > 2 * file_bytes + (1 << 20):
                return f"its arrays, counted where they are named, hold far more than its {file_bytes:,} bytes"
    return None
