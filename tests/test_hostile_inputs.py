"""Hostile inputs of the second audit (issue 75), each answered by one clear line before any
work, or handled as the user would expect: locks that nest, outputs that cannot be written,
checkpoints of another environment, one-line command-line errors, the trial API's arguments,
and records and datasets that know every file they were made from. None starts a process or an
MPC compile (the module runs in a few seconds); the cases that do are in
``test_hostile_processes.py``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import re
import time
from pathlib import Path

import pytest
import torch
import trimesh
from hostile_helpers import (
    FAST,
    RUN,
    SHIPPED_TRIFINGER,
    TOO_LONG,
    UNWRITABLE,
    fake_record,
    refused,
)

from torchcontact.checkpoint import CheckpointError, constant_model, load_checkpoint
from torchcontact.cli import main
from torchcontact.cli.learn_k import dataset_dir
from torchcontact.contacts import Contacts
from torchcontact.digests import content_sha256, file_sha256, loaded_files
from torchcontact.environments import environment
from torchcontact.environments.presets import MPCSettings
from torchcontact.functional import cf_velocity
from torchcontact.generated import generate
from torchcontact.integrate import JointLayout, integrate
from torchcontact.learn.data import collect
from torchcontact.model import ComplementarityFree, paper_model
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.model_options import MAX_STIFFNESS, ModelOptions
from torchcontact.mpc.models import load_learned
from torchcontact.mpc.records import RecordMismatch, record_status
from torchcontact.mpc.trial_config import trial_configs, trial_inputs
from torchcontact.mpc.trials import TrialsInterrupted, build_trial, run_trials
from torchcontact.qp import qp_solve
from torchcontact.relaxed_qp import relaxed_qp_solve
from torchcontact.results import locked_folder, read_json, writable_file, write_csv
from torchcontact.shapes import load_object, make_object
from torchcontact.shipped import SHIPPED, check_shipped, resolve_learned
from torchcontact.stiffness import ContactNetwork, StateNetwork
from torchcontact.systems import QuasiDynamic

# --- 1. two runs into one --out ------------------------------------------------------------


def test_holds_in_one_process_nest(tmp_path):
    with locked_folder(tmp_path, "--out"), locked_folder(tmp_path / ".", "out"):
        pass
    with locked_folder(tmp_path):  # released, taken again
        pass


# --- 5. output paths fail before the work ----------------------------------------------------


@pytest.mark.parametrize("option", ["--json", "--figure"])
@pytest.mark.parametrize("where", ["unwritable", "too long", "a directory"])
def test_run_refuses_an_output_it_cannot_write_before_any_trial(tmp_path, capsys, option, where):
    path = {"unwritable": UNWRITABLE, "too long": str(tmp_path / TOO_LONG), "a directory": "."}
    out = tmp_path / "out"
    refused([*RUN, "--out", str(out), option, path[where]], capsys, "run", option)
    assert not (out / "trials").exists()


@pytest.mark.parametrize("name", ["summary.json", "trials.csv", "results.png"])
def test_run_refuses_a_summary_file_that_is_a_directory_before_any_trial(tmp_path, capsys, name):
    out = tmp_path / "out"
    (out / name).mkdir(parents=True)
    last = refused([*RUN, "--out", str(out)], capsys, "run", f"--out's {name}")
    assert "must be a file path, got the directory" in last
    assert not (out / "trials").exists()


@pytest.mark.parametrize("path", [UNWRITABLE, TOO_LONG, "."])
def test_compare_refuses_a_json_it_cannot_write_before_reading_the_runs(tmp_path, capsys, path):
    path = str(tmp_path / path) if path == TOO_LONG else path
    refused(["compare", "a", "b", "--json", path], capsys, "compare", "--json")


@pytest.mark.parametrize("path", [UNWRITABLE, TOO_LONG])
def test_learn_k_refuses_a_json_it_cannot_write_before_anything(tmp_path, capsys, path):
    path = str(tmp_path / path) if path == TOO_LONG else path
    out = tmp_path / "out"
    argv = ["learn-k", "--trajectories", "3", "--steps", "12", "--no-progress", "--out", str(out)]
    refused([*argv, "--json", path], capsys, "learn-k", "--json")
    assert not (out / "data").exists()


def test_learn_k_refuses_a_data_folder_it_cannot_write_before_anything(tmp_path, capsys):
    argv = ["learn-k", "--trajectories", "3", "--steps", "12", "--no-progress"]
    refused([*argv, "--out", str(tmp_path), "--data", "/proc/no/such/data"], capsys, "learn-k",
            "--data")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("out", ["/proc/no/such/out", "a_file", "a_file/below"])
def test_run_trials_refuses_an_out_it_cannot_write_before_any_trial(tmp_path, out):
    (tmp_path / "a_file").write_text("")
    out = out if out.startswith("/") else tmp_path / out
    with pytest.raises(ValueError, match=r"^out "):
        run_trials(FAST, out=out, progress=False)


def test_the_write_probe_leaves_nothing_behind(tmp_path):
    assert writable_file("--json", tmp_path / "a" / "b" / "c.json") == tmp_path / "a/b/c.json"
    assert not list(tmp_path.iterdir())
    (tmp_path / "kept.json").write_text("{}")
    writable_file("--json", tmp_path / "kept.json")
    assert [p.name for p in tmp_path.iterdir()] == ["kept.json"]


# --- 9. one line means one line --------------------------------------------------------------

PARSER_ERRORS = [
    (["run", "fingertips", "--trials", "x"], "argument --trials: invalid int value"),
    (["run", "fingertips", "--trials", "0"], "--trials must be >= 1"),
    (["run", "fingertips", "--max-steps", "-3"], "--max-steps must be >= 1"),
    (["run", "fingertips", "--no-such-option"], "unrecognized arguments: --no-such-option"),
    (["run", "nowhere"], "argument env: invalid choice"),
    (["run", "fingertips", "--preset", "quick"], "argument --preset: invalid choice"),
    (["run", "fingertips", "--stiffness", "-1"], "--stiffness must be"),
    (["run", "fingertips", "--first-seed", "-1"], "--first-seed must be >= 0"),
    (["run", "fingertips", "--task", "fly"], "--task must be one of"),
    (["run", "fingertips", "--object", "teapot"], "--object must be one of"),
    (["run", "fingertips", "--tips", "a,b"], "--tips is for the custom environment"),
    (["run", "custom"], "--robot is required"),
    (["run", "fingertips", "--model", "relaxed_qp", "--stiffness", "3"], "--stiffness is for"),
    (["run", "fingertips", "--residual-plan", "half"], "argument --residual-plan: invalid choice"),
    (["run", "fingertips", "--workers", "0"], "--workers must be >= 1"),
    (["run", "fingertips", "--object-size", "0.1"], "--object-size/-scale/-mass/-friction"),
    (["compare"], "the following arguments are required: a, b"),
    (["learn-k", "--lr", "-1"], "--lr"),
    (["learn-k", "--scene", "moon"], "argument --scene: invalid choice"),
    (["learn-k", "--trajectories", "x"], "argument --trajectories: invalid int value"),
]


PARSER_ERRORS += [
    (
        ["run", "fingertips", "--max-iter", "0"],
        "--max-iter must be an integer from 1 to 100,000, got 0",
    ),
    (["run", "fingertips", "--memory", "0"], "--memory must be an integer from 1 to 1,000, got 0"),
    (
        ["run", "fingertips", "--horizon", "0"],
        "--horizon must be an integer from 1 to 1,000, got 0",
    ),
    (["run", "fingertips", "--relaxation", "-1"], "--relaxation must be a positive"),
    (["run", "fingertips", "--model", "relaxed_qp", "--relaxation", "nan"], "--relaxation must"),
    (["run", "trifinger", "--hold-first", "-1"], "--hold-first must be a number of contacts"),
    (["run", "trifinger", "--hold-approach", "-1"], "--hold-approach must be a weight > 0, got -1"),
    (["run", "trifinger", "--hold-approach", "0"], "--hold-approach must be a weight > 0"),
    (["run", "fingertips", "--memory", "x"], "argument --memory: invalid int value: 'x'"),
    (
        ["run", "fingertips", "--horizon", "-2"],
        "--horizon must be an integer from 1 to 1,000, got -2",
    ),
    (["run", "fingertips", "--max-iter", "1.5"], "argument --max-iter: invalid int value: '1.5'"),
    (["run", "trifinger", "--object", "random-x"], "--object must be one of"),
    (["run", "fingertips", "--model", "relaxed_qp", "--support-pass", "on"], "--support-pass on"),
    (["run", "fingertips", "--model", "relaxed_qp", "--gaps", "propagated"], "--gaps propagated"),
    (["run", "fingertips", "--model", "relaxed_qp", "--gaps", "live"], "--gaps live"),
    (["run", "fingertips", "--learned", "/no/such.pt"], "--learned must be an existing checkpoint"),
    (["run", "fingertips", "--robot", "x.xml"], "--robot is required by, and only for, the custom"),
    (["run", "fingertips", "--dtype", "float16"], "argument --dtype: invalid choice: 'float16'"),
    (["run", "fingertips", "--collision", "mesh"], "argument --collision: invalid choice"),
    (["run", "fingertips", "--backend", "threads"], "argument --backend: invalid choice"),
    (["run", "fingertips", "--address", "127.0.0.1:6379"], "address is for backend='ray'"),
    (["run", "fingertips", "--cost", "none"], "argument --cost: invalid choice: 'none'"),
    (["run", "fingertips", "--planner", "adam"], "argument --planner: invalid choice: 'adam'"),
    (["run", "fingertips", "--stiffness", "abc"], "--stiffness must be 'shipped', 'paper' or a"),
    (["run", "fingertips", "--object-mass", "0.1"], "are not for fingertips"),
    (["run", "fingertips", "--learned", "x.pt", "--stiffness", "3"], "--learned replaces"),
    (["run", "custom", "--robot", "/no/such.xml"], "--robot must be an existing MJCF file"),
    (["run", "trifinger", "--object", "random:0"], "--object: random:N needs 1 <= N <= 100000"),
    (["run", "trifinger", "--object", "random:5-2"], "--object: random:A-B needs A <= B"),
    (["run", "trifinger", "--object", "/no/such/mesh.stl"], "--object must be an existing mesh"),
    (["run", "fingertips", "--first-seed", "x"], "argument --first-seed: invalid int value"),
    (["run", "fingertips", "--trials", "1.5"], "argument --trials: invalid int value: '1.5'"),
    (["run", "trifinger", "--object-size", "-1"], "--object-size must be a positive finite number"),
    (
        ["run", "trifinger", "--object-scale", "0"],
        "--object-scale must be a positive finite number",
    ),
    (["run", "trifinger", "--object-friction", "-1"], "--object-friction must be a non-negative"),
    (["run", "trifinger", "--object-size", "0.1", "--object-scale", "2"], "size and scale both"),
    (["learn-k", "--lr", "nan"], "--lr must be a positive finite number, got nan"),
    (["run", "fingertips", "--trials", "100000000"], "--trials must be at most 1000000"),
    (["run", "fingertips", "--stiffness", "1e30"], "a positive number at most 1e+09, got 1e+30"),
    (["compare", "a"], "the following arguments are required: b"),
    (["compare", "a", "b", "c"], "unrecognized arguments: c"),
    (["learn-k", "--steps", "x"], "argument --steps: invalid int value: 'x'"),
    (["learn-k", "--steps", "0"], "--steps must be >= 1, got 0"),
    (["learn-k", "--trajectories", "0"], "--trajectories must be >= 1, got 0"),
    (["learn-k", "--seed", "-1"], "--seed must be >= 0, got -1"),
    (["learn-k", "--device", "tpu"], "--device must be cpu or cuda, got 'tpu'"),
    (["learn-k", "--actions", "fly"], "argument --actions: invalid choice: 'fly'"),
    (["learn-k", "--split", "halves"], "argument --split: invalid choice: 'halves'"),
    (["learn-k", "--epochs", "0"], "--epochs must be >= 1, got 0"),
    (["learn-k", "--batch-size", "0"], "--batch-size must be >= 1, got 0"),
    (["learn-k", "--hidden", "0"], "--hidden must be >= 1, got 0"),
    (["learn-k", "--patience", "0"], "--patience must be >= 1, got 0"),
    (["learn-k", "--stiffness", "wave"], "argument --stiffness: invalid choice: 'wave'"),
    (["learn-k", "--damping", "wave"], "argument --damping: invalid choice: 'wave'"),
    (["learn-k", "--scene", "box_pushing", "--object", "teapot"], "are cube and push only"),
    (["learn-k", "--scene", "box_pushing", "--actions", "mpc"], "--actions must be random for"),
    (["learn-k", "--calibrate", "magic"], "--calibrate must name distinct factors"),
    (["learn-k", "--workers", "0"], "--workers must be >= 1, got 0"),
    (["learn-k", "--robot-weight", "-1"], "--robot-weight must be non-negative and finite"),
    (["learn-k", "--loss-horizon", "0"], "--loss-horizon must be >= 1, got 0"),
    (["learn-k", "--residual", "-1"], "--residual must be a non-negative integer, got -1"),
    (["learn-k", "--no-such-option"], "unrecognized arguments: --no-such-option"),
    (["learn-k", "--object", ""], "--object must be one of"),
    (
        ["run", "fingertips", "--horizon", "100000000"],
        "--horizon must be an integer from 1 to 1,000, got",
    ),
    (
        ["run", "fingertips", "--memory", "100000000"],
        "--memory must be an integer from 1 to 1,000, got",
    ),
    (
        ["run", "fingertips", "--max-iter", "100000000"],
        "--max-iter must be an integer from 1 to 100,000",
    ),
]


@pytest.mark.parametrize("argv, message", PARSER_ERRORS)
def test_a_command_line_error_is_one_line_and_points_to_help(tmp_path, capsys, argv, message):
    job = argv[0]
    out = [] if job == "compare" else ["--out", str(tmp_path / "out")]
    last = refused([*argv, *out], capsys, job, "")
    assert message in last and last.endswith(f"(see torchcontact {job} --help)")
    assert "usage:" not in last


def test_an_empty_out_is_refused_instead_of_writing_into_the_current_folder(tmp_path, capsys):
    last = refused(["run", "fingertips", "--out", ""], capsys, "run", "")
    assert "--out: must name a folder, got an empty path" in last


def test_an_unknown_job_is_one_line_too(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["fly"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(err) == 1 and "invalid choice: 'fly'" in err[0]


def test_ctrl_c_in_run_trials_counts_the_records_kept(tmp_path):
    configs = trial_configs(
        "fingertips", [("rotation", "cube")], range(3), MPCSettings(compile=False), max_steps=1
    )
    for config in configs[:2]:
        fake_record(tmp_path, config)

    def interrupt(record, reused):
        if record.config.seed == 1:
            raise KeyboardInterrupt

    with pytest.raises(TrialsInterrupted, match=r"^interrupted; 2 trials kept, rerun to resume$"):
        run_trials(configs, out=tmp_path, progress=False, on_record=interrupt)


# --- 4. checkpoints checked for what they are ---------------------------------------------


@pytest.mark.parametrize("env", ["fingertips", "allegro"])
def test_a_checkpoint_of_another_environment_is_refused_in_one_line(tmp_path, capsys, env):
    argv = ["run", env, "--trials", "1", "--max-steps", "1", "--no-compile", "--no-progress"]
    argv += ["--out", str(tmp_path / "out"), "--learned", str(SHIPPED_TRIFINGER)]
    last = refused(argv, capsys, "run", "--learned")
    assert f"a checkpoint learned in the 'trifinger' environment, not '{env}'" in last
    assert not (tmp_path / "out" / "trials").exists()
    with pytest.raises(CheckpointError, match="learned in the 'trifinger' environment"):
        load_learned(str(SHIPPED_TRIFINGER), env)


def test_a_checkpoint_of_another_state_layout_is_refused(tmp_path, capsys):
    payload = torch.load(SHIPPED_TRIFINGER, weights_only=True)
    payload["meta"]["scene"] = "fingertips"  # named right, learned on the TriFinger's states
    torch.save(payload, tmp_path / "relabelled.pt")
    argv = [*RUN, "--out", str(tmp_path / "out"), "--learned", str(tmp_path / "relabelled.pt")]
    last = refused(argv, capsys, "run", "--learned")
    assert "learned on states of joints free + 9 hinge, but this scene's are free + 9 slide" in last


SHORT_FILES = ["e", "hello", "", "x\n", "PK", "\x80\x02", "{}", "version: 1\n", "\x00" * 7]


@pytest.mark.parametrize("text", SHORT_FILES)
def test_a_short_text_file_as_learned_is_refused_in_one_line(tmp_path, capsys, text):
    path = tmp_path / "model.pt"
    path.write_text(text)
    with pytest.raises(CheckpointError, match=rf"^{path}: (not a|a damaged)"):
        load_checkpoint(path)
    argv = [*RUN, "--out", str(tmp_path / "out"), "--learned", str(path)]
    last = refused(argv, capsys, "run", f"--learned: {path}: ")
    assert "checkpoint" in last


def test_the_shipped_model_is_compared_with_its_manifest(tmp_path):
    assert resolve_learned(SHIPPED, "trifinger") == str(SHIPPED_TRIFINGER)
    copy = tmp_path / "trifinger.pt"
    copy.write_bytes(SHIPPED_TRIFINGER.read_bytes())
    manifest = SHIPPED_TRIFINGER.with_suffix(".json").read_text()
    copy.with_suffix(".json").write_text(manifest)
    assert check_shipped(copy) == copy
    payload = torch.load(copy, weights_only=True)
    payload["state_dict"] = {k: v + 1e-3 for k, v in payload["state_dict"].items()}
    torch.save(payload, copy)  # retrained in place, the manifest left as it was
    digest = file_sha256(copy)
    message = rf"^shipped model {copy}: its SHA-256 {digest[:12]}… differs from its manifest's"
    with pytest.raises(ValueError, match=message):
        check_shipped(copy)
    copy.with_suffix(".json").unlink()
    with pytest.raises(ValueError, match="its manifest trifinger.json records no SHA-256"):
        check_shipped(copy)


# --- 6. the trial API checks its arguments ---------------------------------------------------

CUBE = ("fingertips", [("rotation", "cube")])

TRIAL_API_ERRORS = [
    (("trifinger", [("fly", "cube")]), {}, r"^pairs: task must be one of \("),
    (("fingertips", [("rotation", "teapot")]), {}, r"^pairs: object of task 'rotation' must be"),
    (("fingertips", [("rotation", "random-3")]), {}, r"^pairs: object of task 'rotation'"),
    (("fingertips", ["rotation"]), {}, r"^pairs must hold \(task, object\) pairs"),
    (CUBE, {"max_steps": 0}, r"^max_steps must be a positive"),
    (CUBE, {"max_steps": 2.5}, r"^max_steps must be a positive"),
    (CUBE, {"model": {"stiffness": -1}}, r"^stiffness must be 'shipped', 'paper' or a positive"),
    (CUBE, {"model": {"stiffness": "3"}}, r"^stiffness must be 'shipped', 'paper' or a positive"),
    (CUBE, {"model": {"stiffness": math.nan}}, r"^stiffness must be"),
    (CUBE, {"model": {"relaxation": 0.0}}, r"^relaxation must be"),
    (CUBE, {"model": {"model": "qp2"}}, r"^model must be one of"),
    (CUBE, {"settings": 3}, r"^settings must be MPCSettings"),
    (CUBE, {"settings": "quick"}, r"^preset must be one of"),
    (CUBE, {"seeds": [-1]}, r"^seeds must be non-negative"),
    (CUBE, {"seeds": [0.5]}, r"^seeds must be non-negative"),
    (CUBE, {"stifness": 3}, r"^options must be fields of Tri"),
    (("nowhere", [("rotation", "cube")]), {}, r"^env must be one of"),
    (("fingertips", []), {}, r"^pairs must hold at least one entry"),
    (CUBE, {"seeds": []}, r"^seeds must hold at least one"),
    (CUBE, {"model": {"learned": "/no/such.pt"}}, r"^learned \(--learn"),
]


@pytest.mark.parametrize("args, options, message", TRIAL_API_ERRORS)
def test_trial_configs_checks_its_arguments_as_the_command_line_does(args, options, message):
    seeds = options.pop("seeds", [0])
    with pytest.raises(ValueError, match=message):
        if "model" in options:  # the part refuses its values as it is made
            options["model_options"] = ModelOptions(**options.pop("model"))
        trial_configs(*args, seeds, **options)


def test_trial_configs_takes_a_presets_name_as_from_env_does():
    (config,) = trial_configs("fingertips", [("rotation", "cube")], [0], settings="fast")
    assert config.settings == environment("fingertips").preset("fast")


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("compile", "no", "compile must be True or False, got 'no'"),
        ("compile", 1, "compile must be True or False, got 1"),
        ("max_iter", True, "max_iter must be an integer from 1 to 100,000, got True"),
        ("horizon", 0, "horizon must be an integer from 1 to 1,000, got 0"),
        ("horizon", 10**8, "horizon must be an integer from 1 to 1,000, got 100000000"),
        ("memory", 1001, "memory must be an integer from 1 to 1,000, got 1001"),
        ("dtype", "float16", "dtype must be 'float32' or 'float64'"),
    ],
)
def test_mpc_settings_refuse_values_of_the_wrong_type(field, value, message):
    with pytest.raises(ValueError, match=f"^{re.escape(message)}"):
        MPCSettings(**{field: value})


@pytest.mark.parametrize(
    "configs, message",
    [
        ([dataclasses.replace(FAST[0], max_steps=0)], "max_steps must be a positive integer"),
        (["fingertips_rotation_cube_seed0"], "configs must be TrialConfig, got str"),
    ],
)
def test_run_trials_refuses_configs_it_cannot_run(tmp_path, configs, message):
    with pytest.raises(ValueError, match=f"^{message}"):
        run_trials(configs, out=tmp_path, progress=False)
    assert not (tmp_path / "trials").exists()


@pytest.mark.parametrize(
    "arguments, message",
    [
        (
            {"configs": FAST[0]},
            "configs must be a sequence of TrialConfig (a list), got TrialConfig",
        ),
        ({"out": 3}, "out must be a folder path or None, got int"),
        ({"progress": "yes"}, "progress must be True or False, got 'yes'"),
        ({"on_record": 3}, "on_record must be callable or None, got int"),
    ],
)
def test_run_trials_names_an_argument_of_the_wrong_kind(arguments, message):
    with pytest.raises(TypeError, match=f"^{re.escape(message)}$"):
        run_trials(**{"configs": FAST, "progress": False, **arguments})


@pytest.mark.parametrize(
    "arguments, error, message",
    [
        ({"env": "fingertips"}, TypeError, "env must be an Environment, got str"),
        ({"plant": "cube"}, TypeError, "plant must be a Plant (env.make_plant(...)), got str"),
        (
            {"plant": "trifinger"},
            ValueError,
            "plant must be a plant of fingertips (joints free, sl",
        ),
        ({"model": "bogus"}, ValueError, "model must be one of ['complementarity_free', "),
        ({"model": 3}, TypeError, "model must be a ContactModel, a model's name or None, got int"),
        ({"planner": 3}, TypeError, "planner must be a Planner, a planner's name or None, got 3"),
        ({"settings": 3}, TypeError, "settings must be MPCSettings, a preset's name or None"),
        ({"cost": 3}, TypeError, "cost must be a Cost (a callable), a cost's name or None, got 3"),
        ({"background_compile": "yes"}, TypeError, "background_compile must be True or False"),
    ],
)
def test_from_env_names_an_argument_of_the_wrong_kind(arguments, error, message):
    env = environment("fingertips")
    if arguments.get("plant") == "trifinger":
        arguments["plant"] = environment("trifinger").make_plant("cube")
    arguments = {"env": env, "plant": env.make_plant("cube"), **arguments}
    with pytest.raises(error, match=f"^{re.escape(message)}"):
        ContactImplicitMPC.from_env(**arguments)


def test_collect_names_an_unknown_scene(tmp_path):
    with pytest.raises(ValueError, match=r"^scene must be one of \('fingertips'"):
        collect(tmp_path, "moon")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "where, message",
    [
        ({"workers": 0}, "workers must be a positive integer"),
        ({"backend": "threads"}, "backend must be one of"),
        ({"address": "127.0.0.1:1"}, "address is for backend='ray'"),
    ],
)
def test_run_trials_checks_where_it_runs_before_writing(tmp_path, where, message):
    with pytest.raises(ValueError, match=f"^{message}"):
        run_trials(FAST, out=tmp_path, progress=False, **where)
    assert not (tmp_path / "trials").exists()


# --- 2. a record's identity covers every file its result depends on -------------------------

ROBOT = """<mujoco>
  <compiler meshdir="meshes"/>
  <include file="parts/assets.xml"/>
  <worldbody><body name="palm"><geom type="mesh" mesh="link"/></body></worldbody>
