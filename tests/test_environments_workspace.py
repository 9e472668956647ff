"""What a robot's MJCF says about its environment: initial joints, control bound, reach."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from torchcontact.environments.custom import PoseTask, from_mjcf
from torchcontact.environments.workspace import (
    STEPS_ACROSS,
    TARGET_SHARE,
    reach,
    robot_defaults,
    tip_workspace,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
GRIPPER = EXAMPLES / "two_finger_gripper.xml"
FINGER = EXAMPLES / "planar_finger.xml"
CUBE = np.array([0.06, 0.06, 0.06])


def _reach(path, tips, extent=CUBE):
    defaults = robot_defaults(path)
    points, start = tip_workspace(path, tips, defaults.joint_ranges, defaults.initial_joints)
    return reach(points, start, extent, 0.0, np.zeros(2))


def test_initial_joints_come_from_the_keyframe_or_the_reference_positions():
    finger = robot_defaults(FINGER)
    assert finger.initial_joints == pytest.approx((-0.55, 1.65, 1.15))
    assert "keyframe 'home'" in finger.describe()
    gripper = robot_defaults(GRIPPER)
    assert gripper.initial_joints == (0.0, 0.0, 0.0, 0.0)
    assert "reference positions" in gripper.initial_source


def test_the_control_bound_crosses_the_narrowest_commanded_range_in_fixed_steps():
    # the gripper's closing joints command 0 to 0.07 m; its lifts 0 to 0.12 m
    assert robot_defaults(GRIPPER).control_bound == pytest.approx(0.07 / STEPS_ACROSS)
    assert robot_defaults(FINGER).control_bound == pytest.approx(2.4 / STEPS_ACROSS)


def test_a_joint_without_any_range_is_refused_naming_the_file(tmp_path):
    text = GRIPPER.read_text().replace('limited="true"', 'limited="false"')
    text = text.replace('ctrllimited="true"', 'ctrllimited="false"')
    path = tmp_path / "unlimited.xml"
    path.write_text(text)
    with pytest.raises(ValueError, match="mjcf: every robot joint of unlimited.xml needs a range"):
        robot_defaults(path)


def test_the_gripper_may_shift_its_cube_between_its_pads_and_lift_it():
    region = _reach(GRIPPER, ["left_tip", "right_tip"])
    assert region.placement == (0.0, 0.0)
    assert region.target_x == (0.0, 0.0)  # its tips never leave x = 0
    # the right pad closes to y = -0.01, pushing the cube's face at -0.03 up to +0.02
    low, high = region.target_y
    assert -TARGET_SHARE * 0.02 - 1e-3 < low < 0 < high < TARGET_SHARE * 0.02 + 1e-3
    assert 0 < region.lift[0] < region.lift[1]  # two opposite pads squeeze and rise


def test_the_planar_finger_pushes_its_cube_forward_only():
    region = _reach(FINGER, ["tip"])
    assert region.target_y == (0.0, 0.0) and region.lift == (0.0, 0.0)
    low, high = region.target_x  # away from its base, none met by standing still
    assert low == pytest.approx(high / 2) and high > 0.04


def test_an_object_out_of_reach_is_placed_where_the_tips_reach():
    defaults = robot_defaults(FINGER)
    points, start = tip_workspace(FINGER, ["tip"], defaults.joint_ranges, defaults.initial_joints)
    region = reach(points, start, CUBE, 0.0, np.array([0.5, 0.5]))
    assert np.linalg.norm(region.placement) < 0.3


def test_an_environment_samples_derived_targets_and_says_what_it_derived():
    env = from_mjcf(FINGER, name="finger")
    plant = env.make_plant("cube")
    lines = env.describe(plant)
    assert "keyframe 'home'" in lines[0] and "targets x +" in lines[1]
    initial, target = env.sample(plant, "reposition", 3)
    high = env._sample.region(plant).target_x[1]
    assert 0 <= target[0] - initial[0] <= high and target[1] == initial[1]
    given = PoseTask(target_x=(0.01, 0.01))
    assert given.region(plant).target_x == (0.01, 0.01)  # given values are kept


@pytest.mark.parametrize(
    "fields, match",
    [
        ({"target_x": (0.02, 0.01)}, "target_x must be"),
        ({"placement": (0.0, float("nan"))}, "placement must be None or two finite"),
        ({"lift": (-0.01, 0.0)}, "lift must not be negative"),
    ],
)
def test_a_task_with_a_bad_region_is_refused(fields, match):
    with pytest.raises(ValueError, match=match):
        PoseTask(**fields)


def test_a_bad_control_bound_is_refused():
    with pytest.raises(ValueError, match="control_bound must be a positive finite number"):
        from_mjcf(FINGER, control_bound=-1.0)


def _closed_loop(robot: Path, name: str, seed: int, max_steps: int):
    """The record of the robot's default trial ``seed`` with the defaults, planned eagerly."""
    from torchcontact.mpc.controller import ContactImplicitMPC
    from torchcontact.mpc.model_options import ModelOptions
    from torchcontact.mpc.trial_config import TrialConfig
    from torchcontact.mpc.trials import run_trial

    env = from_mjcf(robot, name=name)
    plant = env.make_plant("cube")
    settings = dataclasses.replace(env.preset(), compile=False)
    mpc = ContactImplicitMPC.from_env(env, plant, settings=settings)
    config = TrialConfig(
        env=name, task="reposition", object="cube", seed=seed, max_steps=max_steps,
        settings=settings, model_options=ModelOptions(stiffness=env.default_stiffness),
    )  # fmt: skip
    return env, plant, run_trial(config, env, plant, mpc)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_planar_finger_pushes_its_cube_to_a_derived_target_with_the_defaults(seed):
    _, _, record = _closed_loop(FINGER, "finger", seed, max_steps=150)
    assert record.success, record.pos_err_mm
    pushed = np.linalg.norm(np.subtract(record.final_pose[:2], record.initial_pose[:2]))
    assert pushed > 0.02  # a real push, not a target met where the cube stood


@pytest.mark.parametrize("seed", [0, 1])
def test_the_gripper_lifts_its_cube_to_a_derived_target_and_holds_it_with_the_defaults(seed):
    env, plant, record = _closed_loop(GRIPPER, "gripper", seed, max_steps=120)
    assert env._sample.region(plant).lift[0] > 0.02  # the derived task is a lift
    # success holds the cube within 2 cm of a target 2-6 cm up for 20 steps: it is not dropped
    assert record.success, record.pos_err_mm
    assert record.final_pose[2] - record.initial_pose[2] > 0.02


def test_a_bad_contact_stiffness_is_refused():
    with pytest.raises(ValueError, match="stiffness must be a positive finite number"):
        from_mjcf(FINGER, stiffness=float("nan"))


def test_a_robot_file_that_holds_an_object_is_refused_naming_it():
    with pytest.raises(ValueError, match=r"robot must hold the robot only, pusher.xml also has"):
        from_mjcf(EXAMPLES / "pusher.xml", ("pusher_tip",))
