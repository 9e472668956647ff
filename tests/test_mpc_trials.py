"""The trial API: a configuration in, a record out; parallel runs, resuming, legacy records; and
the summary of a sweep's records."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import trimesh

from torchcontact.cli.run import print_summary
from torchcontact.environments import environment
from torchcontact.environments.fingertips import FINGERTIPS, STIFFNESS
from torchcontact.environments.presets import PAPER, MPCSettings
from torchcontact.model import ComplementarityFree, RelaxedQP
from torchcontact.mpc import trials
from torchcontact.mpc.model_options import ModelOptions
from torchcontact.mpc.models import DEFAULT_MODEL, MPC_MODELS
from torchcontact.mpc.records import RecordMismatch, finished_record, record_status
from torchcontact.mpc.report import csv_row, summarize
from torchcontact.mpc.trial_config import (
    LEGACY_DEFAULTS,
    REMOVED_OPTIONS,
    SCENES_VERSION,
    TrialConfig,
    TrialRecord,
    trial_configs,
    trial_inputs,
)
from torchcontact.mpc.trials import build_trial, run_trial, run_trials
from torchcontact.relaxed_qp import PAPER_RELAXATION, paper_relaxation
from torchcontact.results import write_json
from torchcontact.shipped import SHIPPED

CONFIG = TrialConfig(
    env="fingertips",
    task="rotation",
    object="cube",
    seed=0,
    max_steps=5,
    settings=MPCSettings(max_iter=5, compile=False),
    model_options=ModelOptions(stiffness=STIFFNESS),
)
TWO = [CONFIG, dataclasses.replace(CONFIG, seed=1)]
FAST = trial_configs(
    "fingertips", [("rotation", "cube")], range(1), MPCSettings(max_iter=5, compile=False),
    max_steps=3,
)  # fmt: skip
TIMINGS = {"detect_ms", "solve_ms", "sim_ms"}


def _untimed(records: list[TrialRecord]) -> list[dict]:
    return [{k: v for k, v in r.to_dict().items() if k not in TIMINGS} for r in records]


def _run(configs, out, **options) -> tuple[list[TrialRecord], list[tuple[int, bool]]]:
    """``run_trials`` into ``out``, with the (seed, reused) of each record as it came."""
    seen = []
    records = run_trials(
        configs,
        out=out,
        progress=False,
        on_record=lambda record, reused: seen.append((record.config.seed, reused)),
        **options,
    )
    return records, seen


@pytest.fixture(scope="module")
def serial() -> list[TrialRecord]:
    """Trials 0 and 1 run one after the other in this process, writing nothing."""
    return run_trials(TWO, progress=False)


def test_the_trials_module_provides_the_names_users_import_from_it():
    from torchcontact.mpc import trial_config

    users = ("TrialConfig", "TrialRecord", "trial_configs", "trial_inputs", "library_versions")
    assert {*users, "run_trials", "build_trial", "run_trial"} <= set(trials.__all__)
    assert all(getattr(trials, name) is getattr(trial_config, name) for name in users)


def test_a_config_builds_its_environment_plant_and_mpc():
    env, plant, mpc = build_trial(CONFIG)
    assert env is FINGERTIPS and plant.object.name == "cube"
    assert isinstance(mpc.model, ComplementarityFree)
    assert (mpc.horizon, mpc.planner.max_iter, mpc.planner.memory) == (4, 5, 8)
    assert not mpc.compiled and mpc.gaps == "frozen"
    assert CONFIG.settings == dataclasses.replace(
        env.preset(), max_iter=5, dtype="float64", compile=False, gaps="frozen", memory=8
    )
    assert CONFIG.variant == "fingertips" and CONFIG.name == "fingertips_rotation_cube_seed0"


def test_trial_configs_fill_in_the_environments_defaults(tmp_path):
    env = environment("trifinger")
    configs = trial_configs("trifinger", [("in-hand", "cube"), ("in-hand", "mug")], range(2))
    assert [(c.task, c.object, c.seed) for c in configs] == [
        ("in-hand", obj, seed) for obj in ("cube", "mug") for seed in (0, 1)
    ]
    first = configs[0]
    assert first.settings == env.preset() and first.max_steps == env.criterion.max_steps
    # the TriFinger ships a learned model: the default plans with it, not with a constant K
    model = first.model_options
    assert model.model == DEFAULT_MODEL and model.stiffness is None and model.learned == SHIPPED
    assert model.relaxation is None and first.variant == "trifinger"
    (allegro,) = trial_configs("allegro", [("on-palm", "cube")], [0])
    assert allegro.model_options.stiffness == environment("allegro").default_stiffness == 0.5
    assert allegro.model_options.learned is None
    qp = ModelOptions(model="relaxed_qp")
    (qp,) = trial_configs("fingertips", [("rotation", "cube")], [3], PAPER, 7, model_options=qp)
    assert (qp.seed, qp.max_steps, qp.settings) == (3, 7, PAPER)
    assert qp.model_options.relaxation == PAPER_RELAXATION and qp.model_options.stiffness is None
    (tmp_path / "model.pt").write_bytes(b"")  # only named here: trial_configs asks it exists
    given = ModelOptions(learned=str(tmp_path / "model.pt"))
    (learned,) = trial_configs("fingertips", [("rotation", "cube")], [0], model_options=given)
    assert learned.model_options.stiffness is None and learned.variant == "fingertips_learned"


def test_the_relaxed_qp_takes_the_papers_kappa_at_the_objects_step():
    """κ is converted for the plant's model step: the foam brick's h is 0.05 s, not 0.1 s."""
    assert tuple(MPC_MODELS) == ("paper", "relaxed_qp") and DEFAULT_MODEL == "paper"
    qp = ModelOptions(model="relaxed_qp", relaxation=2e-4)
    config = dataclasses.replace(CONFIG, object="foam_brick", model_options=qp)
    env, plant, mpc = build_trial(config)
    assert env.h(plant) == 0.05 and isinstance(mpc.model, RelaxedQP)
    assert mpc.model.relaxation == pytest.approx(paper_relaxation(0.05, 2e-4))
    assert config.name == "fingertips_relaxed_qp_rotation_foam_brick_seed0"
    paper_kappa = ModelOptions(model="relaxed_qp", relaxation=PAPER_RELAXATION)
    assert dataclasses.replace(config, model_options=paper_kappa).variant == (
        "fingertips_relaxed_qp"
    )


def test_a_trial_runs_to_its_step_limit_and_records_it(serial):
    record = serial[0]
    assert record.config == CONFIG
    assert record.steps == 5 and not record.success  # 5 steps are too few
    assert all(len(getattr(record, key)) == 5 for key in (*TIMINGS, "iterations"))
    assert all(0 < n <= CONFIG.settings.max_iter for n in record.iterations)
    assert record.pos_err_mm > 0 and record.angle_err_deg > 0
    env = environment("fingertips")
    plant = env.make_plant("cube")
    initial, target = env.sample(plant, "rotation", 0)
    # (to rounding: the plant normalises the quaternions it is given)
    np.testing.assert_allclose(record.initial_pose, initial, rtol=0, atol=1e-12)
    np.testing.assert_allclose(record.target_pose, target, rtol=0, atol=1e-12)
    assert record.aim_pose == record.target_pose  # a rotation target rests already
    assert record.fell is False  # the ground holds it
    assert record.contact_slots == plant.detector.slots
    assert 0 < record.contacts_found_mean <= record.contacts_found_max


def test_a_trial_depends_only_on_its_config(serial):
    """Run again on the MPC of another trial's setup, trial 0 gives the same record."""
    env, plant, mpc = build_trial(CONFIG)
    run_trial(TWO[1], env, plant, mpc)
    assert _untimed([run_trial(CONFIG, env, plant, mpc)]) == _untimed(serial[:1])


