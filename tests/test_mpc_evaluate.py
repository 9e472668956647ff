"""``torchcontact run fingertips``: one short trial end to end, its files, and resuming."""

import json
from pathlib import Path

import pytest

from torchcontact.cli import main
from torchcontact.mpc import evaluate
from torchcontact.mpc.evaluate import SUMMARY_KEYS, parse_args, summarize
from torchcontact.mpc.suites import SCENES_VERSION
from torchcontact.relaxed_qp import PAPER_RELAXATION

ARGS = ["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "1"]
FAST = ["--max-steps", "15", "--max-iter", "5", "--no-compile", "--no-progress"]


def test_one_short_trial_writes_summary_table_and_plot(tmp_path, capsys):
    summary_path = tmp_path / "summary.json"
    assert main([*ARGS, *FAST, "--out", str(tmp_path / "out"), "--json", str(summary_path)]) == 0
    summary = json.loads(summary_path.read_text())
    assert set(SUMMARY_KEYS) <= set(summary)
    assert summary["trials"] == 1 and summary["success_rate"] == 0.0  # 15 steps are too few
    assert summary["solve_ms_median"] > 0 and summary["pos_err_mm_mean"] > 0
    out = tmp_path / "out"
    assert (out / "trials.csv").read_text().startswith("task,object,seed,success")
    assert (out / "results.png").stat().st_size > 0
    record = json.loads((out / "trials" / "fingertips_rotation_cube_seed0.json").read_text())
    assert record["steps"] == 15 and len(record["solve_ms"]) == 15
    assert record["aim_pose"] == record["target_pose"]  # a rotation target rests already
    assert record["fell"] is False and summary["falls"] == 0  # the ground holds it
    printed = capsys.readouterr().out
    assert "rotation" in printed and "success 0.0% of 1" in printed


def test_finished_trials_are_not_run_again(tmp_path, monkeypatch):
    out = str(tmp_path / "out")
    main([*ARGS, *FAST, "--out", out])

    def must_not_run(*args, **kwargs):
        raise AssertionError("a finished trial was run again")

    monkeypatch.setattr(evaluate, "run_trial", must_not_run)
    assert main([*ARGS, *FAST, "--out", out]) == 0
    with pytest.raises(AssertionError, match="run again"):  # other settings: a new trial
        main([*ARGS, "--max-steps", "16", *FAST[2:], "--out", out])


def test_a_short_qp_trial_is_recorded_under_its_own_name(tmp_path, capsys):
    out = tmp_path / "out"
    fast = ["--max-steps", "5", *FAST[2:]]
    assert main([*ARGS, *fast, "--model", "qp", "--out", str(out)]) == 0
    record = json.loads((out / "trials" / "fingertips_qp_rotation_cube_seed0.json").read_text())
    assert record["model"] == "qp" and record["relaxation"] == PAPER_RELAXATION
    assert record["stiffness"] is None and record["steps"] == 5
    summary = json.loads((out / "summary.json").read_text())
    assert summary["model"] == "qp" and summary["trials"] == 1
    assert "through the qp model" in capsys.readouterr().out


def test_each_model_has_its_default_output_folder():
    assert parse_args(["fingertips"]).out == Path("results/fingertips")
    assert parse_args(["fingertips", "--model", "qp"]).out == Path("results/fingertips_qp")


def test_the_cli_plans_with_each_suites_default_k_and_learn_k_keeps_the_papers():
    from torchcontact.learn.scenes import make_scene

    assert parse_args(["fingertips"]).stiffness == 4.64  # learn-k's best constant on the cube
    assert parse_args(["trifinger"]).stiffness == parse_args(["allegro"]).stiffness == 0.5
    assert parse_args(["fingertips", "--stiffness", "1"]).stiffness == 1.0
    assert make_scene("fingertips", "cube").paper_stiffness == 1.0


def test_the_benchmark_collides_every_object_as_its_hull_as_the_paper_does():
    from torchcontact.mpc.suites import SUITES

    assert parse_args(["trifinger"]).collision == "hull"
    assert parse_args(["trifinger", "--collision", "auto"]).collision == "auto"
    mug = SUITES["trifinger"].make_env("mug")
    assert mug.object.collide_hull and len(mug.object.collision_parts) == 1
    assert not SUITES["trifinger"].make_env("mug", "auto").object.collide_hull


def test_the_qp_plans_with_frozen_gaps_whatever_the_preset():
    assert parse_args(["fingertips", "--model", "qp"]).settings.gaps == "frozen"
    assert parse_args(["fingertips", "--gaps", "propagated"]).settings.gaps == "propagated"
    assert parse_args(["fingertips", "--gaps", "frozen"]).settings.gaps == "frozen"


def test_records_written_before_the_model_and_solver_options_still_resume(tmp_path, monkeypatch):
    """Records lacking a key count as its value before the option existed (frozen gaps)."""
    out = tmp_path / "out"
    frozen = [*FAST, "--gaps", "frozen"]
    main([*ARGS, *frozen, "--out", str(out)])
    path = out / "trials" / "fingertips_rotation_cube_seed0.json"
    record = json.loads(path.read_text())
    path.write_text(
        json.dumps(
            {
                k: v
                for k, v in record.items()
                if k not in ("model", "relaxation", "memory", "horizon", "gaps")
            }
        )
    )
    monkeypatch.setattr(evaluate, "run_trial", lambda *a, **k: pytest.fail("run again"))
    assert main([*ARGS, *frozen, "--out", str(out)]) == 0


def test_records_of_older_scenes_are_run_again(tmp_path, monkeypatch):
    """A record without ``scenes`` comes from version 1 of the plants: its outcome may differ."""
    out = tmp_path / "out"
    main([*ARGS, *FAST, "--out", str(out)])
    path = out / "trials" / "fingertips_rotation_cube_seed0.json"
    record = json.loads(path.read_text())
    assert record["scenes"] == SCENES_VERSION
    path.write_text(json.dumps({k: v for k, v in record.items() if k != "scenes"}))
    reruns = []
    real = evaluate.run_trial
    monkeypatch.setattr(evaluate, "run_trial", lambda *a, **k: reruns.append(1) or real(*a, **k))
    assert main([*ARGS, *FAST, "--out", str(out)]) == 0
    assert reruns == [1] and json.loads(path.read_text())["scenes"] == SCENES_VERSION


def test_records_from_before_the_collision_option_count_as_part_by_part(tmp_path, monkeypatch):
    """Objects collided part by part before ``--collision``: such records resume only there."""
    out = tmp_path / "out"
    main([*ARGS, *FAST, "--collision", "parts", "--out", str(out)])
    path = out / "trials" / "fingertips_rotation_cube_seed0.json"
    record = json.loads(path.read_text())
    assert record["collision"] == "parts"
    path.write_text(json.dumps({k: v for k, v in record.items() if k != "collision"}))
    reruns = []
    real = evaluate.run_trial
    monkeypatch.setattr(evaluate, "run_trial", lambda *a, **k: reruns.append(1) or real(*a, **k))
    assert main([*ARGS, *FAST, "--collision", "parts", "--out", str(out)]) == 0
    assert reruns == []
    assert main([*ARGS, *FAST, "--out", str(out)]) == 0  # the default, "hull": run again
    assert reruns == [1] and json.loads(path.read_text())["collision"] == "hull"


@pytest.mark.parametrize(
    "bad, message",
    [
        (["--trials", "0"], "--trials"),
        (["--stiffness", "-1"], "--stiffness"),
        (["--task", "spin"], "--task"),
        (["--object", "teapot"], "--object"),
        (["--model", "cf"], "--model"),
        (["--model", "qp", "--stiffness", "1"], "--stiffness"),
        (["--relaxation", "1e-3"], "--relaxation"),
        (["--model", "qp", "--relaxation", "0"], "--relaxation"),
        (["--preset", "fastest"], "--preset"),
        (["--horizon", "0"], "--horizon"),
        (["--memory", "0"], "--memory"),
        (["--collision", "convex"], "--collision"),
        (["--gaps", "updated"], "--gaps"),
        (["--model", "qp", "--gaps", "propagated"], "--gaps"),
    ],
)
def test_bad_options_are_refused(tmp_path, capsys, bad, message):
    with pytest.raises(SystemExit) as exit_info:
        main(["run", "fingertips", *bad, "--out", str(tmp_path)])
    assert exit_info.value.code not in (0, None)
    assert message in capsys.readouterr().err + str(exit_info.value.code)


def test_summary_needs_records():
    with pytest.raises(ValueError, match="records"):
        summarize([])


TIMINGS = {"detect_ms", "solve_ms", "sim_ms"}


def _records(out):
    return {
        path.name: {k: v for k, v in json.loads(path.read_text()).items() if k not in TIMINGS}
        for path in sorted((out / "trials").glob("*.json"))
    }


def test_parallel_workers_give_the_serial_records(tmp_path):
    two = ["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "2"]
    main([*two, *FAST, "--out", str(tmp_path / "serial")])
    main([*two, *FAST, "--workers", "2", "--out", str(tmp_path / "parallel")])
    serial, parallel = _records(tmp_path / "serial"), _records(tmp_path / "parallel")
    assert len(serial) == 2 and serial == parallel


def test_an_interrupted_sweep_resumes_without_redoing_finished_trials(tmp_path, monkeypatch):
    out = tmp_path / "out"
    two = ["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "2"]
    original, calls = evaluate.run_trial, []

    def interrupted_after_one(config, *args, **kwargs):
        if calls:
            raise KeyboardInterrupt
        calls.append(config.seed)
        return original(config, *args, **kwargs)

    monkeypatch.setattr(evaluate, "run_trial", interrupted_after_one)
    with pytest.raises(KeyboardInterrupt):
        main([*two, *FAST, "--out", str(out)])
    assert [p.name for p in (out / "trials").glob("*.json")] == [
        "fingertips_rotation_cube_seed0.json"
    ]
    ran = []
    monkeypatch.setattr(
        evaluate, "run_trial", lambda c, *a, **k: ran.append(c.seed) or original(c, *a, **k)
    )
    assert main([*two, *FAST, "--out", str(out)]) == 0
    assert ran == [1]


def test_summary_counts_falls_and_reads_them_from_older_records():
    def record(fell=None, z_end=0.03, poses=True):
        r = {"success": False, "pos_err_mm": 1.0, "angle_err_deg": 1.0, "quat_err": 0.1,
             "steps": 1, "solve_ms": [1.0], "detect_ms": [1.0], "sim_ms": [1.0],
             "iterations": [1]}  # fmt: skip
        if poses:
            r["initial_pose"] = [0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0]
            r["final_pose"] = [0.0, 0.0, z_end, 1.0, 0.0, 0.0, 0.0]
        if fell is not None:
            r["fell"] = fell
        return r

    assert summarize([record(True), record(False), record(z_end=-0.17)])["falls"] == 2
    assert summarize([record(False), record(z_end=0.02)])["falls"] == 0
    assert summarize([record(True), record(poses=False)])["falls"] is None
