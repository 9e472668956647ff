"""Box-pushing study: a short real run (N = 2), its physics, its outputs and its errors."""

from __future__ import annotations

import json

import pytest
import torch

from studies.box_pushing import contact_model, main, rollout, run
from torchcontact.sim.box_pushing import BoxPushingConfig, build_scene

STEPS = 60


@pytest.fixture(scope="module")
def short_run():
    """Both rollouts of 2 cubes for 60 steps: the figures and trajectories of :func:`run`."""
    return run(BoxPushingConfig(cubes=2, steps=STEPS), progress=False)


def test_bar_pushes_the_row_along_minus_x(short_run):
    result = short_run
    x_cf = torch.tensor(result["trajectories"]["x_cf"])  # (steps + 1, 2)
    x_qp = torch.tensor(result["trajectories"]["x_qp"])
    for x in (x_cf, x_qp):
        moved = x[-1] - x[0]
        assert moved[0] < -0.02  # the first cube is pushed from about step 10
        assert moved[1] < -0.01  # and pushes the second one (1 cm behind) from about step 25
        assert bool((x.diff(dim=0) < 1e-6).all())  # never backwards
    assert result["bar_dx_cf"] < -0.04 and result["bar_dx_qp"] < -0.04


def test_cubes_rest_on_the_ground(short_run):
    result = short_run
    # CF: K = 1 on 16 ground rows holds a 1 g cube 0.6 mm deep (measured 0.60 mm); the QP
    # (Anitescu) lifts sliding cubes by up to μ·(slide per step) (measured 0.46 mm).
    assert -1e-3 < result["ground_phi_min_cf"] <= 0
    assert result["height_error_max_cf"] < 1e-3
    assert result["height_error_max_qp"] < 1e-3
    assert result["final_angle_diff_max_deg"] < 1.0


def test_cf_and_qp_agree_roughly(short_run):
    result = short_run
    # Measured: 8.2 mm apart after 60 steps (CF's K = 1 lets the bar sink 7.7 mm into the
    # first cube); along the QP trajectory the two predictions differ by at most 0.038 m/s,
    # under the bar's 0.05 m/s.
    assert result["final_position_diff_max"] < 0.015
    assert result["linear_v_diff_max_qp_states"] < 0.05
    assert result["side_phi_min_cf"] > -0.01
    assert abs(result["cube_dx_mean_cf"] - result["cube_dx_mean_qp"]) < 0.01


def test_main_writes_its_outputs(tmp_path, capsys):
    json_path = tmp_path / "figures.json"
    argv = ["--cubes", "2", "--steps", "20", "--out", str(tmp_path), "--json", str(json_path)]
    assert main([*argv, "--no-progress"]) == 0
    assert "speedup" in capsys.readouterr().out  # the printed table
    written = json.loads(json_path.read_text())
    for key in ("cubes", "cf_ms_median", "qp_ms_median", "speedup", "detect_ms_median"):
        assert key in written
    assert written["cubes"] == 2 and written["steps"] == 20
    assert written["speedup"] == pytest.approx(written["qp_ms_median"] / written["cf_ms_median"])
    assert written["cf_ms_median"] > 0 and written["qp_ms_median"] > 0
    assert "trajectories" not in written and "timed_region" in written
    assert (tmp_path / "box_pushing.csv").read_text().startswith("cubes,cf_ms_median")
    assert (tmp_path / "box_pushing.png").stat().st_size > 10_000
    assert not list(tmp_path.glob(".*.tmp"))  # atomic writes leave no temporary file


@pytest.mark.parametrize("name", ["cf", "qp"])
def test_unpushed_cubes_stay_at_rest(name):
    config = BoxPushingConfig(cubes=2, steps=100, push=0.0)
    scene = build_scene(config)
    run = rollout(scene, contact_model(name, config), config.steps)
    drift = run.q[-1] - scene.q0
    # CF settles 0.52 mm deep (16 rows hold m·g: φ = gh²/ε − mg/(16K)); the QP stays at 0.
    assert drift.abs().max() < 1e-3
    assert min(run.phi_ground) > -1e-3
    assert run.q[-1, scene.cube_q[:, 2]].sub(config.edge / 2).abs().max() < 1e-3


def test_contact_slots_suffice_for_the_row():
    config = BoxPushingConfig(cubes=3, steps=40)
    scene = build_scene(config)
    run = rollout(scene, contact_model("cf", config), config.steps)
    assert max(run.active) <= config.slots
    assert run.q.shape == (config.steps + 1, scene.layout.nq)


@pytest.mark.parametrize("argv", [["--cubes", "0"], ["--cubes", "-3"], ["--steps", "x"]])
def test_invalid_arguments_exit_with_a_message(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert "expected a positive integer" in capsys.readouterr().err


def test_unknown_model_name_raises():
    with pytest.raises(ValueError, match="name must be 'cf' or 'qp'"):
        contact_model("lcp", BoxPushingConfig(cubes=1))