</mujoco>
"""
ASSETS = """<mujocoinclude>
  <include file="parts/more.xml"/>
  <asset><mesh name="link" file="link.stl"/><hfield name="floor" file="floor.png"/></asset>
</mujocoinclude>
"""


@pytest.fixture
def robot(tmp_path):
    """A robot MJCF that includes a file (which includes another) and names a mesh and a
    height field, under its compiler's meshdir."""
    (tmp_path / "parts").mkdir()
    (tmp_path / "meshes").mkdir()
    (tmp_path / "robot.xml").write_text(ROBOT)
    (tmp_path / "parts" / "assets.xml").write_text(ASSETS)
    (tmp_path / "parts" / "more.xml").write_text("<mujocoinclude/>\n")
    trimesh.creation.box([0.02, 0.02, 0.05]).export(tmp_path / "meshes" / "link.stl")
    (tmp_path / "meshes" / "floor.png").write_bytes(b"\x89PNG not really")
    return tmp_path / "robot.xml"


def test_an_mjcf_is_known_by_every_file_it_includes_or_names(robot):
    folder = robot.parent
    assert loaded_files(robot) == [
        folder / "parts/assets.xml",
        folder / "parts/more.xml",
        folder / "meshes/link.stl",
        folder / "meshes/floor.png",
    ]
    before = content_sha256(robot)
    assert before != file_sha256(robot)
    for changed in ("parts/more.xml", "meshes/link.stl", "meshes/floor.png"):
        path = folder / changed
        path.write_bytes(path.read_bytes() + b" ")
        assert content_sha256(robot) != before, changed
        before = content_sha256(robot)
    (folder / "meshes/floor.png").unlink()  # the loader will say so; the identity still differs
    assert content_sha256(robot) != before


