"""Private names of other packages (Ray, RLlib, Tune, torch, numpy) are used in one adapter module only.

A private name is one with a leading underscore that our package does not define itself: an attribute read or
written (`learner._params`), a module imported (`ray._private`), or a method of a library base class that one of
our classes overrides (`_sample`). `smorphi_rl/rllib_compat.py` is the only module allowed them; its own tests
(`tests/test_rllib_compat.py`) fail when the library changes underneath.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
from pathlib import Path

import smorphi_rl

PACKAGE = Path(smorphi_rl.__file__).parent
ADAPTER = PACKAGE / "rllib_compat.py"
DOCUMENTED = {
    "_forward",
    "_forward_exploration",
    "_forward_inference",
    "_forward_train",  # RLModule: what a module implements
    "_evaluate",  # pymoo's Problem: what a problem implements
    "_exit",  # os._exit: the standard library's documented exit without clean-up
    "_abc_impl",  # set on every ABC subclass by ABCMeta, not written by us
}
"""Underscored names the libraries document as what a user implements or calls: public in all but spelling."""


def _private(name: str) -> bool:
    return name.startswith("_") and not name.endswith("_")  # dunder and sunder (`_missing_`) names are protocols


def _sources() -> dict[Path, ast.Module]:
    return {path: ast.parse(path.read_text()) for path in sorted(PACKAGE.rglob("*.py"))}


def _own_names(trees: dict[Path, ast.Module]) -> set[str]:
    """Every private name our package defines: functions, classes, assigned attributes and variables, modules."""
    own = {path.stem for path in PACKAGE.rglob("_*.py")} | {path.stem for path in PACKAGE.rglob("*.so")}
    own |= {path.name.split(".")[0] for path in PACKAGE.rglob("_*.so")}
    for tree in trees.values():
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                own.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _on_self(node):
                own.add(node.attr)  # `self._x = ...`: `other._x = ...` writes what may be another package's
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                own.add(node.id)
            elif _registers_buffer(node):  # self.register_buffer("_freqs", ...): our own attribute
                own.add(node.args[0].value)  # type: ignore[attr-defined]
    return {name for name in own if _private(name)} | DOCUMENTED


def _on_self(node: ast.Attribute) -> bool:
    return isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")


def _registers_buffer(node: ast.AST) -> bool:
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "register_buffer"
        and bool(node.args)
        and isinstance(node.args[0], ast.Constant)
    )


HOOKS = {"sys.stdout", "sys.stderr", "sys.unraisablehook"}
"""What the standard library documents as there to be replaced (the CLI's escaping streams, `interrupts`'s hook)."""


def _modules_bound(tree: ast.Module) -> set[str]:
    """Names that hold another package's module: `import x`, `from x import y` where y is a module,
    `x = inspect.getmodule(...)`."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {(alias.asname or alias.name).split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and not (node.module or "").startswith("smorphi_rl"):
            for alias in node.names:
                try:
                    is_module = inspect.ismodule(getattr(importlib.import_module(node.module or ""), alias.name))
                except (ImportError, AttributeError):
                    is_module = False
                if is_module:
                    names.add(alias.asname or alias.name)
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            func = node.value.func
            if isinstance(func, ast.Attribute) and func.attr == "getmodule":
                names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return names


def _uses(path: Path, tree: ast.Module, own: set[str]) -> list[str]:
    """Private names read or imported, another package's module assigned into, and `__class__` swapped."""
    found = []
    modules = _modules_bound(tree)
    for node in ast.walk(tree):
        where = f"{path.relative_to(PACKAGE.parent)}:{getattr(node, 'lineno', 0)}"
        stored = isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store)
        if stored and node.attr == "__class__":  # type: ignore[union-attr]
            found.append(f"{where} __class__ swapped")
        elif stored and isinstance(node.value, ast.Name) and node.value.id in modules:  # type: ignore[union-attr]
            if f"{node.value.id}.{node.attr}" not in HOOKS:  # type: ignore[union-attr]
                found.append(f"{where} {node.value.id}.{node.attr} assigned")  # type: ignore[union-attr]
        elif isinstance(node, ast.Attribute) and _private(node.attr) and node.attr not in own:
            found.append(f"{where} .{node.attr}")
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and not (node.module or "").startswith("smorphi_rl"):
            parts = (node.module or "").split(".") + [alias.name for alias in node.names]
            found += [f"{where} {node.module}: {part}" for part in parts if _private(part)]
        elif isinstance(node, ast.Import):
            found += [
                f"{where} {alias.name}"
                for alias in node.names
                if not alias.name.startswith("smorphi_rl") and any(_private(p) for p in alias.name.split("."))
            ]
    return found


def test_no_private_name_of_another_package_outside_the_adapter():
    trees = _sources()
    own = _own_names(trees)
    uses = [use for path, tree in trees.items() if path != ADAPTER for use in _uses(path, tree, own)]
    assert uses == []


def test_the_scan_sees_a_private_read_an_import_and_leaves_our_own_names_alone():
    tree = ast.parse(
        "from ray._private import services\nimport torch._dynamo\nlearner._params\nself._mine\nself._mine = 1\n"
        "import inspect\nfrom ray.rllib.utils import torch_utils\nm = inspect.getmodule(f)\nm.batch = g\n"
        "torch_utils.clip_gradients = g\nwrapper.__class__ = Other\nself.batch = g\nenv._np_random = None\n"
    )
    uses = sorted(
        use.split(" ", 1)[1] for use in _uses(PACKAGE / "x.py", tree, own=_own_names({PACKAGE / "x.py": tree}))
    )
    assert uses == [
        "._np_random", "._params", "__class__ swapped", "m.batch assigned", "ray._private: _private", "torch._dynamo",
        "torch_utils.clip_gradients assigned",
    ]  # fmt: skip


def _our_classes() -> list[type]:
    classes = []
    for info in pkgutil.walk_packages(smorphi_rl.__path__, "smorphi_rl."):
        if info.name.endswith(("__main__", "rllib_compat")):
            continue
        module = importlib.import_module(info.name)
        classes += [c for _, c in inspect.getmembers(module, inspect.isclass) if c.__module__ == info.name]
    return classes


def _library_uses(base: type, name: str) -> bool:
    """Whether a library base class defines `name` or uses it as an attribute of its instances."""
    if name in base.__dict__:
        return True
    try:
        return f"self.{name}" in inspect.getsource(base)
    except (OSError, TypeError):  # compiled: only its dict says
        return False


TYPING_SETS = {"_is_protocol", "_is_runtime_protocol"}
"""Set in a class's own dict by `typing` itself when the class is a `Protocol`: not an override of ours."""


def test_no_class_outside_the_adapter_overrides_a_private_name_of_a_library_base():
    """Neither a private method of a library base nor a private attribute its code sets or reads."""
    overrides = []
    for cls in _our_classes():
        for name in cls.__dict__:
            if not _private(name) or name in DOCUMENTED or name in TYPING_SETS:
                continue
            bases = [b for b in cls.__mro__[1:] if not b.__module__.startswith("smorphi_rl") and _library_uses(b, name)]
            overrides += [f"{cls.__module__}.{cls.__name__}.{name} (of {bases[0].__qualname__})"] if bases else []
    assert overrides == []