def test_a_record_round_trips_through_its_dict_and_json(serial):
    record = serial[0]
    assert TrialRecord.from_dict(record.to_dict()) == record
    assert TrialRecord.from_dict(json.loads(json.dumps(record.to_dict()))) == record
    # a user robot's fingertip sites come back from JSON's list as the config's tuple
    custom = dataclasses.replace(
        record,
        config=dataclasses.replace(CONFIG, env="custom", robot="/hand.xml", tips=("a", "b")),
    )
    assert TrialRecord.from_dict(json.loads(json.dumps(custom.to_dict()))) == custom


def test_parallel_workers_give_the_serial_records(serial):
    parallel = run_trials(TWO, workers=2, progress=False)
    assert [r.config for r in parallel] == TWO  # in the configs' order
    assert len(serial) == 2 and _untimed(parallel) == _untimed(serial)
    assert _untimed(serial[:1]) != _untimed(serial[1:])  # two different trials


def test_a_second_run_reuses_the_records_and_runs_nothing(tmp_path, serial):
    first, seen = _run(TWO, tmp_path)
    assert seen == [(0, False), (1, False)]
    assert _untimed(first) == _untimed(serial)
    paths = sorted((tmp_path / "trials").glob("*.json"))
    assert [p.name for p in paths] == [f"{c.name}.json" for c in TWO]
    again, seen = _run(TWO, tmp_path)
    assert seen == [(0, True), (1, True)]
    assert again == first  # timings too: read back, not run
    assert finished_record(paths[0], CONFIG) == first[0]


