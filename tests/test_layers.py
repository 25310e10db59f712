"""Imports run one way (docs/architecture.md): a module imports only from its own layer or layers to its left,
and each outside library from its one home. Lazy imports inside functions count too: they run all the same.
"""

from __future__ import annotations

import ast
from pathlib import Path

import smorphi_rl

PACKAGE = Path(smorphi_rl.__file__).parent

LAYERS: list[tuple[str, ...]] = [
    (
        "errors",
        "words",
        "jsontext",
        "config_fields",
        "interrupts",
        "progress",
        "quiet",
        "stats",
        "rundir",
        "inputs",
        "_kernels",
        "cluster",
        "rllib_compat",
    ),
    ("geometry",),
    ("maps", "floorplans", "maptools", "map_sources"),
    ("coverage", "coverage_reference", "score"),
    ("planning",),
    ("env_config", "env", "vector_env"),
    ("search", "protocol", "numpy_policy", "policy_file"),
    ("design", "designer"),
    ("recording",),
    ("plots",),
    ("training",),
    ("compare", "reproduce"),
    ("cli", "entry", "__init__", "__main__"),
]
"""Left to right. The foundation (errors, files, the adapter of private names, a local Ray) imports nothing above
it; plots read the core's values, and the training jobs draw their figures with them."""

AGAINST_THE_FLOW = {
    ("policy_file", "training.presets"): "the algorithm names and angle frequencies; presets imports nothing heavy",
}
"""Reads that run against the flow on purpose, each named in docs/architecture.md."""

HOMES = {
    "ray": ("training", "rllib_compat", "cluster", "search.on_ray"),
    "torch": ("training", "rllib_compat"),
    "tensorboardX": ("training", "rllib_compat"),
    "pymoo": ("search.nsga2",),
    "mcap": ("recording",),
    "matplotlib": ("plots",),
    "numba": ("_kernels",),
}
"""The only modules an outside library may be imported from (ARCHITECTURE.md: each library lives in one place)."""


def _module(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" and len(parts) > 1 else parts)


def _imports(source: str, module: str) -> list[tuple[int, str]]:
    """(line, module) for every import in `module`'s source, at any depth."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert not node.level, f"smorphi_rl.{module}:{node.lineno}: import absolutely"
            base = str(node.module)
            found.append((node.lineno, base))
            if base == "smorphi_rl":  # `from smorphi_rl import interrupts`: the submodules themselves
                found += [(node.lineno, f"smorphi_rl.{alias.name}") for alias in node.names]
    return found


def _layer(module: str) -> int:
    top = module.split(".")[0]
    for index, names in enumerate(LAYERS):
        if top in names:
            return index
    raise AssertionError(f"smorphi_rl.{module} is in no layer of LAYERS: place it there (and in docs/architecture.md)")


def _home(module: str, homes: tuple[str, ...]) -> bool:
    return any(module == home or module.startswith(f"{home}.") for home in homes)


def _edges() -> list[tuple[str, int, str, str]]:
    """(file, line, importer, imported) for every import the package makes."""
    edges = []
    for path in sorted(PACKAGE.rglob("*.py")):
        importer = _module(path)
        for line, target in _imports(path.read_text(), importer):
            edges.append((str(path.relative_to(PACKAGE.parent)), line, importer, target))
    return edges


def test_every_module_has_a_layer():
    for path in sorted(PACKAGE.rglob("*.py")):
        _layer(_module(path))


def _against_the_flow(edges: list[tuple[str, int, str, str]]) -> list[str]:
    wrong = []
    for file, line, importer, target in edges:
        imported = target.removeprefix("smorphi_rl.")
        allowed = not target.startswith("smorphi_rl.") or (importer, imported) in AGAINST_THE_FLOW
        if not allowed and _layer(imported) > _layer(importer):
            wrong.append(f"{file}:{line}: {importer} imports {imported}, a layer to its right")
    return wrong


def _away_from_home(edges: list[tuple[str, int, str, str]]) -> list[str]:
    wrong = []
    for file, line, importer, target in edges:
        library = target.split(".")[0]
        if library in HOMES and not _home(importer, HOMES[library]):
            wrong.append(f"{file}:{line}: {importer} imports {library} (its home: {', '.join(HOMES[library])})")
    return wrong


def test_imports_run_left_to_right():
    wrong = _against_the_flow(_edges())
    assert not wrong, "\n".join(wrong)


def test_each_outside_library_is_imported_from_its_home_only():
    wrong = _away_from_home(_edges())
    assert not wrong, "\n".join(wrong)


def test_the_checks_see_lazy_imports_and_judge_them():
    """An import inside a function is found and judged: the two tests above can fail."""
    source = "def make():\n    from smorphi_rl.recording import RecordingWrapper\n    from smorphi_rl import plots\n"
    source += "    import matplotlib.pyplot\n"
    edges = [("vector_env.py", line, "vector_env", target) for line, target in _imports(source, "vector_env")]
    targets = [target for *_, target in edges]
    assert targets == ["smorphi_rl.recording", "smorphi_rl", "smorphi_rl.plots", "matplotlib.pyplot"]
    assert len(_against_the_flow(edges)) == 2 and len(_away_from_home(edges)) == 1
