"""The CasADi/IPOPT speed baseline solves our fingertip MPC problem: same step, same optimum."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchcontact.functional import cf_velocity
from torchcontact.mpc.fingertips import fingertips_mpc
from torchcontact.mpc.hands import hand_mpc
from torchcontact.mpc.ipopt_baseline import IpoptMPC
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
    with pytest.raises(ValueError, match="fingertips"):
        IpoptMPC(hand_mpc("trifinger"), n_rows=60)
    with pytest.raises(ValueError, match="n_rows"):
        IpoptMPC(mpc, n_rows=0)
    contacts = env.contacts(torch.float64)
    with pytest.raises(ValueError, match="rows"):
        IpoptMPC(mpc, n_rows=8).plan(torch.as_tensor(env.state()), contacts, p, quat)
    with pytest.raises(ValueError, match="q"):
        baseline.plan(torch.zeros(15), contacts, p, quat)
    with pytest.raises(ValueError, match="tip_height"):
        IpoptMPC(mpc, n_rows=40, tip_height=(0.1, 0.0))


def test_the_speed_benchmark_times_both_solvers_on_one_short_trial(tmp_path):
    out = tmp_path / "speed"
    script = Path(__file__).parents[1] / "benchmarks" / "ipopt_speed.py"
    options = ["--pairs", "rotation:cube", "--seeds", "1", "--steps", "8", "--no-compile"]
    run = [sys.executable, str(script), *options, "--no-progress", "--out", str(out)]
    printed = subprocess.run(run, check=True, capture_output=True, text=True).stdout
    assert "rotation cube" in printed and "IPOPT return status" in printed
    overall = read_json(out / "ipopt_speed.json")["rows"][-1]
    assert overall["steps"] == 3 and overall["ours_ms_median"] > 0 < overall["ipopt_ms_median"]
    assert (out / "trials" / "rotation_cube_seed0_steps8.json").exists()
