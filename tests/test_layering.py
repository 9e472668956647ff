"""The layers import one way: core ← sim ← mpc, learn; each check in a fresh interpreter.

The core (``import torchcontact``) loads neither MuJoCo nor pytorch-kinematics; no module of
``torchcontact.mpc`` imports ``torchcontact.learn`` and none of ``torchcontact.learn`` imports
``torchcontact.mpc``; no installed module imports the repository's ``studies`` folder; and no
function of the installed packages is longer than :data:`MAX_FUNCTION_LINES` lines.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_FUNCTION_LINES = 80
"""Longest function or method allowed, in lines from ``def`` to its last line."""
LONG_FUNCTIONS_ALLOWED = ("parse_args", "build_parser")
"""Argument-parser definitions: one ``add_argument`` call per option, long by nature."""
PACKAGES = ("torchcontact", "torchcontact.mpc", "torchcontact.learn", "torchcontact.assets")
"""The installed packages (``[tool.setuptools]`` in pyproject.toml)."""

# Prints the modules of the installed packages, found by pkgutil without importing them (so a
# module that fails to import is reported by the import check, not lost here).
LIST_MODULES = """
import importlib.util, json, pkgutil


def walk(package):
    names = [package]
    folders = importlib.util.find_spec(package).submodule_search_locations
    for info in pkgutil.iter_modules(folders, package + "."):
        names += walk(info.name) if info.ispkg else [info.name]
    return names


print(json.dumps(sorted({{name for package in {packages!r} for name in walk(package)}})))
"""

# Imports the modules in a child forked from a process that holds only third-party packages
# (loaded once, to save time), and prints, per module, the loaded modules under the forbidden
# prefixes and the import statements naming them anywhere in the module's source
# (function-level imports included), or the import error.
IMPORT_CHECK = """
import ast, importlib, importlib.util, json, os, sys

for package in ("torch", "numpy", "scipy", "mujoco", "trimesh", "pytorch_kinematics", "osqp"):
    try:
        importlib.import_module(package)
    except ImportError:
        pass

modules, forbidden = {modules!r}, {forbidden!r}


def matches(name):
    return any(name == f or name.startswith(f + ".") for f in forbidden)