def test_a_file_its_loader_reads_alone_keeps_its_plain_digest(tmp_path):
    path = tmp_path / "cube.stl"
    trimesh.creation.box([0.05] * 3).export(path)
    assert loaded_files(path) == [] and content_sha256(path) == file_sha256(path)
    (tmp_path / "broken.xml").write_text("<mujoco")  # MuJoCo reports it; no files found here
    assert loaded_files(tmp_path / "broken.xml") == []


def _gltf_box(folder: Path, size: float) -> Path:
    """A box of side ``size`` [m] as ``box.gltf`` with its geometry in ``.bin`` buffers."""
    for name, data in trimesh.creation.box([size] * 3).export(file_type="gltf").items():
        (folder / ("box.gltf" if name.endswith(".gltf") else name)).write_bytes(data)
    return folder / "box.gltf"


def test_a_record_of_a_gltf_whose_buffers_changed_refuses_the_run(tmp_path):
    """The reproduction: the .gltf is the same file, its .bin now holds an 8 cm box."""
    mesh = _gltf_box(tmp_path, 0.05)
    gltf = mesh.read_bytes()
    config = dataclasses.replace(FAST[0], env="trifinger", task="in-hand", object=str(mesh))
    fake_record(tmp_path / "out", config)
    _gltf_box(tmp_path, 0.08)
    mesh.write_bytes(gltf)  # the top file unchanged
    extents = trimesh.load(mesh, force="mesh").extents
    assert extents == pytest.approx([0.08] * 3)  # what the loader reads has changed
    with pytest.raises(RecordMismatch, match="inputs.object_sha256"):
        run_trials([config], out=tmp_path / "out", progress=False)