def test_an_interrupted_sweep_resumes_without_redoing_finished_trials(tmp_path):
    _run(TWO[:1], tmp_path)
    records, seen = _run(TWO, tmp_path)
    assert seen == [(0, True), (1, False)]
    assert [r.config for r in records] == TWO


def test_a_record_of_other_settings_refuses_the_run_before_anything_runs(tmp_path):
    """Another ``max_steps`` in the same folder would overwrite the record: the run is refused,
    naming the file, the field (old → new) and what to do, before its other trial runs."""
    _run([CONFIG], tmp_path)
    path = tmp_path / "trials" / f"{CONFIG.name}.json"
    before = path.read_bytes()
    longer = dataclasses.replace(CONFIG, max_steps=6)
    assert finished_record(path, longer) is None
    fresh = dataclasses.replace(longer, seed=1)  # would run first, were the run not refused
    seen = []
    with pytest.raises(RecordMismatch, match=r"max_steps 5 → 6") as error:
        run_trials([fresh, longer], out=tmp_path, progress=False, on_record=seen.append)
    assert str(path) in str(error.value) and "--out" in str(error.value)
    assert seen == [] and path.read_bytes() == before
    assert sorted(p.name for p in (tmp_path / "trials").iterdir()) == [path.name]
    (record,), seen = _run([longer], tmp_path / "other")  # another folder: runs
    assert seen == [(0, False)] and record.steps == 6


def _strip(tmp_path, config: TrialConfig, keys) -> dict:
    """Delete ``keys`` from the saved record of ``config``, as records written before them lack."""
    path = tmp_path / "trials" / f"{config.name}.json"
    record = json.loads(path.read_text())
    path.write_text(json.dumps({k: v for k, v in record.items() if k not in keys}))
    return record


def test_records_written_before_the_solver_options_still_resume(tmp_path):
    """Records lacking a key count as its value before the option existed (frozen gaps, the
    paper's memory and horizon, no learned model, L-BFGS, a built-in robot)."""
    _run([CONFIG], tmp_path)
    keys = ("relaxation", "memory", "horizon", "gaps", "learned", "planner", "robot", "tips")
    assert set(keys) - {"relaxation"} <= set(LEGACY_DEFAULTS)
    _strip(tmp_path, CONFIG, keys)
    _, seen = _run([CONFIG], tmp_path)
    assert seen == [(0, True)]
    # another setting than the legacy one: refused, not overwritten
    with pytest.raises(RecordMismatch, match="memory 8 → 4"):
        _run(
            [
                dataclasses.replace(
                    CONFIG, settings=MPCSettings(max_iter=5, compile=False, memory=4)
                )
            ],
            tmp_path,
        )


