"""A trial starts with no finger inside its object: the joints are moved out (sim.clearance)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from torchcontact.environments import environment
from torchcontact.sim.clearance import CLEARANCE, penetrations
from torchcontact.sim.hands import HandPlant
from torchcontact.sim.scene import OBJECT_BODY

# a 14.3 cm generated object whose trial seed 1 places it through a TriFinger fingertip
OVERLAPPING = ("random-84", 1)


def robot_penetration(plant: HandPlant) -> float:
    """[m] The deepest overlap of any robot geom with the object (0: none)."""
    model, data = plant.model, plant.data
    body = model.body(OBJECT_BODY).id
    robot = set(range(1, model.nbody)) - {body}
    return max((-c.dist for c in penetrations(model, data, body, robot)), default=0.0)


def overlapping_trifinger() -> tuple[HandPlant, np.ndarray, np.ndarray]:
    env = environment("trifinger")
    plant = env.make_plant(OVERLAPPING[0])
    initial, target = env.sample(plant, "in-hand", OVERLAPPING[1])
    return plant, initial, target


def test_the_hands_initial_joints_overlap_this_object():
    """The case the clearing exists for: the fixed initial joints put a tip inside it."""
    plant, initial, target = overlapping_trifinger()
    plant.reset(initial, target, joints=plant.initial_joints)
    assert robot_penetration(plant) > 0.01


def test_reset_moves_the_fingers_out_of_the_object_and_leaves_the_object():
    plant, initial, target = overlapping_trifinger()
    state = plant.reset(initial, target)
    assert plant.start_penetration == 0.0
    assert robot_penetration(plant) == 0.0
    np.testing.assert_allclose(state[:7], initial, atol=1e-12)
    moved = np.abs(state[7:] - plant.initial_joints).reshape(3, 3).max(1)
    assert (moved > 1e-3).sum() >= 1, "a finger should have moved"
    assert (moved == 0).sum() >= 1, "a finger clear of the object should stay where it was"
    # the servos hold the cleared joints: the first step does not push the fingers back in
    plant.step(np.zeros(9))
    assert robot_penetration(plant) < CLEARANCE


def test_joints_given_to_reset_are_kept_as_given_and_their_overlap_measured():
    plant, initial, target = overlapping_trifinger()
    state = plant.reset(initial, target, joints=plant.initial_joints)
    np.testing.assert_array_equal(state[7:], plant.initial_joints)
    assert plant.start_penetration == pytest.approx(robot_penetration(plant))
    assert plant.start_penetration > 0.01


def test_the_allegro_keeps_the_papers_start_with_its_fingers_pressed_onto_the_object():
    env = environment("allegro")
    assert not env.hand.clear_start
    plant = env.make_plant("random-58")
    state = plant.reset(*env.sample(plant, "on-palm", 0))
    np.testing.assert_array_equal(state[7:], plant.initial_joints)
    assert plant.start_penetration == pytest.approx(robot_penetration(plant))
    assert plant.start_penetration > 0.005


@pytest.mark.parametrize("hand", ["trifinger", "allegro"])
def test_an_object_clear_of_the_fingers_starts_at_the_initial_joints(hand):
    env = environment(hand)
    plant = env.make_plant("cube")
    far = plant.resting_pose(plant.support_centre + np.array([0.5, 0.5]), [1.0, 0.0, 0.0, 0.0])
    state = plant.reset(far)
    np.testing.assert_array_equal(state[7:], plant.initial_joints)


def test_joints_stay_within_their_limits():
    env = environment("allegro")
    plant = HandPlant(dataclasses.replace(env.hand, clear_start=True), "random-58")
    overlap = plant.reset(*env.sample(plant, "on-palm", 0), joints=plant.initial_joints)
    depth = robot_penetration(plant)
    state = plant.reset(*env.sample(plant, "on-palm", 0))
    low, high = plant.model.jnt_range[1:].T  # joint 0 is the object's free joint
    assert np.all(state[7:] >= low - 1e-12) and np.all(state[7:] <= high + 1e-12)
    assert not np.array_equal(state[7:], overlap[7:])
    # the fingers leave; the base links, which no joint moves far, may stay in, no deeper
    assert 0 < plant.start_penetration <= depth


def test_trial_records_store_the_overlap_left_at_the_start():
    from torchcontact.mpc.trials import start_penetration_mm

    plant, initial, target = overlapping_trifinger()
    plant.reset(initial, target)
    assert start_penetration_mm(plant) == 0.0
    env = environment("allegro")
    plant = env.make_plant("random-58")  # its fingers start inside the object
    plant.reset(*env.sample(plant, "on-palm", 0))
    assert start_penetration_mm(plant) == pytest.approx(1e3 * robot_penetration(plant))
    assert start_penetration_mm(plant) > 1.0
    assert start_penetration_mm(environment("fingertips").make_plant("cube")) is None


def test_a_user_robots_slide_joints_lift_its_pads_off_a_wide_slab():
    """The example gripper's pads, 16 cm apart when open, stand in a 20 cm slab laid across
    them: the close joints cannot open further, so the lift joints raise the pads onto it."""
    from pathlib import Path

    import trimesh

    from torchcontact.environments.custom import from_mjcf
    from torchcontact.shapes import assemble

    gripper = Path(__file__).resolve().parents[1] / "examples" / "two_finger_gripper.xml"
    env = from_mjcf(gripper, name="gripper")
    slab = assemble("slab", [trimesh.creation.box((1, 1, 1))], np.array([0.05, 0.2, 0.025]), 0.01)
    plant = env.make_plant(slab)
    initial = plant.resting_pose([0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    plant.reset(initial, joints=plant.initial_joints)
    assert robot_penetration(plant) > 0.005
    state = plant.reset(initial)
    assert plant.start_penetration == 0.0 and robot_penetration(plant) == 0.0
    close, lift = state[[7, 9]], state[[8, 10]]
    np.testing.assert_array_equal(close, 0.0)
    pad_bottom = 0.015  # above the ground at lift 0
    assert np.all(lift + pad_bottom > 0.025)


def test_a_user_robot_may_keep_its_initial_joints():
    from pathlib import Path

    from torchcontact.environments.custom import from_mjcf

    gripper = Path(__file__).resolve().parents[1] / "examples" / "two_finger_gripper.xml"
    assert from_mjcf(gripper, name="gripper").hand.clear_start
    assert not from_mjcf(gripper, name="gripper", clear_start=False).hand.clear_start