def test_a_record_of_a_robot_whose_included_file_changed_refuses_the_run(tmp_path, robot):
    config = dataclasses.replace(FAST[0], env="custom", robot=str(robot), tips=("tip",))
    fake_record(tmp_path / "out", config)
    (robot.parent / "parts" / "more.xml").write_text(
        "<mujocoinclude><!-- edited --></mujocoinclude>"
    )
    with pytest.raises(RecordMismatch, match="inputs.robot_sha256"):
        run_trials([config], out=tmp_path / "out", progress=False)


# --- 3. learn-k datasets know their objects by content --------------------------------------


def _data_args(tmp_path) -> argparse.Namespace:
    return argparse.Namespace(
        data=tmp_path / "data", scene="trifinger", actions="random", steps=3, seed=0
    )


def test_a_users_cube_and_the_built_in_cube_get_their_own_datasets(tmp_path):
    args = _data_args(tmp_path)
    mesh = tmp_path / "cube.stl"
    trimesh.creation.box([0.06] * 3).export(mesh)
    builtin, user = dataset_dir(args, "cube"), dataset_dir(args, str(mesh))
    assert builtin != user and user.name.startswith("trifinger_cube-mesh-")
    trimesh.creation.icosphere().apply_scale(0.03).export(mesh)  # another mesh, same box
    assert dataset_dir(args, str(mesh)) not in (builtin, user)