def test_records_of_a_removed_option_resume_only_where_it_was_off(tmp_path):
    """A record holds the keys of options since removed: at the value that left them off it
    resumes, at another it was made by the option and refuses the run, naming it."""
    _run([CONFIG], tmp_path)
    path = tmp_path / "trials" / f"{CONFIG.name}.json"
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, **REMOVED_OPTIONS}))
    _, seen = _run([CONFIG], tmp_path)
    assert seen == [(0, True)]
    path.write_text(json.dumps({**record, **REMOVED_OPTIONS, "balance": 1.0}))
    with pytest.raises(RecordMismatch, match="balance 1.0 → 'an option since removed'"):
        _run([CONFIG], tmp_path)
    assert not CONFIG.matches({**record, "pose_stage": 0.5})


def test_records_with_the_models_former_names_resume(tmp_path):
    """Records name the paper's model "complementarity_free" from before ``contact_model``
    names, and lacked the key before the model option existed: both are the paper model."""
    _run([CONFIG], tmp_path)
    path = tmp_path / "trials" / f"{CONFIG.name}.json"
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "model": "complementarity_free"}))
    (resumed,), seen = _run([CONFIG], tmp_path)
    assert seen == [(0, True)] and resumed.config.model_options.model == "paper"
    _strip(tmp_path, CONFIG, ("model",))
    _, seen = _run([CONFIG], tmp_path)
    assert seen == [(0, True)]


def test_records_of_older_scenes_are_set_aside_and_run_again(tmp_path, capsys):
    """A record without ``scenes`` comes from version 1 of the plants: its outcome may differ.
    It is kept beside the new one, with a warning."""
    _run([CONFIG], tmp_path)
    assert _strip(tmp_path, CONFIG, ("scenes",))["scenes"] == SCENES_VERSION
    path = tmp_path / "trials" / f"{CONFIG.name}.json"
    old = path.read_bytes()
    _, seen = _run([CONFIG], tmp_path)
    assert seen == [(0, False)]
    assert json.loads(path.read_text())["scenes"] == SCENES_VERSION
    kept = path.with_name(f"{CONFIG.name}.stale-1.json")
    assert kept.read_bytes() == old
    assert f"{path} is stale" in capsys.readouterr().out


def test_records_of_other_library_versions_are_set_aside_and_run_again(tmp_path):
    (config,) = FAST
    _run([config], tmp_path)
    path = tmp_path / "trials" / f"{config.name}.json"
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "inputs": {**record["inputs"], "torch": "1.0"}}))
    _, seen = _run([config], tmp_path)
    assert seen == [(0, False)]
    assert json.loads(path.read_text())["inputs"] == trial_inputs(config)
    kept = json.loads(path.with_name(f"{config.name}.stale-1.json").read_text())
    assert kept["inputs"]["torch"] == "1.0"


def test_records_from_before_the_collision_option_count_as_part_by_part(tmp_path):
    """Objects collided part by part before ``collision`` existed: such records resume only
    there."""
    parts = dataclasses.replace(CONFIG, collision="parts")
    _run([parts], tmp_path)
    assert _strip(tmp_path, parts, ("collision",))["collision"] == "parts"
    _, seen = _run([parts], tmp_path)
    assert seen == [(0, True)]
    with pytest.raises(RecordMismatch, match="collision 'parts' → 'hull'"):
        _run([CONFIG], tmp_path)  # the default, "hull": not over a part-by-part record


def test_workers_must_be_a_positive_integer():
    with pytest.raises(ValueError, match="workers"):
        run_trials([CONFIG], workers=0)


def test_summary_needs_records():
    with pytest.raises(ValueError, match="records"):
        summarize([])


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