def static_imports(name):
    origin = importlib.util.find_spec(name).origin
    found = []
    for node in ast.walk(ast.parse(open(origin, encoding="utf-8").read())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            targets = [node.module] + [node.module + "." + alias.name for alias in node.names]
        else:
            continue
        found += [f"imports {{t}} (line {{node.lineno}})" for t in targets if matches(t)][:1]
    return found


def in_child(names):
    # Import names in a forked child; the forbidden modules it loaded, or the error.
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(read)
        try:
            for name in names:
                importlib.import_module(name)
            found = [f"loads {{m}}" for m in sorted(sys.modules) if matches(m)]
        except BaseException as error:
            found = [f"import failed: {{type(error).__name__}}: {{error}}"]
        with os.fdopen(write, "w") as pipe:
            pipe.write(json.dumps(found))
        os._exit(0)
    os.close(write)
    with os.fdopen(read) as pipe:
        found = json.loads(pipe.read() or '["the child process died"]')
    os.waitpid(pid, 0)
    return found


# All modules in one child first; one child per module only to name the culprits.
culprits = modules if in_child(modules) else []
report = {{}}
for name in modules:
    found = (in_child([name]) if name in culprits else []) + static_imports(name)
    if found:
        report[name] = found
print(json.dumps(report))
"""

LONG_FUNCTIONS = """
import ast, importlib.util, json
from pathlib import Path
long = []
for package in ("torchcontact", "torchcontact.mpc", "torchcontact.learn"):
    for folder in importlib.util.find_spec(package).submodule_search_locations:
        for path in sorted(Path(folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    lines = node.end_lineno - node.lineno + 1
                    first = node.body[0]
                    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                        lines -= first.end_lineno - first.lineno + 1  # the docstring
                    if lines > {limit} and node.name not in {allowed!r}:
                        long.append(f"{{path}}:{{node.lineno}} {{node.name}} ({{lines}} lines)")
print(json.dumps(long))
"""


def _run(code: str):
    """Run ``code`` in a fresh interpreter at the repository root; the JSON it prints last."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


def _modules(*packages: str) -> list[str]:
    return _run(LIST_MODULES.format(packages=packages))


def _assert_imports_none(modules: list[str], forbidden: tuple[str, ...]) -> None:
    """Fail, listing the culprits, when a module loads or names a ``forbidden`` package (or
    cannot be imported at all)."""
    report = _run(IMPORT_CHECK.format(modules=modules, forbidden=forbidden))
    lines = "\n".join(f"{name}: {'; '.join(found)}" for name, found in report.items())
    assert not report, f"modules importing {' or '.join(forbidden)} (or not importable):\n{lines}"


def test_core_imports_neither_mujoco_nor_pytorch_kinematics():
    loaded = _run(
        """
        import json, sys
        import torchcontact
        heavy = ("mujoco", "pytorch_kinematics")
        print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in heavy)))
        """
    )
    assert loaded == []


def test_mpc_never_imports_learn():
    modules = _modules("torchcontact.mpc")
    assert "torchcontact.mpc.controller" in modules
    _assert_imports_none(modules, ("torchcontact.learn",))


def test_learn_never_imports_mpc():
    modules = _modules("torchcontact.learn")
    assert "torchcontact.learn.fit" in modules
    _assert_imports_none(modules, ("torchcontact.mpc",))


def test_no_installed_module_imports_studies():
    modules = _modules(*PACKAGES)
    assert {"torchcontact.contacts", "torchcontact.sim.detect"} <= set(modules)
    _assert_imports_none(modules, ("studies",))


def test_no_function_is_longer_than_the_limit():
    code = LONG_FUNCTIONS.format(limit=MAX_FUNCTION_LINES, allowed=LONG_FUNCTIONS_ALLOWED)
    long = _run(code)
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


SOURCE_FOLDERS = {"torchcontact": ROOT / "torchcontact", "torchcontact.mpc": ROOT / "mpc",
                  "torchcontact.learn": ROOT / "learn"}  # fmt: skip
"""The installed packages' folders (``package-dir`` in pyproject.toml)."""


def _sources() -> dict[str, Path]:
    """Every module of the installed packages by dotted name, read from the folders."""
    found = {}
    for package, folder in SOURCE_FOLDERS.items():
        for path in sorted(folder.rglob("*.py")):
            parts = [p for p in path.relative_to(folder).with_suffix("").parts if p != "__init__"]
            found[".".join([package, *parts])] = path
    return found


def _imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of ours that ``name`` (file ``path``) imports anywhere in its source,
    function-level imports included (an import deferred into a function still closes a
    circle: it only moves the failure to the first call)."""

    def owner(dotted: str) -> str | None:
        while dotted and dotted not in modules:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {owner(alias.name) for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{up}.{base}" if base else up
            for alias in node.names:
                full = f"{base}.{alias.name}"
                found.add(full if full in modules else owner(base))
    return {module for module in found if module and module != name}


def test_no_import_circle_anywhere():
    """Tarjan's strongly connected components of the import graph: each must be one module."""
    modules = _sources()
    graph = {name: _imported(name, path, modules) for name, path in modules.items()}
    index, low, stack, on_stack, circles = {}, {}, [], set(), []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component, member = set(), None
            while member != node:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
            if len(component) > 1:
                circles.append(sorted(component))

    for name in graph:
        if name not in index:
            visit(name)
    assert "torchcontact.mpc.trials" in graph["torchcontact.cli.run"]  # the graph is real
    assert not circles, "import circles:\n" + "\n".join(" ↔ ".join(c) for c in circles)


def _registries() -> dict[str, set[str]]:
    """The registered names of each registry, by the modules that own it (where its names may
    be compared: registering, validating, building)."""
    from torchcontact import checkpoint, model, object_sources, stiffness
    from torchcontact.environments import ENVIRONMENTS, costs
    from torchcontact.mpc import models, planners

    return {
        "torchcontact.model": set(model.MODELS),
        "torchcontact.stiffness": set(stiffness.PARAMETERIZATIONS),
        "torchcontact.checkpoint": set(checkpoint.STIFFNESS_KINDS),
        "torchcontact.environments.costs": set(costs.COSTS),
        "torchcontact.environments": set(ENVIRONMENTS),
        "torchcontact.mpc.planners": set(planners.PLANNERS),
        "torchcontact.mpc.models": {*models.MPC_MODELS, *models.LEGACY_MODELS},
        "torchcontact.object_sources": set(object_sources.OBJECT_SOURCES),
    }


def _compared_strings(tree: ast.AST):
    """``(line, text)`` of every string literal in a comparison (``==``, ``!=``, ``in``)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            for side in (node.left, *node.comparators):
                items = side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side]
                for item in items:
                    if isinstance(item, ast.Constant) and isinstance(item.value, str):
                        yield node.lineno, item.value


def test_no_registered_name_is_compared_as_a_string_outside_its_registry():
    """A behaviour chosen by comparing a registered name bypasses the registry: what the
    name means belongs to its entry (as :class:`~torchcontact.mpc.models.MPCModel`'s fields)."""
    from torchcontact.checkpoint import DAMPING_KINDS

    registries = _registries()
    names = set().union(*registries.values())
    registries["torchcontact.checkpoint"] |= set(DAMPING_KINDS)  # its own words for D
    found = []
    for module, path in _sources().items():
        allowed = registries.get(module, set())
        tree = ast.parse(path.read_text(encoding="utf-8"))
        found += [
            f"{path.relative_to(ROOT)}:{line} compares {text!r}"
            for line, text in _compared_strings(tree)
            if text in names and text not in allowed
        ]
    assert not found, "registered names compared as strings:\n" + "\n".join(found)


OBJECT_PARSERS = {"is_generated", "is_set", "seed_of", "expand", "is_mesh_file"}
"""What tells an object's string apart: only :mod:`torchcontact.object_sources` (and the
generated objects' own module) may call it; every other module asks the registry."""


def test_object_strings_are_told_apart_by_their_registry_alone():
    found = []
    for module, path in _sources().items():
        if module in ("torchcontact.object_sources", "torchcontact.generated"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            func = node.func if isinstance(node, ast.Call) else None
            called = getattr(func, "attr", None) or getattr(func, "id", None)
            via = getattr(getattr(func, "value", None), "id", None)
            if called in OBJECT_PARSERS and (called == "is_mesh_file" or via == "generated"):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno} calls {called}")
    assert not found, "object strings parsed outside torchcontact.object_sources:\n" + "\n".join(
        found
    )
