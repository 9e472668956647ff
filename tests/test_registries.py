"""A user's own cost and contact model, registered by name in a module that
``torchcontact run --import`` names, run from the command line like the built-in ones."""

from __future__ import annotations

import json
import sys

import pytest

from torchcontact.cli import main
from torchcontact.environments.costs import COSTS, ManipulationCost, cost, register_cost
from torchcontact.mpc.models import MPC_MODELS, mpc_model, register_mpc_model


@pytest.fixture
def module(tmp_path):
    """A user's module registering the cost ``gentle`` and the MPC model ``stiff``."""
    path = tmp_path / "my_parts.py"
    path.write_text(
        "from torchcontact.environments.costs import ManipulationCost, register_cost\n"
        "from torchcontact.model import contact_model\n"
        "from torchcontact.mpc.models import MPCModel, register_mpc_model\n"
        "register_cost('gentle', lambda **w: ManipulationCost(control=20.0, **w))\n"
        "register_mpc_model(MPCModel('stiff', lambda h, k, kappa: contact_model('paper', "
        "stiffness=10.0), False, None, True, 'the paper model at K = 10'))\n"
    )
    yield path
    COSTS.pop("gentle", None)
    MPC_MODELS.pop("stiff", None)
    for name in [n for n in sys.modules if n.startswith("torchcontact_user_my_parts_")]:
        del sys.modules[name]


def test_a_registered_cost_is_built_by_name():
    register_cost("heavy_control", lambda **weights: ManipulationCost(control=99.0, **weights))
    try:
        assert cost("heavy_control").control == 99.0
        with pytest.raises(ValueError, match="name must be a new cost name, got 'heavy_control'"):
            register_cost("heavy_control", ManipulationCost)
        with pytest.raises(ValueError, match="cost 'broken' is not a valid cost"):
            register_cost("broken", 3)
    finally:
        COSTS.pop("heavy_control")


def test_an_mpc_model_is_registered_once_and_as_an_mpc_model():
    with pytest.raises(ValueError, match="name must be a new MPC model name, got 'paper'"):
        register_mpc_model(mpc_model("paper"))
    with pytest.raises(ValueError, match="name must be a non-empty string, got None"):
        register_mpc_model("paper")


def test_run_plans_with_a_cost_and_a_model_its_module_registers(module, tmp_path):
    out = tmp_path / "out"
    argv = ["run", "fingertips", "--task", "rotation", "--import", str(module),
            "--cost", "gentle", "--model", "stiff", "--trials", "1", "--max-steps", "1",
            "--no-compile", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    (record,) = [json.loads(p.read_text()) for p in (out / "trials").glob("*.json")]
    assert record["cost"] == "gentle" and record["model"] == "stiff"