# --- 7. errors name the input that is wrong -------------------------------------------------

BAD_FACES = "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 2 9\nf 1 3 4\nf 2 3 4\n"
"""An OBJ mesh whose second face names a vertex it does not have."""


def test_a_checkpoint_with_nan_weights_is_named_damaged(tmp_path, capsys):
    payload = torch.load(SHIPPED_TRIFINGER, weights_only=True)
    key = next(iter(payload["state_dict"]))
    payload["state_dict"][key] = torch.full_like(payload["state_dict"][key], math.nan)
    path = tmp_path / "nan.pt"
    torch.save(payload, path)
    with pytest.raises(CheckpointError, match=f"its weights {re.escape(key)} hold NaN or Inf"):
        load_checkpoint(path)
    argv = ["run", "trifinger", "--trials", "1", "--max-steps", "1", "--no-compile"]
    last = refused([*argv, "--out", str(tmp_path / "out"), "--learned", str(path)], capsys,
                    "run", "--learned")  # fmt: skip
    assert "object_metric" not in last and "hold NaN or Inf" in last


def _contacts(**values) -> Contacts:
    fields = {
        "phi": torch.rand(2), "jac_normal": torch.randn(2, 3), "jac_tangent": torch.randn(2, 2, 3),
        "mu": torch.ones(2), "active": torch.ones(2, dtype=torch.bool),
        "frame": torch.eye(3).expand(2, 3, 3).clone(), "position": torch.zeros(2, 3),
    }  # fmt: skip
    return Contacts(**{**fields, **values})


