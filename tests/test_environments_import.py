"""``torchcontact run NAME --import MODULE``: an environment a user's module registers, run by
name from the command line, in every process that runs its trials."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from torchcontact.cli import main
from torchcontact.environments import ENVIRONMENTS, import_environments
from torchcontact.mpc.trial_config import trial_configs
from torchcontact.mpc.trials import build_trial

FINGER = Path(__file__).resolve().parents[1] / "examples" / "planar_finger.xml"


@pytest.fixture
def module(tmp_path):
    """A user's module file registering the planar finger as ``finger_here``; unregistered
    after the test."""
    path = tmp_path / "my_envs.py"
    path.write_text(
        "from torchcontact.environments import from_mjcf, register_environment\n"
        f"register_environment(from_mjcf({str(FINGER)!r}, name='finger_here'))\n"
    )
    yield path
    ENVIRONMENTS.pop("finger_here", None)
    for name in [n for n in sys.modules if n.startswith("torchcontact_user_my_envs_")]:
        del sys.modules[name]


def test_a_module_registers_its_environment_once(module):
    assert import_environments(str(module)) == ["finger_here"]
    assert import_environments(str(module)) == []  # imported already
    assert "finger_here" in ENVIRONMENTS


def test_run_takes_an_environment_a_named_module_registers(module, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["run", "finger_here", "--import", str(module), "--trials", "1", "--max-steps", "1",
            "--no-compile", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    (record,) = [json.loads(p.read_text()) for p in (out / "trials").glob("*.json")]
    assert record["env"] == "finger_here" and record["env_module"] == str(module)
    assert len(record["inputs"]["env_module_sha256"]) == 64  # a changed module is a new input


def test_a_trial_imports_its_module_where_it_runs(module):
    (config,) = trial_configs("finger_here", [("reposition", "cube")], [0], env_module=str(module))
    # a fresh worker process knows neither the environment nor the module
    ENVIRONMENTS.pop("finger_here")
    for name in [n for n in sys.modules if n.startswith("torchcontact_user_my_envs_")]:
        del sys.modules[name]
    env, _, _ = build_trial(config)
    assert env.name == "finger_here" and "finger_here" in ENVIRONMENTS


@pytest.mark.parametrize(
    "module, message",
    [
        ("/no/such/envs.py", "--import: module '/no/such/envs.py' must import, got FileNotFound"),
        ("no_such_package.envs", "got ModuleNotFoundError: No module named 'no_such_package'"),
    ],
)  # fmt: skip
def test_a_module_that_does_not_import_is_refused_in_one_line(module, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["run", "fingertips", "--import", module])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1
    assert message in err, err