def test_summary_counts_the_objects_that_end_tipped_over():
    """Tipped: the final tilt error past 45°, whatever the turn about the vertical."""
    upright, turned = [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]  # the latter 180° about z
    lying = [math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]  # 90° about x

    def record(final=upright, poses=True):
        r = {"success": False, "pos_err_mm": 1.0, "angle_err_deg": 1.0, "quat_err": 0.1,
             "steps": 1, "solve_ms": [1.0], "detect_ms": [1.0], "sim_ms": [1.0],
             "iterations": [1]}  # fmt: skip
        if poses:
            r["target_pose"] = [0.0, 0.0, 0.03, *upright]
            r["final_pose"] = [0.0, 0.0, 0.03, *final]
        return r

    assert summarize([record(), record(turned), record(lying)])["tipped"] == 1
    assert summarize([record(turned)])["tipped"] == 0
    assert summarize([record(lying), record(poses=False)])["tipped"] is None
    assert csv_row({**record(lying), "task": "t", "object": "o", "seed": 0})[
        "tilt_err_deg"
    ] == pytest.approx(90.0)


def test_solve_times_report_the_steps_planned_while_compiling_apart(capsys):
    """Steps planned eagerly while the graph compiled are not the compiled MPC's speed: the
    summary gives both medians apart, each with its count, and says so where no step was
    compiled instead of reporting the eager steps as the MPC's."""
    base = {"success": True, "pos_err_mm": 1.0, "angle_err_deg": 1.0, "quat_err": 0.1,
            "steps": 3, "detect_ms": [1.0], "sim_ms": [1.0], "iterations": [1]}  # fmt: skip
    eager_first = {**base, "solve_ms": [100.0, 120.0, 3.0], "eager_steps": [0, 1]}
    compiled = {**base, "solve_ms": [4.0, 5.0, 6.0], "eager_steps": []}
    all_eager = {**base, "solve_ms": [90.0, 110.0], "eager_steps": [0, 1]}
    summary = summarize([eager_first, compiled, all_eager])
    assert (summary["solve_ms_median"], summary["solve_steps"]) == (4.5, 4)
    assert (summary["eager_solve_ms_median"], summary["eager_steps"]) == (105.0, 4)
    alone = summarize([all_eager])
    assert alone["solve_ms_median"] is None and alone["solve_steps"] == 0
    assert alone["eager_solve_ms_median"] == 100.0
    older = {**base, "solve_ms": [2.0, 7.0]}  # records from before eager steps were kept
    assert summarize([older])["solve_ms_median"] == 4.5 and summarize([older])["eager_steps"] == 0
    assert summarize([older])["eager_solve_ms_median"] is None
    print_summary(alone, [("rotation", "cube")])
    printed = capsys.readouterr().out
    assert "no step was compiled" in printed and "median 100.0 ms" in printed
    print_summary(summary, [("rotation", "cube")])
    printed = capsys.readouterr().out
    assert "median 4.5 ms" in printed and "(4 steps)" in printed and "median 105.0 ms" in printed


@pytest.fixture(scope="module")
def fast_record() -> dict:
    """The JSON of trial 0 of :data:`FAST`, run once, writing nothing."""
    (record,) = run_trials(FAST, progress=False)
    return json.loads(json.dumps(record.to_dict()))


def _record_path(folder, config: TrialConfig):
    return folder / "trials" / f"{config.name}.json"