@pytest.mark.parametrize("name", ["frame", "position", "phi", "jac_normal", "jac_tangent"])
def test_a_nan_in_a_contacts_field_is_named(name):
    value = _contacts().__getattribute__(name).clone()
    value.view(-1)[0] = math.nan
    with pytest.raises(ValueError, match=f"^{name} must be finite"):
        _contacts(**{name: value})


@pytest.mark.parametrize("stiffness", ["1e30", "1e10", "2e9"])
def test_a_stiffness_past_what_the_mpc_takes_is_refused_first(tmp_path, capsys, stiffness):
    last = refused([*RUN, "--out", str(tmp_path), "--stiffness", stiffness], capsys, "run",
                    "--stiffness")  # fmt: skip
    assert f"at most {MAX_STIFFNESS:g}, got {float(stiffness)!r}" in last
    with pytest.raises(ValueError, match=r"^stiffness must be .* a positive number at most 1e\+09"):
        ModelOptions(stiffness=float(stiffness))


@pytest.fixture(scope="module")
def mpc_and_plant():
    env, plant, mpc = build_trial(FAST[0])
    return mpc, plant


@pytest.mark.parametrize("which", ["target_p", "target_quat"])
def test_a_nan_target_is_named_by_the_mpc_before_it_plans(mpc_and_plant, which):
    mpc, plant = mpc_and_plant
    target = {"target_p": torch.zeros(3), "target_quat": torch.tensor([1.0, 0, 0, 0])}
    target[which][0] = math.nan
    q = torch.as_tensor(plant.state())
    with pytest.raises(ValueError, match=f"^{which} must be finite"):
        mpc.plan(q, plant.contacts(mpc.dtype), target["target_p"], target["target_quat"])


def test_a_mesh_with_a_bad_face_index_is_refused_in_one_line(tmp_path, capsys):
    mesh = tmp_path / "bad.obj"
    mesh.write_text(BAD_FACES)
    with pytest.raises(ValueError, match="must hold a readable triangle mesh.*IndexError"):
        load_object(mesh)
    run = ["run", "trifinger", "--trials", "1", "--max-steps", "1", "--no-compile"]
    refused([*run, "--out", str(tmp_path / "o"), "--object", str(mesh)], capsys, "run",
             "--object")  # fmt: skip
    learn = ["learn-k", "--out", str(tmp_path / "l"), "--scene", "trifinger", "--no-progress"]
    refused([*learn, "--object", str(mesh)], capsys, "learn-k", "--object")
    assert not (tmp_path / "l" / "data").exists()


def test_a_quasi_dynamic_system_of_mismatched_object_sizes_names_both():
    with pytest.raises(ValueError, match="object_metric and object_force must have one entry"):
        QuasiDynamic([1.0] * 5, 1.0, [0.0] * 6, n_robot=3)


def test_a_state_network_names_a_q_of_the_wrong_length():
    with pytest.raises(ValueError, match=r"^q must have shape \(\.\.\., 16\), got \(13,\)"):
        StateNetwork(16, 8)(Contacts.empty(2, 9), 4, q=torch.zeros(13))


@pytest.mark.parametrize(
    "active, message",
    [
        (torch.ones(4), "active must be a bool tensor of shape (..., 4), got torch.float"),
        ("all", "active must be a bool tensor of shape (..., 4), got str"),
        (torch.ones(5, dtype=torch.bool), "active must have shape (..., 4), got (5,)"),
    ],
)
def test_qp_solve_checks_its_active_rows(active, message):
    Q, b, jac, phi = torch.ones(3), torch.zeros(3), torch.randn(4, 3), torch.rand(4)
    with pytest.raises(ValueError, match=f"^{re.escape(message)}"):
        qp_solve(Q, b, jac, phi, 0.1, active=active)


# --- 8. bounded and honest at the edges -----------------------------------------------------


@pytest.mark.parametrize(
    "argv, option, message",
    [
        (["--trials", "100000000"], "--trials", "--trials must be at most 1000000"),
        (["--object", "random:50000000"], "--object", "random:N needs 1 <= N <= 100000"),
        (["--object", "random:0-50000000"], "--object", "random:A-B names at most 100000"),
        (["--object", "cube", "--object-size", "5"], "", "object 'cube' would be 5 m across"),
    ],
)
def test_sizes_that_cannot_run_are_refused_naming_the_limit(
    tmp_path, capsys, argv, option, message
):
    start = time.perf_counter()
    base = ["run", "trifinger", "--task", "in-hand", "--max-steps", "1", "--no-compile"]
    last = refused([*base, "--out", str(tmp_path), *argv], capsys, "run", option)
    assert message in last and time.perf_counter() - start < 30
    assert not (tmp_path / "trials").exists()


def test_the_trial_api_refuses_more_trials_than_it_takes_at_once():
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"^pairs × seeds must make at most 1000000 trials"):
        trial_configs("fingertips", [("rotation", "cube")], range(10**8))
    assert time.perf_counter() - start < 5


