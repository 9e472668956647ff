"""The CasADi/IPOPT speed baseline solves our MPC problems (fingertips and hands, both NLP
formulations): same step, same optimum; as a planner it drives our MPC to the same plan."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from studies.ipopt_baseline import FORMULATIONS, IpoptMPC, IpoptPlanner, register_ipopt
from torchcontact.environments import environment
from torchcontact.environments.options import CostOptions
from torchcontact.environments.presets import MPCSettings
from torchcontact.functional import cf_velocity
from torchcontact.model import paper_model
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.planners import PLANNERS, Objective
from torchcontact.results import read_json

EAGER = MPCSettings(compile=False)
"""The paper's settings (frozen gaps, float64, T = 4), eager."""


@pytest.fixture(scope="module")
def scene():
    """The foam brick of flip trial 0 at rest at the origin, three tips pressing on its sides."""
    env = environment("fingertips")
    plant = env.make_plant("foam_brick")
    _, target = env.sample(plant, "flip", 0)
    half = np.array([0.052, 0.075, 0.047]) / 2 + 0.0099  # 0.1 mm into the brick
    tips = [[half[0], 0, 0.02], [0, half[1], 0.02], [-half[0], 0, 0.02]]
    plant.reset([0, 0, plant.resting_height([1, 0, 0, 0]), 1, 0, 0, 0], target, np.ravel(tips))
    settings = MPCSettings(max_iter=100, compile=False)
    mpc = ContactImplicitMPC.from_env(env, plant, settings=settings)
    baseline = IpoptMPC(mpc, n_rows=plant.detector.slots * 4)
    return plant, mpc, baseline, torch.as_tensor(target[:3]), torch.as_tensor(target[3:])


