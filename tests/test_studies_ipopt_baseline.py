"""The CasADi/IPOPT speed baseline solves our MPC problems (fingertips and hands, both NLP
formulations): same step, same optimum."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from studies.ipopt_baseline import FORMULATIONS, IpoptMPC
from torchcontact.functional import cf_velocity
from torchcontact.mpc.fingertips import fingertips_mpc
from torchcontact.mpc.hands import hand_mpc
from torchcontact.mpc.suites import SUITES
from torchcontact.results import read_json


@pytest.fixture(scope="module")
def scene():
    """The foam brick of flip trial 0 at rest at the origin, three tips pressing on its sides."""
    suite = SUITES["fingertips"]
    env = suite.make_env("foam_brick")
    _, target = suite.sample(env, "flip", "foam_brick", 0)
    half = np.array([0.052, 0.075, 0.047]) / 2 + 0.0099  # 0.1 mm into the brick
    tips = [[half[0], 0, 0.02], [0, half[1], 0.02], [-half[0], 0, 0.02]]
    env.reset([0, 0, env.resting_height([1, 0, 0, 0]), 1, 0, 0, 0], target, np.ravel(tips))
    mpc = fingertips_mpc("foam_brick", max_iter=100, compile=False)
    baseline = IpoptMPC(mpc, n_rows=env.detector.slots * 4)
    return env, mpc, baseline, torch.as_tensor(target[:3]), torch.as_tensor(target[3:])


def test_the_nlps_step_is_the_complementarity_free_step(scene):
    env, mpc, baseline, p, quat = scene
    q, contacts = torch.as_tensor(env.state()), env.contacts(torch.float64)
    assert env.detector.found >= 3  # the three tips
    params = baseline.parameters(q, contacts, p, quat)
    u = 0.004 * torch.randn(9, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    predicted = np.asarray(baseline.step_function(q.numpy(), u.numpy(), params[23:])).ravel()
    Q, b = mpc.system(u)
    jac, phi, K, D = mpc.frozen_rows(q, contacts)
    v = cf_velocity(Q, b, jac, phi, mpc.h, K, D, mpc.model.gamma).numpy()
    assert np.abs(v - (b / Q / mpc.h).numpy()).max() > 1e-3  # the contacts push: a real test
    w, x, y, z = q[3:7].numpy()
    rate = np.array([[-x, w, z, -y], [-y, -z, w, x], [-z, y, -x, w]])  # q̇ = ½Gᵀω, body ω
    np.testing.assert_allclose(predicted[:3], q[:3].numpy() + mpc.h * v[:3], atol=1e-12)
    np.testing.assert_allclose(predicted[3:7], q[3:7].numpy() + 0.5 * mpc.h * rate.T @ v[3:6])
    np.testing.assert_allclose(predicted[7:], q[7:].numpy() + mpc.h * v[6:], atol=1e-12)


def test_ipopt_and_lbfgs_reach_the_same_optimum_in_the_box(scene):
    env, mpc, baseline, p, quat = scene
    q, contacts = torch.as_tensor(env.state()), env.contacts(torch.float64)
    baseline.reset()
    reference = baseline.plan(q, contacts, p, quat)
    ours = mpc.plan(q, contacts, p, quat)
    assert reference.status == "Solve_Succeeded" and reference.solve_ms > 0
    assert np.abs(reference.controls).max() <= 0.005 + 1e-8
    rows = mpc.frozen_rows(q, contacts)

    def cost(controls):
        controls = torch.as_tensor(controls, dtype=torch.float64)[None]
        return float(mpc.objective(controls, q, rows, p, quat)[0])

    # the NLP integrates the quaternion to first order, our rollout exactly: nearly equal
    assert cost(reference.controls) == pytest.approx(reference.cost, rel=1e-3)
    assert cost(ours.controls) == pytest.approx(cost(reference.controls), rel=2e-3)
    assert cost(ours.controls) < cost(np.zeros((4, 9)))


def test_the_baseline_refuses_what_it_cannot_solve(scene):
    env, mpc, baseline, p, quat = scene
    with pytest.raises(ValueError, match="frozen"):
        IpoptMPC(fingertips_mpc("cube", gaps="propagated"), n_rows=32)
    with pytest.raises(ValueError, match="qp"):
        IpoptMPC(hand_mpc("trifinger", model="qp"), n_rows=60)
    with pytest.raises(ValueError, match="tip_height"):
        IpoptMPC(hand_mpc("trifinger"), n_rows=60, tip_height=(0.0, 0.1))
    with pytest.raises(ValueError, match="formulation"):
        IpoptMPC(mpc, n_rows=40, formulation="casadi")
    with pytest.raises(ValueError, match="n_rows"):
        IpoptMPC(mpc, n_rows=0)
    contacts = env.contacts(torch.float64)
    with pytest.raises(ValueError, match="rows"):
        IpoptMPC(mpc, n_rows=8).plan(torch.as_tensor(env.state()), contacts, p, quat)
    with pytest.raises(ValueError, match="q"):
        baseline.plan(torch.zeros(15), contacts, p, quat)
    with pytest.raises(ValueError, match="tip_height"):
        IpoptMPC(mpc, n_rows=40, tip_height=(0.1, 0.0))


@pytest.mark.parametrize("hand", ["trifinger", "allegro"])
def test_a_hands_nlp_steps_and_solves_as_our_mpc_in_both_formulations(hand):
    """Allegro trial 0 of the stick and TriFinger trial 0 of the cube, a few steps in: the NLP's
    step is the complementarity-free step through CasADi forward kinematics, and IPOPT on
    either formulation reaches the optimum our L-BFGS reaches."""
    suite, obj = SUITES[hand], {"trifinger": "cube", "allegro": "stick"}[hand]
    env = suite.make_env(obj)
    initial, target = suite.sample(env, suite.tasks[0], obj, 0)
    env.reset(initial, target)
    for _ in range(3):  # let the object settle into the fingers' grip
        env.step(np.zeros(env.hand.n_joints))
    mpc = suite.make_mpc(obj, None, plant=env, compile=False, max_iter=200)
    q, contacts = torch.as_tensor(env.state()), env.contacts(torch.float64)
    assert env.detector.found >= 2
    p, quat = torch.as_tensor(target[:3]), torch.as_tensor(target[3:])
    rows = mpc.frozen_rows(q, contacts)

    def cost(controls):
        controls = torch.as_tensor(controls, dtype=torch.float64)[None]
        return float(mpc.objective(controls, q, rows, p, quat)[0])

    ours = mpc.plan(q, contacts, p, quat)
    bound = float(mpc.upper.max())
    u = bound * np.linspace(-0.8, 0.8, env.hand.n_joints)
    for formulation in FORMULATIONS:
        baseline = IpoptMPC(mpc, env.detector.slots * 4, max_iter=200, formulation=formulation)
        params = baseline.parameters(q, contacts, p, quat)
        model_rows = params[q.shape[0] + 7 :]  # after q and the target
        predicted = np.asarray(baseline.step_function(q.numpy(), u, model_rows)).ravel()
        held = torch.as_tensor(u).expand(mpc.horizon, -1)[None]
        expected = mpc.rollout(q, held, rows)[0, 1].numpy()
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
