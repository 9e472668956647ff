"""Settings defined once: options generated from their dataclass fields, carried as typed parts
of a trial's configuration, written flat in its record as before."""

from __future__ import annotations

import argparse
import dataclasses
import json

import pytest

from torchcontact.cli import Parser, main
from torchcontact.cli.options import add_options, option_name, options_object
from torchcontact.cli.run import build_parser, configs_of, parse_args
from torchcontact.environments import CostOptions, RobotOptions, environment
from torchcontact.environments.presets import MPCSettings
from torchcontact.mpc.records import record_problem
from torchcontact.mpc.trial_config import (
    RECORD_KEYS,
    RECORD_PARTS,
    config_from_flat,
    flat_config,
    stored_config,
)
from torchcontact.mpc.trials import build_trial
from torchcontact.objects import ObjectOptions

FINGER = ["custom", "--robot", "examples/planar_finger.xml", "--object", "cube"]


def test_every_field_of_a_part_is_an_option_of_run():
    help_text = build_parser().format_help()
    for _, (cls, prefix) in RECORD_PARTS.items():
        for field in dataclasses.fields(cls):
            flag = option_name(field.name, prefix)
            if field.type == "bool":
                flag = "--no-" + flag[2:]
            assert flag in help_text, flag


def test_an_option_not_given_keeps_the_base_and_one_given_is_checked_by_its_class():
    parser = Parser(prog="p")
    add_options(parser, MPCSettings)
    base = MPCSettings(max_iter=7, horizon=3)
    assert options_object(parser, parser.parse_args([]), base) == base
    given = options_object(parser, parser.parse_args(["--horizon", "5", "--no-compile"]), base)
    assert given == dataclasses.replace(base, horizon=5, compile=False)
    with pytest.raises(SystemExit):
        options_object(parser, parser.parse_args(["--memory", "0"]), base)


def test_a_tuple_field_takes_comma_separated_numbers_negative_first():
    parser = Parser(prog="p")
    add_options(parser, RobotOptions)
    args = parser.parse_args(["--initial-joints", "-0.5,1.6,1.1", "--target-x=0.01,0.03"])
    options = options_object(parser, args, RobotOptions())
    assert options == RobotOptions(initial_joints=(-0.5, 1.6, 1.1), target_x=(0.01, 0.03))
    with pytest.raises(SystemExit):
        parser.parse_args(["--placement", "1"])  # two numbers


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--initial-joints", "0.1,0.2"], "--initial-joints must have 3 values, one per joint"),
        (["--target-x", "0.05,0.01"], "--target-x must be (low, high) with low <= high"),
        (["--lift", "-0.01,0"], "--lift must not be negative"),
        (["--control-bound", "0"], "--control-bound must be a positive finite number"),
        (["--placement", "1"], "argument --placement: must be 2 comma-separated numbers"),
    ],
)
def test_a_robot_option_is_refused_in_one_line_naming_it(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["run", *FINGER, *argv])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1
    assert message in err, err


def test_robot_options_are_for_a_user_robot_only(capsys):
    with pytest.raises(SystemExit):
        main(["run", "trifinger", "--target-x", "0.01,0.02"])
    assert "--target-x is for the custom environment" in capsys.readouterr().err
    with pytest.raises(ValueError, match="options .* are for a user robot"):
        environment("trifinger", options=RobotOptions(control_bound=0.1))


def test_robot_options_reach_the_environment_and_its_task():
    argv = [*FINGER, "--target-x", "0.03,0.04", "--initial-joints", "-0.5,1.6,1.1",
            "--control-bound", "0.05", "--trials", "1"]  # fmt: skip
    (config,) = configs_of(parse_args(argv))
    assert config.robot_options == RobotOptions(
        initial_joints=(-0.5, 1.6, 1.1), control_bound=0.05, target_x=(0.03, 0.04)
    )
    env, plant, mpc = build_trial(config)
    assert env.hand.initial_joints == (-0.5, 1.6, 1.1)
    assert env.control_bound(plant) == pytest.approx(0.05)
    region = env._sample.region(plant)
    assert region.target_x == (0.03, 0.04) and region.target_y != (0.03, 0.04)
    _, target = env.sample(plant, "reposition", 0)
    assert 0.03 <= target[0] - region.placement[0] <= 0.04
    robot, task = env.describe(plant)  # the run's header says what was given
    assert "initial joints (-0.5, 1.6, 1.1) from the initial joints given" in robot
    assert "control bound 0.05 per step (given)" in robot
    assert "x +30 to +40 mm (given)" in task and task.endswith("the rest from the tips' reach")


def test_a_record_holds_the_parts_flat_and_reads_back_the_same_config():
    argv = [*FINGER, "--target-y", "0,0.01", "--trials", "1", "--horizon", "5"]
    (config,) = configs_of(parse_args(argv))
    record = json.loads(json.dumps(flat_config(config)))  # as written and read back
    assert tuple(record) == RECORD_KEYS
    assert record["horizon"] == 5 and record["target_y"] == [0, 0.01]
    assert record["object_pose"] == "stable" and record["hold_first"] == 0
    assert config_from_flat(stored_config(record)) == config
    assert config.matches(record)


def test_a_record_whose_part_is_refused_is_corrupt():
    (config,) = configs_of(parse_args([*FINGER, "--trials", "1"]))
    assert record_problem({**flat_config(config), **_outcome()}) is None
    record = {**flat_config(config), "target_x": [0.05, 0.01]}
    problem = record_problem({**record, **_outcome()})
    assert problem.startswith("its configuration is refused: target_x must be (low, high)")


def _outcome() -> dict:
    pose = [0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0]
    return {
        "success": False, "steps": 1, "pos_err_mm": 1.0, "quat_err": 0.0, "angle_err_deg": 0.0,
        "initial_pose": pose, "target_pose": pose, "aim_pose": pose, "final_pose": pose,
        "fell": False, "detect_ms": [1.0], "solve_ms": [1.0], "sim_ms": [1.0],
        "iterations": [1], "contact_slots": 1, "contacts_found_mean": 0.0,
        "contacts_found_max": 0, "steps_with_dropped_contacts": 0,
    }  # fmt: skip


def test_trial_configs_takes_the_parts_typed():
    from torchcontact.mpc.trial_config import trial_configs

    with pytest.raises(TypeError, match="^cost_options must be CostOptions, got dict"):
        trial_configs("trifinger", [("in-hand", "cube")], [0], cost_options={"hold_first": 1})
    with pytest.raises(TypeError, match="^object_options must be ObjectOptions, got float"):
        trial_configs("trifinger", [("in-hand", "cube")], [0], object_options=0.1)
    (held,) = trial_configs(
        "trifinger", [("in-hand", "cube")], [0], cost_options=CostOptions(hold_first=1)
    )
    assert held.cost_options == CostOptions(1, environment("trifinger").cost_defaults.hold_approach)
    assert isinstance(held.object_options, ObjectOptions)


def test_the_namespace_of_run_holds_the_typed_parts():
    args = parse_args(["trifinger", "--hold-approach", "2", "--object-mass", "0.02"])
    assert isinstance(args, argparse.Namespace)
    assert args.cost_options == CostOptions(hold_approach=2.0)
    assert args.object_options == ObjectOptions(mass=0.02)
    assert args.robot_options == RobotOptions()