def test_the_nlps_step_is_the_complementarity_free_step(scene):
    plant, mpc, baseline, p, quat = scene
    q, contacts = torch.as_tensor(plant.state()), plant.contacts(torch.float64)
    assert plant.detector.found >= 3  # the three tips
    params = baseline.parameters(q, contacts, p, quat)
    u = 0.004 * torch.randn(9, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    predicted = np.asarray(baseline.step_function(q.numpy(), u.numpy(), params[23:])).ravel()
    Q, b = mpc.system(u)
    frozen = mpc.freeze(q, contacts)
    jac, phi, K, D = frozen.jac, frozen.phi, frozen.stiffness, frozen.damping
    v = cf_velocity(Q, b, jac, phi, mpc.h, K, D, mpc.model.gamma).numpy()
    assert np.abs(v - (b / Q / mpc.h).numpy()).max() > 1e-3  # the contacts push: a real test
    w, x, y, z = q[3:7].numpy()
    rate = np.array([[-x, w, z, -y], [-y, -z, w, x], [-z, y, -x, w]])  # q̇ = ½Gᵀω, body ω
    np.testing.assert_allclose(predicted[:3], q[:3].numpy() + mpc.h * v[:3], atol=1e-12)
    np.testing.assert_allclose(predicted[3:7], q[3:7].numpy() + 0.5 * mpc.h * rate.T @ v[3:6])
    np.testing.assert_allclose(predicted[7:], q[7:].numpy() + mpc.h * v[6:], atol=1e-12)


def _cost(mpc, q, contacts, p, quat):
    """``controls (T, n_u) ↦`` the MPC's own cost of them at ``q`` (exact rotation)."""
    frozen = mpc.freeze(q, contacts)

    def cost(controls):
        controls = torch.as_tensor(controls, dtype=torch.float64)[None]
        return float(mpc.objective(controls, q, frozen, p, quat)[0])

    return cost


def test_ipopt_and_lbfgs_reach_the_same_optimum_in_the_box(scene):
    plant, mpc, baseline, p, quat = scene
    q, contacts = torch.as_tensor(plant.state()), plant.contacts(torch.float64)
    baseline.reset()
    reference = baseline.plan(q, contacts, p, quat)
    ours = mpc.plan(q, contacts, p, quat)
    assert reference.status == "Solve_Succeeded" and reference.solve_ms > 0
    assert np.abs(reference.controls).max() <= 0.005 + 1e-8
    cost = _cost(mpc, q, contacts, p, quat)
    # the NLP integrates the quaternion to first order, our rollout exactly: nearly equal
    assert cost(reference.controls) == pytest.approx(reference.cost, rel=1e-3)
    assert cost(ours.controls) == pytest.approx(cost(reference.controls), rel=2e-3)
    assert cost(ours.controls) < cost(np.zeros((4, 9)))


def test_an_mpc_plans_through_ipopt_as_its_planner(scene):
    """``planner=IpoptPlanner()`` and, once registered, ``planner="ipopt"``: one MPC step
    through IPOPT reaches the plan our L-BFGS reaches, from the MPC's padded contacts."""
    plant, mpc, _, p, quat = scene
    register_ipopt()
    register_ipopt()  # a second call changes nothing
    assert "ipopt" in PLANNERS
    env = environment("fingertips")
    settings = MPCSettings(max_iter=100, compile=False)
    q, contacts = torch.as_tensor(plant.state()), plant.contacts(torch.float64)
    cost = _cost(mpc, q, contacts, p, quat)
    mpc.reset()
    ours = mpc.plan(q, contacts, p, quat)
    for planner in (IpoptPlanner(max_iter=100), "ipopt"):
        ipopt = ContactImplicitMPC.from_env(env, plant, planner=planner, settings=settings)
        assert isinstance(ipopt.planner, IpoptPlanner) and ipopt.planner.max_iter == 100
        plan = ipopt.plan(q, contacts, p, quat)
        assert ipopt.planner.status == "Solve_Succeeded"
        assert plan.iterations > 0 and plan.evaluations > 0
        assert plan.controls.dtype == torch.float64 and plan.controls.shape == (4, 9)
        assert plan.controls.abs().max() <= 0.005 + 1e-8
        assert cost(plan.controls) == pytest.approx(plan.cost, rel=1e-3)
        assert cost(ours.controls) == pytest.approx(cost(plan.controls), rel=2e-3)
        assert torch.equal(plan.control, plan.controls[0])


def test_the_planner_refuses_what_it_cannot_solve(scene):
    plant, mpc, _, p, quat = scene
    with pytest.raises(ValueError, match="formulation"):
        IpoptPlanner(formulation="casadi")
    with pytest.raises(ValueError, match="max_iter"):
        IpoptPlanner(max_iter=0)
    env = environment("fingertips")
    propagated = MPCSettings(gaps="propagated", compile=False)
    drifting = ContactImplicitMPC.from_env(env, plant, planner=IpoptPlanner(), settings=propagated)
    q, contacts = torch.as_tensor(plant.state()), plant.contacts(torch.float64)
    with pytest.raises(ValueError, match="frozen"):
        drifting.plan(q, contacts, p, quat)
    frozen = mpc.freeze(q, contacts)
    x0, box = torch.zeros(1, 36, dtype=torch.float64), (mpc.lower, mpc.upper)
    with pytest.raises(ValueError, match="mpc="):
        objective = Objective(lambda x, *args: (x.square().sum(-1), 2 * x))  # not an MPC's
        IpoptPlanner().plan(objective, x0, box, args=(q, frozen, p, quat))


def test_the_baseline_refuses_what_it_cannot_solve(scene):
    plant, mpc, baseline, p, quat = scene
    fingertips, trifinger = environment("fingertips"), environment("trifinger")
    cube, hand = fingertips.make_plant("cube"), trifinger.make_plant("cube")
    propagated = MPCSettings(gaps="propagated", compile=False)
    with pytest.raises(ValueError, match="frozen"):
        IpoptMPC(ContactImplicitMPC.from_env(fingertips, cube, settings=propagated), n_rows=32)
    with pytest.raises(ValueError, match="qp"):
        IpoptMPC(ContactImplicitMPC.from_env(trifinger, hand, "relaxed_qp", settings=EAGER), 60)
    bottle = trifinger.make_plant("water_bottle")  # tips before it slides: held first
    held = trifinger.cost(bottle, CostOptions(hold_first=2))
    with pytest.raises(ValueError, match="not the hold term"):
        IpoptMPC(ContactImplicitMPC.from_env(trifinger, bottle, settings=EAGER, cost=held), 60)
    paper_cost = trifinger.cost(hand)
    hand_mpc = ContactImplicitMPC.from_env(trifinger, hand, settings=EAGER, cost=paper_cost)
    with pytest.raises(ValueError, match="tip_height"):
        IpoptMPC(hand_mpc, n_rows=60, tip_height=(0.0, 0.1))
    with pytest.raises(ValueError, match="formulation"):
        IpoptMPC(mpc, n_rows=40, formulation="casadi")
    with pytest.raises(ValueError, match="n_rows"):
        IpoptMPC(mpc, n_rows=0)
    contacts = plant.contacts(torch.float64)
    with pytest.raises(ValueError, match="rows"):
        IpoptMPC(mpc, n_rows=8).plan(torch.as_tensor(plant.state()), contacts, p, quat)
    with pytest.raises(ValueError, match="q"):
        baseline.plan(torch.zeros(15), contacts, p, quat)
    with pytest.raises(ValueError, match="tip_height"):
        IpoptMPC(mpc, n_rows=40, tip_height=(0.1, 0.0))


@pytest.mark.parametrize("hand", ["trifinger", "allegro"])
def test_a_hands_nlp_steps_and_solves_as_our_mpc_in_both_formulations(hand):
    """Allegro trial 0 of the stick and TriFinger trial 0 of the cube, a few steps in: the NLP's
    step is the complementarity-free step through CasADi forward kinematics, and IPOPT on
    either formulation reaches the optimum our L-BFGS reaches."""
    env, obj = environment(hand), {"trifinger": "cube", "allegro": "stick"}[hand]
    plant = env.make_plant(obj)
    initial, target = env.sample(plant, env.tasks[0], 0)
    plant.reset(initial, target)
    for _ in range(3):  # let the object settle into the fingers' grip
        plant.step(np.zeros(plant.hand.n_joints))
    settings, cost = MPCSettings(max_iter=200, compile=False), env.cost(plant)
    model = paper_model(env.default_stiffness)  # the NLP's: the paper model at constant K
    mpc = ContactImplicitMPC.from_env(env, plant, model, settings=settings, cost=cost)
    q, contacts = torch.as_tensor(plant.state()), plant.contacts(torch.float64)
    assert plant.detector.found >= 2
    p, quat = torch.as_tensor(target[:3]), torch.as_tensor(target[3:])
    frozen = mpc.freeze(q, contacts)
    cost = _cost(mpc, q, contacts, p, quat)
    ours = mpc.plan(q, contacts, p, quat)
    bound = float(mpc.upper.max())
    u = bound * np.linspace(-0.8, 0.8, plant.hand.n_joints)
    for formulation in FORMULATIONS:
        baseline = IpoptMPC(mpc, plant.detector.slots * 4, max_iter=200, formulation=formulation)
        params = baseline.parameters(q, contacts, p, quat)
        model_rows = params[q.shape[0] + 7 :]  # after q and the target
        predicted = np.asarray(baseline.step_function(q.numpy(), u, model_rows)).ravel()
        held = torch.as_tensor(u).expand(mpc.horizon, -1)[None]
        expected = mpc.rollout(q, held, frozen)[0, 1].numpy()
        np.testing.assert_allclose(predicted[7:], expected[7:], atol=1e-12)  # joints
        np.testing.assert_allclose(predicted[:3], expected[:3], atol=1e-9)
        # the NLP turns the quaternion to first order, our rollout exactly
        np.testing.assert_allclose(predicted[3:7], expected[3:7], atol=1e-4)
        reference = baseline.plan(q, contacts, p, quat)
        assert reference.status == "Solve_Succeeded"
        assert np.abs(reference.controls).max() <= bound + 1e-8
        assert cost(reference.controls) == pytest.approx(reference.cost, rel=1e-3)
        assert cost(ours.controls) == pytest.approx(cost(reference.controls), rel=1e-3)
    assert cost(ours.controls) < cost(np.zeros_like(ours.controls.numpy())) - 1e-3


def test_the_speed_benchmark_times_both_solvers_on_one_short_trial(tmp_path):
    out = tmp_path / "speed"
    script = Path(__file__).parents[1] / "benchmarks" / "ipopt_speed.py"
    options = ["--pairs", "rotation:cube", "--seeds", "1", "--steps", "8", "--no-compile"]
    run = [sys.executable, str(script), *options, "--no-progress", "--out", str(out)]
    printed = subprocess.run(run, check=True, capture_output=True, text=True).stdout
    assert "rotation cube" in printed and "IPOPT (reference) return status" in printed
    overall = read_json(out / "ipopt_speed.json")["rows"][-1]
    assert overall["steps"] == 3 and overall["ours_ms_median"] > 0
    assert overall["ipopt_lean_ms_median"] > 0 < overall["ipopt_reference_ms_median"]
    record = read_json(out / "trials" / "rotation_cube_seed0_steps8.json")
    # each formulation replays the very states our closed loop visited, in its own pass
    for name in ("lean", "reference"):
        assert len(record["ipopt"][name]["ms"]) == len(record["ours_ms"]) == 3
        assert sum(record["ipopt"][name]["status"].values()) == 3


def test_the_speed_benchmark_runs_a_hand(tmp_path):
    out = tmp_path / "speed"
    script = Path(__file__).parents[1] / "benchmarks" / "ipopt_speed.py"
    options = ["--env", "allegro", "--pairs", "on-palm:cube", "--seeds", "1", "--steps", "7"]
    options += ["--no-compile", "--no-progress", "--out", str(out)]
    run = [sys.executable, str(script), *options]
    printed = subprocess.run(run, check=True, capture_output=True, text=True).stdout
    assert "on-palm cube" in printed
    summary = read_json(out / "ipopt_speed.json")
    assert summary["env"] == "allegro" and summary["rows"][-1]["steps"] == 2
