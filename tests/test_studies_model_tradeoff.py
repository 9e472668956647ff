"""Speed–accuracy trade-off: the quick run end to end, the Pareto front, the dominance
statements, the MuJoCo box-pushing reference, agreement with ``learn-k``'s errors, the options."""

from __future__ import annotations

import csv
import json
import math

import pytest
import torch

from studies import model_tradeoff as to
from torchcontact.checkpoint import constant_model
from torchcontact.learn.evaluate import one_step_error, rollout_error
from torchcontact.learn.fit import StepData
from torchcontact.sim import box_pushing as bp

ERRORS = [f"{g}_{k}" for g in ("one_step", "h10") for k in ("pos_mm", "angle_deg", "combined")]
TRAJECTORY = [f"traj_{k}" for k in ("pos_mm", "angle_deg", "combined")]


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """``--quick`` over every scene: the output folder and the CSV rows."""
    out = tmp_path_factory.mktemp("tradeoff")
    assert to.main(["--quick", "--out", str(out), "--no-progress"]) == 0
    with open(out / "tradeoff.csv") as f:
        return out, list(csv.DictReader(f))


def test_quick_run_has_every_setting_with_finite_errors(quick):
    out, rows = quick
    meta = json.loads((out / "tradeoff.json").read_text())
    assert set(meta["scenes"]) == set(to.SCENES)
    for scene in to.SCENES:
        info = meta["scenes"][scene]
        expected = to.settings_grid(info["stiffness"], info["damping_ratio"], quick=True)
        got = [r for r in rows if r["scene"] == scene]
        assert sorted(r["label"] for r in got) == sorted(s.label for s in expected)
        for row in got:
            assert float(row["call_ms"]) > 0 and float(row["sample_ms"]) > 0
            assert float(row["sample_ms"]) == pytest.approx(
                float(row["call_ms"]) / int(row["batch"]), rel=1e-9
            )
            full_dynamic = scene in ("sliding_cube", "falling_cube")
            for key in ERRORS + (TRAJECTORY if full_dynamic else []):
                assert math.isfinite(float(row[key])), (row["label"], key)
            if not full_dynamic:
                assert all(row[key] == "" for key in TRAJECTORY)
    for name in ("pareto_one_step.png", "pareto_h10.png", "tradeoff.md"):
        assert (out / name).stat().st_size > 0


def test_batch_sizes_share_errors_and_qp_runs_once_per_state(quick):
    _, rows = quick
    by_label = {(r["scene"], r["label"]): r for r in rows}
    for (scene, label), row in by_label.items():
        if label.endswith(" b1"):
            batched = by_label[(scene, label[: -len(" b1")] + " b1024")]
            assert all(batched[key] == row[key] for key in ERRORS)
        if row["model"] == "qp":
            assert row["batch"] == "1" and row["dtype"] == "float64"


def test_pareto_front_on_a_hand_example():
    points = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (2.0, 3.0), (5.0, 1.0)]
    points += [(math.nan, 0.0), (0.5, math.nan)]
    # (3, 4) is beaten by (2, 3); (5, 1) by (4, 1); equal points both stay; NaNs never count.
    assert to.pareto_front(points) == [0, 1, 4, 3]
    assert to.pareto_front([]) == []


def _row(scene, model, ms, error, batch=1, label=None):
    return {
        "scene": scene,
        "model": model,
        "label": label or f"{model} {ms} {error} b{batch}",
        "batch": batch,
        "sample_ms": ms,
        "one_step_combined": error,
        "h10_combined": error,
    }