def test_learn_k_refuses_an_empty_object(tmp_path, capsys):
    argv = ["learn-k", "--out", str(tmp_path), "--no-progress", "--object", ""]
    assert "got ''" in refused(argv, capsys, "learn-k", "--object")


def test_a_mesh_too_small_for_mujoco_is_refused_with_our_message(tmp_path, capsys):
    mesh = tmp_path / "speck.stl"
    trimesh.creation.box([1e-5] * 3).export(mesh)
    with pytest.raises(ValueError, match="too small or too thin"):
        environment("trifinger").make_plant(str(mesh))
    run = ["run", "trifinger", "--trials", "1", "--max-steps", "1", "--no-compile"]
    last = refused([*run, "--out", str(tmp_path / "o"), "--object", str(mesh)], capsys, "run",
                    "--object")  # fmt: skip
    assert "mesh volume is too small" not in last


def test_a_mesh_with_a_nan_vertex_or_too_thin_is_refused_in_one_line(tmp_path, capsys):
    nan = tmp_path / "nan.obj"
    nan.write_text("v nan 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 2 4\nf 1 3 4\n")
    with pytest.raises(ValueError, match="finite vertex coordinates, but .* has NaN or Inf"):
        load_object(nan)  # trimesh, left to itself, drops the vertex and loads the rest
    sheet = tmp_path / "sheet.stl"
    trimesh.creation.box([0.05, 0.05, 1e-7]).export(sheet)
    with pytest.raises(ValueError, match="too thin to be a solid: it is 1e-07 m across"):
        load_object(sheet)
    run = ["run", "trifinger", "--trials", "1", "--max-steps", "1", "--no-compile"]
    refused([*run, "--out", str(tmp_path / "o"), "--object", str(sheet)], capsys, "run",
            "--object")  # fmt: skip


IMPOSSIBLE = [
    ({"pos_err_mm": -1.0}, "pos_err_mm must be finite and >= 0"),
    ({"angle_err_deg": -0.5}, "angle_err_deg must be finite and >= 0"),
    ({"steps": 99}, "steps must lie in [1, max_steps = 1], got 99"),
    ({"steps": 0}, "steps must lie in [1, max_steps = 1], got 0"),
    ({"solve_ms": [math.nan]}, "solve_ms must be finite and >= 0"),
    ({"detect_ms": [-2.0]}, "detect_ms must be finite and >= 0"),
    ({"iterations": [-1]}, "iterations must be finite and >= 0"),
    ({"contact_slots": -1}, "contact_slots must be finite and >= 0"),
    ({"contacts_found_max": -1}, "contacts_found_max must be finite and >= 0"),
    ({"contacts_found_mean": math.nan}, "contacts_found_mean must be finite and >= 0"),
]


@pytest.mark.parametrize("change, why", IMPOSSIBLE)
def test_a_record_edited_to_impossible_values_is_corrupt_and_run_again(tmp_path, change, why):
    (config,) = FAST
    path = fake_record(tmp_path, config)
    path.write_text(json.dumps({**json.loads(path.read_text()), **change}))  # NaN as a literal
    status, found = record_status(path, config, trial_inputs(config))
    assert status == "corrupt" and found == why


@pytest.mark.parametrize("key, status", [("inputs", "stale"), ("task", "corrupt")])
def test_a_record_missing_its_inputs_or_a_config_field_is_not_reused(tmp_path, key, status):
    (config,) = FAST
    path = fake_record(tmp_path, config)
    path.write_text(json.dumps({k: v for k, v in json.loads(path.read_text()).items() if k != key}))
    assert record_status(path, config, trial_inputs(config))[0] == status


# --- the audit's core findings (benchmarks/hostile_audit.py) ---------------------------------

_C = {
    "phi": torch.rand(2), "jac_normal": torch.randn(2, 3), "jac_tangent": torch.randn(2, 2, 3),
    "mu": torch.ones(2), "active": torch.ones(2, dtype=torch.bool),
}  # fmt: skip


@pytest.mark.parametrize(
    "call, error, message",
    [
        (lambda: Contacts(**_C, frame=[[0.0] * 3] * 3), TypeError, "frame must be a torch.Tensor"),
        (lambda: Contacts(**_C, position=torch.zeros(2, 3, dtype=torch.long)), TypeError,
         "position must be a floating-point tensor"),
        (lambda: Contacts(**{**_C, "active": [True, True]}), TypeError, "active must be a bool"),
        (lambda: Contacts(**_C, position=torch.zeros(2, 3, device="meta")), ValueError,
         "position must be on the device of phi"),
        (lambda: Contacts.empty(-1, 3), ValueError, "slots must be an integer >= 0, got -1"),
        (lambda: Contacts.empty(2, 0), ValueError, "nv must be an integer >= 1, got 0"),
        (lambda: Contacts.empty(2.5, 3), ValueError, "slots must be an integer >= 0, got 2.5"),
        (lambda: ContactNetwork(hidden=0), ValueError, "hidden must be an integer >= 1, got 0"),
        (lambda: StateNetwork(16, 4, hidden=-3), ValueError, "hidden must be an integer >= 1"),
        (lambda: paper_model(-1.0), ValueError, "stiffness must be a positive finite number"),
        (lambda: constant_model(math.nan, {"gamma": 100.0, "facets": 4}), ValueError,
         "stiffness must be a positive finite number"),
        (lambda: write_csv(UNWRITABLE, [{"a": 1}]), FileNotFoundError,
         f"cannot write {UNWRITABLE}"),
        (lambda: write_csv("x.csv", [1, 2]), TypeError, "rows must be mappings of column"),
    ],
)  # fmt: skip
def test_the_audits_core_findings_are_named(call, error, message):
    with pytest.raises(error, match=re.escape(message)):
        call()


@pytest.mark.parametrize("h", ["0.1", None, True])
def test_a_step_names_an_h_that_is_not_a_number(h):
    model = ComplementarityFree(3.0)
    with pytest.raises(TypeError, match=r"^h must be a number or a torch.Tensor"):
        model(torch.ones(3), torch.zeros(3), Contacts(**_C), h)


