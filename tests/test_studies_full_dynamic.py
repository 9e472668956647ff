"""Full-dynamic study: short real runs of settings 1–2, the γ choice, metrics and the CLI.

Measured at the settings' constants (``python benchmarks/full_dynamic.py``):
setting 1 after 1 s, v_x = 0.854 m/s (CF), 0.333 m/s (QP, exactly the sheath plateau
gap/(2μh)) and 0.611 m/s (MuJoCo, Euler, pyramidal cone, chattering between the planes);
all three stay far below Coulomb sliding ((F − μmg)/m·t = 2.06 m/s). Setting 2: the sliding
cube's centre rises 27.6 mm (CF) and 33.1 mm (QP) above its resting height within 0.12 s.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from studies import full_dynamic as fd


@pytest.fixture(scope="module")
def sphere_result():
    """Setting 1 for 1 s (100 steps): CF, QP and MuJoCo."""
    return fd.run_setting(replace(fd.sphere_setting(), steps=100), progress=False)


def test_sphere_cf_outruns_the_qp_sheath_plateau(sphere_result):
    metrics = sphere_result["metrics"]
    cf, qp, mujoco = (metrics[k]["terminal_vx"] for k in ("cf_K20", "qp", "mujoco"))
    plateau = sphere_result["reference"]["qp_sheath_plateau_vx"]
    # The QP stalls exactly where 2μ|v_x|h fills the 2 mm gap (relaxation on both planes).
    assert qp == pytest.approx(plateau, abs=1e-3)
    assert plateau == pytest.approx(0.002 / (2 * 0.3 * 0.01))
    # CF slides 2.5x faster than the QP and within 0.35 m/s of MuJoCo (measured 0.854, 0.611).
    assert cf > 2 * qp
    assert abs(cf - mujoco) < 0.35
    # Reference the measurements above are compared with: Coulomb sliding, 2.06 m/s at 1 s.
    assert sphere_result["reference"]["coulomb_terminal_vx"] == pytest.approx(2.057, abs=1e-3)


def test_sliding_cube_cf_lifts_less_than_the_qp():
    setting = replace(fd.sliding_cube_setting(), steps=60)
    scene = fd.build_scene(setting)
    state = (setting.qpos0, setting.qvel0, setting.force, setting.steps)
    excursion = {
        name: fd.cube_metrics(
            scene, fd.rollout(fd.contact_model(setting, name, 1.0), scene, *state)
        )["height_excursion"]
        for name in ("cf", "qp")
    }
    assert excursion["cf"] < excursion["qp"]
    # The QP's relaxation launches the cube at μ|v_t| = 0.8 m/s: a ballistic 33 mm hop.
    assert excursion["qp"] == pytest.approx(0.8**2 / (2 * fd.gravity(scene)), rel=0.05)


def test_cube_gamma_must_be_sharper_than_the_row_weight():
    """At γ = 100 the softplus floor (6.9 mN a row) exceeds the 6.1 mN each of the 16 rows
    carries: a resting cube floats up; at the chosen γ = 1e4 it rests (0.1 mm penetration)."""
    setting = fd.sliding_cube_setting()
    assert fd.resting_clearance(setting, 100.0, steps=100) > 2e-3
    assert abs(fd.resting_clearance(setting, setting.gamma, steps=100)) < 5e-4


def test_metric_helpers():
    assert fd.speed_roughness(np.array([2.0, 1.5, 1.0, 0.0])) == 0.0
    assert fd.speed_roughness(np.array([2.0, 1.0, 1.5, 0.0])) == pytest.approx(1.0)
    assert fd.reversals(np.array([0.5, 0.005, -0.5, -0.2, 0.3, 0.0])) == 2
    time = np.arange(5) * 0.1
    assert fd.settling_time(time, np.array([1.0, 0.5, 0.001, 0.002, 0.0]), 0.01) == 0.2
    assert fd.settling_time(time, np.array([1.0, 0.0, 0.0, 0.0, 0.5]), 0.01) is None


def test_cli_writes_json_csv_and_png(tmp_path, capsys):
    json_path = tmp_path / "summary.json"
    out = tmp_path / "out"
    code = fd.main(
        ["--setting", "1", "--steps", "10", "--out", str(out), "--json", str(json_path)]
        + ["--no-progress"]
    )
    assert code == 0
    document = json.loads(json_path.read_text())
    (setting,) = document["settings"]
    assert setting["setting"]["number"] == 1
    assert set(setting["metrics"]) == {"cf_K20", "qp", "mujoco"}
    assert (out / "full_dynamic.json").read_text() == json_path.read_text()
    header = (out / "setting1.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["time", "cf_K20_vx", "cf_K20_z"]
    assert (out / "setting1.png").read_bytes()[:4] == b"\x89PNG"
    assert not list(out.glob(".*.tmp"))
    assert "Setting 1" in capsys.readouterr().out