def test_a_truncated_record_is_set_aside_named_and_run_again(tmp_path, capsys):
    (config,) = FAST
    _run(FAST, tmp_path)
    path = _record_path(tmp_path, config)
    for n in (1, 2):  # a second corrupt record does not overwrite the first one set aside
        truncated = path.read_bytes()[: len(path.read_bytes()) // 2]
        path.write_bytes(truncated)
        _, seen = _run(FAST, tmp_path)
        assert seen == [(0, False)]
        out = capsys.readouterr().out
        assert f"{path} is corrupt (not valid JSON" in out and f".corrupt-{n}.json" in out
        assert path.with_name(f"{config.name}.corrupt-{n}.json").read_bytes() == truncated
        assert finished_record(path, config) is not None  # the rerun's record, valid


def _mutations(record: dict) -> list:
    missing = {k: v for k, v in record.items() if k != "pos_err_mm"}
    return [
        ([1, 2], "a JSON list, not an object"),
        (missing, "pos_err_mm must be number, got missing"),
        ({**record, "steps": "3"}, "steps must be int"),
        ({**record, "success": 1}, "success must be bool"),
        ({**record, "final_pose": record["final_pose"][:6]}, "final_pose must be pose"),
        ({**record, "pos_err_mm": None}, "pos_err_mm must be number"),  # a NaN written as null
        ({**record, "quat_err": float("nan")}, "quat_err is not finite"),
        ({**record, "aim_pose": [float("inf")] * 7}, "aim_pose is not finite"),
        ({**record, "inputs": ["x"]}, "inputs must be an object"),
    ]


@pytest.mark.parametrize("index", range(9))
def test_a_record_of_the_wrong_shape_or_not_finite_counts_as_corrupt(tmp_path, fast_record, index):
    (config,) = FAST
    bad, why = _mutations(fast_record)[index]
    path = _record_path(tmp_path, config)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(bad))  # json writes NaN and Infinity literals
    status, found = record_status(path, config, trial_inputs(config))
    assert status == "corrupt" and why in found
    assert finished_record(path, config) is None
    assert record_status(path.with_name("absent.json"), config, {})[0] == "run"


@pytest.mark.parametrize("index", [0, 6])
def test_a_wrong_shape_or_non_finite_record_does_not_block_the_sweep(tmp_path, fast_record, index):
    (config,) = FAST
    bad, _ = _mutations(fast_record)[index]
    path = _record_path(tmp_path, config)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(bad))
    (record,), seen = _run(FAST, tmp_path)
    assert seen == [(0, False)] and np.isfinite(record.pos_err_mm)
    assert path.with_name(f"{config.name}.corrupt-1.json").read_text() == json.dumps(bad)
    assert finished_record(path, config) == record


def test_a_trial_with_a_non_finite_outcome_raises_and_writes_no_record(tmp_path, monkeypatch):
    (config,) = FAST
    monkeypatch.setattr(trials.tasks, "position_error", lambda *args: np.float64("nan"))
    with pytest.raises(ValueError, match=f"trial {config.name} .*non-finite pos_err_mm"):
        run_trials(FAST, out=tmp_path, progress=False)
    assert not _record_path(tmp_path, config).exists()


def _fake_record(folder, fast_record: dict, config: TrialConfig):
    """A record of ``config`` with ``fast_record``'s outcome and ``config``'s current inputs,
    written where a run of ``config`` into ``folder`` looks for it."""
    outcome = TrialRecord.from_dict(fast_record)
    record = dataclasses.replace(outcome, config=config, inputs=trial_inputs(config))
    return write_json(_record_path(folder, config), record.to_dict())


@pytest.mark.parametrize("field", ["object", "learned"])
def test_a_changed_mesh_or_checkpoint_at_the_same_path_refuses_the_run(
    tmp_path, fast_record, field
):
    """The record of a mesh (or retrained checkpoint) is reused while the file is the same and
    refused once its content changed: its SHA-256 differs."""
    (config,) = FAST
    file = tmp_path / ("cube.stl" if field == "object" else "model.pt")
    file.write_bytes(b"first version")
    if field == "object":
        config = dataclasses.replace(config, env="trifinger", object=str(file))
    else:
        config = dataclasses.replace(config, model_options=ModelOptions(learned=str(file)))
    path = _fake_record(tmp_path / "out", fast_record, config)
    before = path.read_bytes()
    (reused,), seen = _run([config], tmp_path / "out")
    assert seen == [(0, True)] and reused.inputs[f"{field}_sha256"] is not None
    file.write_bytes(b"second version")
    pattern = rf"inputs\.{field}_sha256 [0-9a-f]{{12}}… → [0-9a-f]{{12}}…"
    with pytest.raises(RecordMismatch, match=pattern) as error:
        _run([config], tmp_path / "out")
    assert path.read_bytes() == before
    assert str(path) in str(error.value)


