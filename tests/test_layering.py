"""The layers import one way: core ← sim ← mpc, learn; each check in a fresh interpreter.

The core (``import torchcontact``) loads neither MuJoCo nor pytorch-kinematics; no module of
``torchcontact.mpc`` imports ``torchcontact.learn`` and none of ``torchcontact.learn`` imports
``torchcontact.mpc``; no installed module imports the repository's ``studies`` folder; and no
function of the installed packages is longer than :data:`MAX_FUNCTION_LINES` lines.
"""

from __future__ import annotations

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

# Imports every module in a child forked from a process that holds only third-party packages
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


report = {{}}
for name in modules:
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(read)
        try:
            importlib.import_module(name)
            found = [f"loads {{m}}" for m in sorted(sys.modules) if matches(m)]
            found += static_imports(name)
        except BaseException as error:
            found = [f"import failed: {{type(error).__name__}}: {{error}}"]
        with os.fdopen(write, "w") as pipe:
            pipe.write(json.dumps(found))
        os._exit(0)
    os.close(write)
    with os.fdopen(read) as pipe:
        found = json.loads(pipe.read() or '["the child process died"]')
    os.waitpid(pid, 0)
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