def test_dominance_is_derived_from_the_rows():
    rows = [
        _row("a", "qp", 1.0, 0.1, label="QP a"),
        _row("a", "cf", 0.5, 0.05, label="CF fast and accurate"),
        _row("a", "cf", 0.2, 0.2, label="CF fast only"),
        _row("a", "cf", 2.0, 0.01, label="CF accurate only"),
        _row("a", "cf", 0.01, 0.1, batch=1024, label="CF batched"),
        _row("b", "qp", 1.0, 0.01, label="QP b"),
        _row("b", "cf", 0.5, 0.1, label="CF b fast"),
        _row("b", "cf", 3.0, 0.005, label="CF b accurate"),
    ]
    a, b = to.dominance(rows, "h10")
    assert (a["qp"], a["dominated_b1"], a["dominated_any"], a["cf_b1"]) == ("QP a", 1, 2, 3)
    assert a["best_b1"] == ("CF fast and accurate", 0.5, 0.05)
    assert (b["dominated_b1"], b["dominated_any"]) == (0, 0)
    assert b["most_accurate_faster_b1"] == ("CF b fast", 0.5, 0.1)
    assert b["fastest_as_accurate_b1"] == ("CF b accurate", 3.0, 0.005)
    meta = {"command": "test", "load_average": [1.0, 1.0], "cpus": 2, "scenes": {}}
    text = to.summary_markdown(rows, meta)
    section_a, section_b = text.split("## a")[1].split("## b")
    assert "CF dominates 1 of 1 QP settings" in section_a
    assert "most accurate: CF fast and accurate" in section_a
    assert "CF dominates 0 of 1 QP settings" in section_b
    assert "the fastest CF at least as accurate is CF b accurate at 3 ms" in section_b
    # A change in the rows changes the statement: make the QP of scene b slower than CF b.
    rows[5] = _row("b", "qp", 5.0, 0.01, label="QP b")
    assert to.dominance(rows, "h10")[1]["dominated_b1"] == 1


def test_box_pushing_reference_drives_the_bar_and_pushes_the_cubes():
    config = bp.BoxPushingConfig(cubes=2)
    states = to.box_pushing_reference(config, steps=30)
    scene = bp.build_scene(config)
    bar = states[:, scene.bar_q]
    expected = bar[0] + config.push * torch.arange(31).numpy()
    assert abs(bar - expected).max() < 1e-12
    x = states[:, scene.cube_q[:, 0].numpy()]
    # The bar meets the first cube after its 1 cm gap (10 steps), the second 10 steps later.
    assert -0.0215 < x[-1, 0] - x[0, 0] < -0.0185
    assert -0.0115 < x[-1, 1] - x[0, 1] < -0.0085
    z = states[:, scene.cube_q[:, 2].numpy()]
    assert abs(z - config.edge / 2).max() < 1e-3


def test_hand_errors_line_up_with_learn_k(quick):
    out, _ = quick
    scene = to.build_scene("trifinger", to.QUICK, out / "data", progress=False)
    meta = scene.transitions.meta
    setting = to.Setting("cf", 4, gamma=meta["gamma"], stiffness=scene.stiffness, damping=0.1)
    errors = to.errors(scene, to.build_model(setting), setting)
    model = constant_model(scene.stiffness, meta)
    data = StepData.from_transitions(scene.transitions, dtype=torch.float64)
    reference = one_step_error(model, data, scene.weights)
    assert errors["one_step_combined"] == pytest.approx(reference["combined"], rel=1e-6)
    # learn-k re-detects the first step's contacts; here they are the recorded float32 ones.
    rollout = rollout_error(model, scene.transitions, scene.detector, to.HORIZON, to.QUICK.stride)
    assert errors["h10_pos_mm"] == pytest.approx(rollout["pos_mm"], rel=1e-3)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--scenes", "box_pushing", "nope"], "--scenes: unknown ['nope']"),
        (["--device", "tpu"], "--device: unknown ['tpu']"),
        (["--batch", "1"], "--batch must be at least 2"),
    ],
)
def test_bad_options_error_clearly(argv, message, capsys):
    with pytest.raises(SystemExit) as error:
        to.parse_args(argv)
    assert error.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here")
def test_cuda_without_a_gpu_errors_clearly(capsys):
    with pytest.raises(SystemExit):
        to.parse_args(["--device", "cuda"])
    assert "no CUDA device is available" in capsys.readouterr().err


def test_out_must_be_a_directory(tmp_path, capsys):
    path = tmp_path / "file"
    path.write_text("")
    with pytest.raises(SystemExit):
        to.parse_args(["--out", str(path)])
    assert "is not a directory" in capsys.readouterr().err