def test_a_record_without_inputs_is_of_an_older_release_and_run_again(tmp_path, fast_record):
    (config,) = FAST
    legacy = {k: v for k, v in fast_record.items() if k != "inputs"}
    path = _record_path(tmp_path, config)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(legacy))
    # no versions recorded: as stale as a record of other versions, even naming no file
    status, differences = record_status(path, config, trial_inputs(config))
    assert status == "stale" and list(differences) == ["inputs"]
    mesh = tmp_path / "cube.stl"
    mesh.write_bytes(b"mesh")
    config = dataclasses.replace(config, env="trifinger", object=str(mesh))
    path.write_text(json.dumps({**legacy, "env": "trifinger", "object": str(mesh)}))
    status, differences = record_status(path, config, trial_inputs(config))
    assert status == "stale" and list(differences) == ["inputs"]  # set aside and run again


def test_a_mesh_named_like_a_builtin_object_gets_its_own_record_name():
    builtin = dataclasses.replace(CONFIG, env="trifinger")
    here = dataclasses.replace(builtin, object="cube.stl")
    there = dataclasses.replace(builtin, object="/meshes/cube.stl")
    assert builtin.name == "trifinger_rotation_cube_seed0"  # built-in names as before
    assert here.name.startswith("trifinger_rotation_cube-mesh-") and here.name.endswith("_seed0")
    assert len({builtin.name, here.name, there.name}) == 3


def test_two_configs_writing_one_record_are_refused(tmp_path):
    other_k = dataclasses.replace(CONFIG, model_options=ModelOptions(stiffness=1.0))
    with pytest.raises(ValueError, match=f"same record {CONFIG.name}.json.*stiffness"):
        run_trials([CONFIG, other_k], out=tmp_path, progress=False)


def test_the_summary_of_a_pair_without_success_is_written_with_null(tmp_path, fast_record):
    assert not fast_record["success"]  # 3 steps are too few
    summary = summarize([fast_record, fast_record])
    assert np.isnan(summary["pos_err_mm_mean_success"])
    text = write_json(tmp_path / "summary.json", {**summary, "pairs": {"p": summary}}).read_text()
    assert "NaN" not in text and "Infinity" not in text

    def refuse(constant):
        raise AssertionError(f"{constant} in summary.json")

    read = json.loads(text, parse_constant=refuse)
    assert read["pos_err_mm_mean_success"] is None and read["pairs"]["p"]["trials"] == 2
    assert read["pos_err_mm_mean"] == pytest.approx(fast_record["pos_err_mm"])


def test_a_resumed_sweep_handles_a_truncated_record_other_settings_and_a_changed_mesh(tmp_path):
    """The three ways a sweep's folder goes stale, in one sweep of a built-in object and a
    mesh: a changed mesh and other settings refuse the run before anything runs; a truncated
    record is set aside and rerun."""
    mesh = tmp_path / "block.stl"
    trimesh.creation.box([0.05, 0.04, 0.03]).export(mesh)
    settings = MPCSettings(max_iter=3, compile=False)
    pairs = [("in-hand", "cube"), ("in-hand", str(mesh))]
    configs = trial_configs("trifinger", pairs, range(1), settings, max_steps=2)
    out = tmp_path / "out"
    _run(configs, out)
    cube, block = (out / "trials" / f"{c.name}.json" for c in configs)
    cube.write_text(cube.read_text()[:40])  # truncated
    trimesh.creation.box([0.05, 0.04, 0.035]).export(mesh)  # changed at the same path
    with pytest.raises(ValueError, match="object_sha256"):
        _run(configs, out)
    assert len(cube.read_text()) == 40  # refused before anything ran: the record untouched
    trimesh.creation.box([0.05, 0.04, 0.03]).export(mesh)  # the mesh as it was
    _, seen = _run(configs, out)
    assert sorted(seen) == [(0, False), (0, True)]  # the cube rerun, the block reused
    assert list((out / "trials").glob("*.corrupt-*.json"))
    longer = trial_configs("trifinger", pairs, range(1), settings, max_steps=3)
    with pytest.raises(ValueError, match="max_steps 2 → 3"):
        _run(longer, out)