def test_a_step_names_contacts_that_are_not_contacts_and_a_b_its_jac_does_not_fit():
    model = ComplementarityFree(3.0)
    with pytest.raises(TypeError, match=r"^contacts must be Contacts, got str"):
        model(torch.ones(3), torch.zeros(3), "x", 0.1)
    with pytest.raises(TypeError, match=r"^stiffness must be a number or a torch.Tensor"):
        cf_velocity(torch.ones(3), torch.zeros(3), torch.randn(8, 3), torch.rand(8), 0.1, "3")
    with pytest.raises(ValueError, match=r"nv that of b \(2,\), got \(8, 3\)"):
        cf_velocity(torch.ones(2), torch.zeros(2), torch.randn(8, 3), torch.rand(8), 0.1, 3.0)


# --- the audit's remaining core findings ----------------------------------------------------


@pytest.mark.parametrize(
    "call, error, message",
    [
        (lambda: QuasiDynamic("x", 1.0, [0.0] * 6, n_robot=3), TypeError, "object_metric must"),
        (lambda: QuasiDynamic([1.0] * 6, 1.0, [0.0] * 6, n_robot=0), ValueError,
         "n_robot must be an integer >= 1, got 0"),
        (lambda: QuasiDynamic([1.0] * 6, 1.0, [0.0] * 6, n_robot=3)(torch.zeros(3),
         object_displacement=torch.full((6,), math.nan)), ValueError,
         "object_displacement must be finite"),
        (lambda: QuasiDynamic([1.0] * 6, 1.0, [0.0] * 6, n_robot=3)(torch.zeros(3),
         robot_force=torch.zeros(4)), ValueError, "robot_force must have shape (..., 3)"),
        (lambda: qp_solve(torch.ones(3), torch.zeros(3), torch.randn(4, 3), torch.rand(4), 0.1,
         settings="x"), TypeError, "settings must be a mapping of OSQP settings, got str"),
        (lambda: relaxed_qp_solve(torch.ones(3), torch.zeros(3), torch.randn(4, 3),
         torch.rand(4), 0.1, tol=-1.0), ValueError, "tol must be positive"),
        (lambda: integrate(torch.zeros(7), torch.zeros(6), 0.1, "x"), TypeError,
         "layout must be a JointLayout, got str"),
        (lambda: JointLayout.manipulation(["ball"]), ValueError,
         "robot_joints must be 'slide' or 'hinge' joints, got ['ball']"),
        (lambda: make_object("cube", size=(5.0,) * 3), ValueError, "size must be at most 1 m"),
        (lambda: generate(1, extent=5.0), ValueError, "extent (or scale) must make the object"),
        (lambda: load_object(3), TypeError, "path must be a mesh file path, got int"),
        (lambda: QuasiDynamic([1.0] * 6, 1.0, "x", n_robot=3), TypeError,
         "object_force must be a number or a tensor, got 'x'"),
        (lambda: QuasiDynamic([], 1.0, [0.0] * 6, n_robot=3), ValueError,
         "object_metric must have one entry per object coordinate, got none"),
        (lambda: make_object("cube", size=(0.05, 0.05, 1e-5)), ValueError,
         "object 'cube' is too small or too thin to be a solid"),
    ],
)  # fmt: skip
def test_the_audits_remaining_core_findings_are_named(call, error, message):
    with pytest.raises(error, match=re.escape(message)):
        call()


def test_load_object_names_a_bad_name(tmp_path):
    trimesh.creation.box([0.05] * 3).export(tmp_path / "cube.stl")
    with pytest.raises(TypeError, match="name must be a non-empty string or None, got 3"):
        load_object(tmp_path / "cube.stl", name=3)


def test_a_phi_of_another_shape_than_jac_normal_names_both():
    with pytest.raises(ValueError, match=r"^phi \(\.\.\., nc\) and jac_normal .* got phi \(3,\)"):
        Contacts(**{**_C, "phi": torch.rand(3)})


@pytest.mark.parametrize("obj", ["teapot2", "", 3, None])
def test_fingertips_names_an_object_it_does_not_have(obj):
    with pytest.raises(ValueError, match=r"^obj must be one of fingertips' objects"):
        environment("fingertips").make_plant(obj)


def test_a_missing_file_and_a_file_that_is_not_json_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"^path must be an existing file, got '.*nowhere'"):
        content_sha256(tmp_path / "nowhere")
    (tmp_path / "text.json").write_text("not json\n")
    with pytest.raises(json.JSONDecodeError, match=r"^.*text\.json must hold JSON: Expecting"):
        read_json(tmp_path / "text.json")


@pytest.mark.parametrize("dtype", ["float16", torch.int64, 3])
def test_a_plants_contacts_name_a_dtype_that_is_not_one(mpc_and_plant, dtype):
    with pytest.raises(TypeError, match=r"^dtype must be a floating torch.dtype or None"):
        mpc_and_plant[1].contacts(dtype)


@pytest.mark.parametrize(
    "field, value, error, message",
    [
        ("edge", "x", TypeError, "edge must be a number, got 'x'"),
        ("h", "x", TypeError, "h must be a number, got 'x'"),
        ("facets", -1, ValueError, "facets must be a positive integer, got -1"),
        ("facets", "x", ValueError, "facets must be a positive integer, got 'x'"),
        ("gamma", -1.0, ValueError, "gamma must be a positive finite number or None"),
        ("gamma", math.nan, ValueError, "gamma must be a positive finite number or None"),
    ],
)
def test_box_pushing_config_names_a_bad_field(field, value, error, message):
    from torchcontact.sim.box_pushing import BoxPushingConfig

    with pytest.raises(error, match=f"^{re.escape(message)}"):
        BoxPushingConfig(**{field: value})


def test_a_plan_names_contacts_that_are_not_contacts_and_a_zero_target_quat(mpc_and_plant):
    mpc, plant = mpc_and_plant
    q, p = torch.as_tensor(plant.state()), torch.zeros(3)
    with pytest.raises(TypeError, match=r"^contacts must be Contacts, got str"):
        mpc.plan(q, "x", p, torch.tensor([1.0, 0, 0, 0]))
    with pytest.raises(ValueError, match=r"^target_quat must be a non-zero quaternion"):
        mpc.plan(q, plant.contacts(mpc.dtype), p, torch.zeros(4))
