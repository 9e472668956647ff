"""Environment descriptions: the registry, MPCs built from them, a user's robot, and a contact
model and a planner registered from outside the library."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from torchcontact import environments
from torchcontact.environments import (
    ENVIRONMENTS,
    environment,
    register_environment,
)
from torchcontact.environments.costs import PushingCost
from torchcontact.environments.custom import PoseTask, from_mjcf
from torchcontact.environments.hands import PAPER_OBJECT_MASS
from torchcontact.environments.presets import MPCSettings
from torchcontact.environments.tasks import SuccessCriterion
from torchcontact.frozen import FrozenComplementarityFree
from torchcontact.model import MODELS, ContactModel, contact_model, register_model
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.planners import PLANNERS, PlannerResult, register_planner
from torchcontact.mpc.trials import run_trial
from torchcontact.objects import ObjectOptions
from torchcontact.sim.hands import HandPlant

GRIPPER = Path(__file__).resolve().parents[1] / "examples" / "two_finger_gripper.xml"
EAGER = MPCSettings(max_iter=10, compile=False)


def test_the_three_environments_are_registered_and_unknown_names_are_refused():
    assert set(ENVIRONMENTS) == {"fingertips", "trifinger", "allegro"}
    with pytest.raises(ValueError, match="env must be one of"):
        environment("shadow_hand")
    with pytest.raises(ValueError, match="name must be a new environment name"):
        register_environment(ENVIRONMENTS["trifinger"])


@pytest.mark.parametrize("name", ["fingertips", "trifinger", "allegro"])
def test_an_environments_mpc_plans_within_its_box(name):
    env = environment(name)
    plant = env.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(env, plant, settings=EAGER)
    assert mpc.layout is env.layout and mpc.system.n_robot == env.layout.nv - 6
    initial, target = env.sample(plant, env.tasks[0], 0)
    plant.reset(initial, target)
    q = torch.as_tensor(plant.state())
    plan = mpc.plan(q, plant.contacts(mpc.dtype), *torch.as_tensor(target).split([3, 4]))
    bound = env.control_bound(plant)
    assert plan.controls.shape == (EAGER.horizon, env.layout.nv - 6)
    assert bool((plan.controls.abs() <= bound + 1e-12).all())
    tips = mpc.fingertips(q.unsqueeze(0))[0].numpy()
    # the MPC's fingertips are the plant's own (sites or tip bodies)
    expected = plant.fingertips() if hasattr(plant, "fingertips") else q[7:].reshape(3, 3)
    np.testing.assert_allclose(tips, np.asarray(expected), atol=1e-6)


def test_a_user_robots_model_takes_the_object_mass_from_the_plant():
    env = _gripper()
    light = env.make_plant("cube")
    heavy = HandPlant(env.hand, "cube", options=ObjectOptions(mass=0.05))
    Q_light, b_light = env.system(light)(torch.zeros(4, dtype=torch.float64))
    Q_heavy, b_heavy = env.system(heavy)(torch.zeros(4, dtype=torch.float64))
    torch.testing.assert_close(Q_heavy[:6], 5 * Q_light[:6])
    torch.testing.assert_close(b_heavy[2], 5 * b_light[2])
    assert float(b_light[2]) == pytest.approx(-0.01 * 9.8)


def test_the_paper_hands_model_a_ten_gram_object_whatever_the_plants():
    env = environment("allegro")
    heavy = env.make_plant("cube")
    assert heavy.object.mass == pytest.approx(0.1)
    _, b = env.system(heavy)(torch.zeros(16, dtype=torch.float64))
    assert float(b[2]) == pytest.approx(-PAPER_OBJECT_MASS * 9.8)


def _gripper(max_steps: int = 150):
    task = PoseTask(
        target_x=(0.0, 0.0),
        target_y=(0.01, 0.015),
        lift=(0.0, 0.0),
        criterion=SuccessCriterion(
            position_tolerance=0.004, quaternion_tolerance=0.04, hold_steps=5, max_steps=max_steps
        ),
    )
    return from_mjcf(GRIPPER, task=task, cost=PushingCost(), name="gripper", control_bound=0.01)


def test_a_user_robot_from_its_mjcf_pushes_a_cube_to_its_target_closed_loop():
    env = _gripper()
    assert isinstance(environments.from_mjcf(GRIPPER), type(env))  # the package's own
    assert env.layout.joints == ("free", "slide", "slide", "slide", "slide")
    assert env.hand.tips == ("left_tip", "right_tip")
    plant = env.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(env, plant, settings=EAGER)
    initial, target = env.sample(plant, "reposition", 0)
    assert target[1] - initial[1] >= 0.01  # a push of 1-1.5 cm along y (the finger reaches 2 cm)
    from torchcontact.mpc.model_options import ModelOptions
    from torchcontact.mpc.trial_config import TrialConfig

    config = TrialConfig(
        env="gripper", task="reposition", object="cube", seed=0, max_steps=150,
        settings=MPCSettings(max_iter=10, compile=False),
        model_options=ModelOptions(stiffness=0.5),
    )  # fmt: skip
    record = run_trial(config, env, plant, mpc)
    assert record.success, record.pos_err_mm
    assert record.pos_err_mm < 4.0


def test_a_registered_contact_model_and_planner_run_the_mpc():
    class Frictionless(ContactModel):
        """The complementarity-free step on normal rows only (no friction cone)."""

        facets = 4

        def freeze(self, contacts, h, q=None, *, compile=False):
            rows = contacts.jac_normal.repeat_interleave(4, dim=-2) / 4
            phi = contacts.phi.repeat_interleave(4, dim=-1)
            K = torch.ones_like(phi)
            return FrozenComplementarityFree(rows, phi, K, None, rows, float(h), 100.0)

    class ZeroPlanner:
        """Keeps the start: proves the MPC calls the registered planner."""

        def __init__(self, max_iter, memory, compile):
            self.calls = 0

        def plan(self, objective, x0, box, args=()):
            self.calls += 1
            f, _ = objective.value_and_grad(x0.clamp(*box), *args)
            return PlannerResult(x0.clamp(*box), f, 0, 1)

    register_model("frictionless_test", Frictionless)
    register_planner("zero_test", ZeroPlanner)
    try:
        env = environment("fingertips")
        plant = env.make_plant("cube")
        model = contact_model("frictionless_test")
        mpc = ContactImplicitMPC.from_env(env, plant, model, "zero_test", EAGER)
        initial, target = env.sample(plant, "rotation", 0)
        plant.reset(initial, target)
        plan = mpc.plan(
            torch.as_tensor(plant.state()),
            plant.contacts(mpc.dtype),
            *torch.as_tensor(target).split([3, 4]),
        )
        assert mpc.planner.calls == 1 and plan.iterations == 0
        assert torch.equal(plan.controls, torch.zeros_like(plan.controls))
        assert np.isfinite(plan.cost)
    finally:
        MODELS.pop("frictionless_test")
        PLANNERS.pop("zero_test")


def test_a_model_that_cannot_be_differentiated_is_refused_by_name():
    env = environment("fingertips")
    plant = env.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(env, plant, "qp", settings=EAGER)
    with pytest.raises(ValueError, match="AnitescuQP cannot be frozen"):
        mpc.plan(
            torch.as_tensor(plant.state()),
            plant.contacts(mpc.dtype),
            torch.zeros(3, dtype=torch.float64),
            torch.tensor([1.0, 0, 0, 0], dtype=torch.float64),
        )
