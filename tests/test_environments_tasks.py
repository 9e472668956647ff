"""Fingertip tasks: reproducible samplers inside their ranges, error formulas, success rule."""

from __future__ import annotations

import math

import numpy as np
import pytest

from torchcontact.environments import tasks
from torchcontact.environments.hands import ALLEGRO_ENV
from torchcontact.environments.tasks import (
    OBJECT_SETTINGS,
    PAPER_PAIRS,
    SuccessCriterion,
    SuccessTracker,
    aim_pose,
    angle_error,
    position_error,
    quat_from_axis_angle,
    quat_from_yaw_pitch_roll,
    quaternion_error,
    sample,
)
from torchcontact.shapes import object_names
from torchcontact.sim.hands import HandPlant

SEEDS = range(tasks.TRIALS)


def _yaw_pitch_roll(quat: np.ndarray) -> tuple[float, float, float]:
    w, x, y, z = quat
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    pitch = math.asin(np.clip(2 * (w * y - x * z), -1, 1))
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    return yaw, pitch, roll


@pytest.mark.parametrize(("task", "obj"), PAPER_PAIRS)
def test_samples_are_reproducible_and_inside_their_ranges(task, obj):
    settings = OBJECT_SETTINGS[obj]
    for seed in SEEDS:
        initial, target = sample(task, obj, seed)
        again = sample(task, obj, seed)
        np.testing.assert_array_equal(initial, again[0])
        np.testing.assert_array_equal(target, again[1])
        assert initial.shape == target.shape == (7,)
        assert np.linalg.norm(initial[3:]) == pytest.approx(1.0)
        assert np.linalg.norm(target[3:]) == pytest.approx(1.0)
        assert np.all(np.abs(initial[:2]) <= 0.025) and initial[2] == settings.rest_height
        _, pitch, roll = _yaw_pitch_roll(initial[3:])
        assert abs(pitch) < 1e-12 and abs(roll) < 1e-12  # upright, yaw only
        assert np.all(np.abs(target[:2]) <= 0.1)
        _, pitch, roll = _yaw_pitch_roll(target[3:])
        if task == "rotation":
            assert target[2] == settings.rest_height
            assert abs(pitch) < 1e-9 and abs(roll) < 1e-9
        elif task == "flip":
            assert target[2] == settings.flip_height
            if not settings.flip_pitch:
                assert abs(pitch) < 1e-9
        else:
            low, high = settings.in_air_height
            assert low <= target[2] <= high
    first = [sample(task, obj, seed)[1] for seed in SEEDS]
    assert len({tuple(t) for t in first}) == len(first)  # seeds give different trials


def test_flip_and_in_air_targets_spread_over_their_distributions():
    flips = np.array([_yaw_pitch_roll(sample("flip", "cube", s)[1][3:]) for s in range(200)])
    assert np.abs(flips[:, 1]).max() > 1.0 and np.abs(flips[:, 2]).max() > 1.0
    axes = []
    for seed in range(200):
        quat = sample("in-air", "cube", seed)[1][3:]
        axes.append(np.sign(quat[0]) * quat[1:] / np.linalg.norm(quat[1:]))
    mean_axis = np.mean(np.abs(axes), axis=0)
    assert mean_axis[1] > 0.6 and mean_axis[2] > 0.6 and mean_axis[0] < 0.15  # about (0, 1, 1)


def test_rest_heights_match_the_meshes():
    from torchcontact.shapes import make_object

    for name, settings in OBJECT_SETTINGS.items():
        assert make_object(name).resting_height() == pytest.approx(settings.rest_height, abs=5e-4)


def test_error_formulas_match_the_fact_sheet():
    for e, degrees in ((0.04, 23.1), (0.03, 19.9), (0.015, 14.1)):
        theta = 2 * math.asin(math.sqrt(e))  # e = sin²(θ/2)
        quat = quat_from_axis_angle([0.3, -1.0, 0.5], theta)
        identity = np.array([1.0, 0, 0, 0])
        assert quaternion_error(quat, identity) == pytest.approx(e)
        assert angle_error(quat, identity) == pytest.approx(degrees, abs=0.05)
        assert quaternion_error(-quat, identity) == pytest.approx(e)  # q and −q agree
    assert angle_error(identity, identity) == 0.0
    assert position_error([0.0, 0.03, 0.04], [0, 0, 0]) == pytest.approx(0.05)
    batch = np.stack([identity, quat_from_yaw_pitch_roll(np.pi)])
    np.testing.assert_allclose(angle_error(batch, identity), [0.0, 180.0], atol=1e-6)


def test_yaw_pitch_roll_is_the_z_y_x_convention():
    yaw, pitch, roll = 0.4, -0.3, 1.1
    quat = quat_from_yaw_pitch_roll(yaw, pitch, roll)
    np.testing.assert_allclose(_yaw_pitch_roll(quat), (yaw, pitch, roll), atol=1e-12)


def test_success_needs_twenty_consecutive_steps_in_tolerance():
    target = np.array([0.05, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0])
    tracker = SuccessTracker(target)
    near = target + [0.015, 0, 0, 0, 0, 0, 0]
    far = target + [0.025, 0, 0, 0, 0, 0, 0]
    tilted = np.concatenate([target[:3], quat_from_axis_angle([1, 0, 0], np.radians(15))])
    for _ in range(19):
        assert not tracker.update(near)
    assert not tracker.update(far) and tracker.consecutive == 0
    assert not tracker.update(tilted)  # 15° > 14.1°
    for _ in range(19):
        assert not tracker.update(np.concatenate([near, np.zeros(9)]))  # full state accepted
    assert tracker.update(near) and tracker.succeeded and tracker.success_step == 41


def test_tracker_gives_up_after_max_steps():
    tracker = SuccessTracker(np.array([0, 0, 0.03, 1, 0, 0, 0.0]), SuccessCriterion(max_steps=3))
    far = np.array([1.0, 0, 0.03, 1, 0, 0, 0])
    assert [tracker.update(far) for _ in range(3)] == [False, False, True]
    assert tracker.done and not tracker.succeeded


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("spin", "cube", 0), "task"),
        (("rotation", "spoon", 0), "obj"),
        (("in-air", "stick", 0), "stick"),
        (("flip", "bunny", 0), "bunny"),
        (("rotation", "cube", -1), "seed"),
        (("rotation", "cube", 1.5), "seed"),
    ],
)
def test_bad_input_names_the_argument(args, message):
    with pytest.raises(ValueError, match=message):
        sample(*args)


def test_every_paper_pair_is_supported():
    assert len(PAPER_PAIRS) == 9
    for task, obj in PAPER_PAIRS:
        assert OBJECT_SETTINGS[obj].supports(task)


def _flat_rest(xy, quat):
    return np.concatenate([xy, [0.03], quat])


def test_in_hand_samples_lie_in_the_papers_ranges_and_repeat():
    for seed in range(50):
        initial, target = tasks.sample_in_hand(_flat_rest, seed)
        for pose in (initial, target):
            assert np.all(np.abs(pose[:2]) <= tasks.IN_HAND_XY_RANGE)
            yaw = 2 * np.arctan2(pose[6], pose[3])
            assert abs(yaw) <= np.pi / 2 + 1e-12 and np.allclose(pose[4:6], 0)
    again = tasks.sample_in_hand(_flat_rest, 7)
    np.testing.assert_array_equal(again[0], tasks.sample_in_hand(_flat_rest, 7)[0])


def test_on_palm_targets_turn_a_quarter_either_way():
    centre = np.array([-0.03, -0.01])
    turns = []
    for seed in range(40):
        initial, target = tasks.sample_on_palm(_flat_rest, centre, seed=seed)
        assert np.linalg.norm(initial[:2] - centre) < 0.03
        np.testing.assert_allclose(target[:2], centre)
        angle = tasks.angle_error(initial[3:], target[3:])
        np.testing.assert_allclose(angle, 90.0, atol=1e-9)
        turns.append(np.sign(target[6] * initial[3] - target[3] * initial[6]))
    assert set(turns) == {-1.0, 1.0}


def test_on_palm_yaw_range_and_the_sticks_exception():
    low, high = tasks.ON_PALM_OBJECT_YAW_RANGES["stick"]
    assert (low, high) == (np.pi / 4, 3 * np.pi / 4)
    for seed in range(20):
        initial, _ = tasks.sample_on_palm(_flat_rest, np.zeros(2), seed=seed, yaw_range=(low, high))
        yaw = 2 * np.arctan2(initial[6], initial[3])
        assert low <= yaw <= high
    with pytest.raises(ValueError, match="yaw_range"):
        tasks.sample_on_palm(_flat_rest, np.zeros(2), seed=0, yaw_range=(1.0, 0.0))


def test_on_palm_placements_start_and_end_where_the_paper_puts_each_object():
    start, end = tasks.ON_PALM_PLACEMENTS["bunny"]
    initial, target = tasks.sample_on_palm(_flat_rest, start, end, seed=3)
    assert np.linalg.norm(initial[:2] - start) < 0.03
    np.testing.assert_allclose(target[:2], end)
    assert set(tasks.ON_PALM_PLACEMENTS) == set(object_names())
    with pytest.raises(ValueError, match="target_centre"):
        tasks.sample_on_palm(_flat_rest, start, (0.0, np.nan), seed=0)


def test_hand_criteria():
    assert tasks.TRIFINGER_SUCCESS.quaternion_tolerance == 0.04
    tracker = tasks.SuccessTracker([0, 0, 0, 1, 0, 0, 0], tasks.ALLEGRO_SUCCESS)
    assert tracker.within_tolerance(np.array([0.5, 0.5, 0.5, 1, 0, 0, 0]))  # orientation only
    with pytest.raises(ValueError, match="seed"):
        tasks.sample_in_hand(_flat_rest, -1)


def test_allegro_environment_starts_the_stick_across_the_palm():
    plant = ALLEGRO_ENV.make_plant("stick")
    low, high = tasks.ON_PALM_OBJECT_YAW_RANGES["stick"]
    for seed in range(5):
        initial, _ = ALLEGRO_ENV.sample(plant, "on-palm", seed)
        assert low <= 2 * np.arctan2(initial[6], initial[3]) <= high


def test_the_aim_rises_out_of_the_support_by_at_most_half_the_tolerance():
    target = np.array([0.05, -0.02, 0.03, 1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(aim_pose(target, 0.03, 0.02), target)  # resting: unchanged
    np.testing.assert_array_equal(aim_pose(target, 0.01, 0.02), target)  # above: unchanged
    np.testing.assert_array_equal(aim_pose(target, 0.03 + 6e-18, 0.02), target)  # rounding
    raised = aim_pose(target, 0.036, 0.02)  # sunk by 6 mm: raised onto the support
    assert raised[2] == pytest.approx(0.036)
    np.testing.assert_array_equal(np.delete(raised, 2), np.delete(target, 2))
    assert aim_pose(target, 0.051, 0.02)[2] == pytest.approx(0.04)  # 21 mm: capped at 10 mm
    assert aim_pose(target, 0.051, math.inf)[2] == pytest.approx(0.051)  # no position criterion


def test_most_flip_targets_of_the_foam_brick_sink_and_are_aimed_above_them():
    from torchcontact.sim.fingertips import FingertipsPlant

    env = FingertipsPlant("foam_brick")
    assert env.support_height == 0.0  # the ground
    assert env.resting_height([1.0, 0.0, 0.0, 0.0]) == env.object.resting_height()
    lifts = []
    for seed in SEEDS:
        _, target = sample("flip", "foam_brick", seed)
        resting = env.resting_height(target[3:])
        aim = aim_pose(target, resting, 0.02)
        lifts.append(aim[2] - target[2])
        assert aim[2] <= max(target[2], resting) + 1e-12  # never above the resting height
    assert min(lifts) >= 0 and max(lifts) == pytest.approx(0.01) and np.mean(lifts) > 0.005
    for seed in SEEDS:  # on-ground rotation targets rest already
        _, target = sample("rotation", "foam_brick", seed)
        assert aim_pose(target, env.resting_height(target[3:]), 0.02)[2] == pytest.approx(target[2])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((np.zeros(6), 0.03, 0.02), "target_pose"),
        ((np.array([0, 0, np.nan, 1, 0, 0, 0]), 0.03, 0.02), "target_pose"),
        ((np.array([0, 0, 0.03, 1, 0, 0, 0]), math.nan, 0.02), "resting_height"),
        ((np.array([0, 0, 0.03, 1, 0, 0, 0]), 0.03, 0.0), "position_tolerance"),
    ],
)
def test_bad_aim_input_names_the_argument(args, message):
    with pytest.raises(ValueError, match=message):
        aim_pose(*args)


def test_an_object_set_beyond_the_allegro_palm_falls_and_one_on_it_does_not():
    env = HandPlant("allegro", "cube")
    identity = [1.0, 0.0, 0.0, 0.0]
    for dx, falls in ((0.0, False), (-0.25, True)):  # the wrist edge lies on −x
        start = env.resting_pose(env.support_centre + [dx, 0.0], identity)
        env.reset(start)
        for _ in range(10):
            env.step(np.zeros(env.nu))
        assert tasks.fell(start, env.state()[:7]) is falls


def test_fell_counts_a_drop_beyond_the_threshold_only():
    start = np.array([0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0])
    low = start - [0, 0, tasks.FALL_DROP + 1e-6, 0, 0, 0, 0]
    high = start - [0, 0, tasks.FALL_DROP - 1e-6, 0, 0, 0, 0]
    assert tasks.fell(start, low) and not tasks.fell(start, high)
    assert not tasks.fell(start, start + [0.3, 0.3, 0.1, 0, 0, 0, 0])  # far, but not lower
    with pytest.raises(ValueError, match="final_pose"):
        tasks.fell(start, start[:3])


def test_the_tilt_error_is_the_lean_no_turn_about_the_vertical_removes():
    target = tasks.quat_from_yaw_pitch_roll(0.4)
    turned = tasks.quat_from_yaw_pitch_roll(0.4 + math.radians(155))  # 155° short: no lean
    on_side = tasks.quat_from_yaw_pitch_roll(1.0, 0.0, math.pi / 2)
    upside_down = tasks.quat_from_yaw_pitch_roll(-2.0, math.pi, 0.0)
    assert tasks.tilt_error(turned, target) == pytest.approx(0.0, abs=1e-6)
    assert tasks.angle_error(turned, target) == pytest.approx(155.0, abs=1e-6)
    assert tasks.tilt_error(on_side, target) == pytest.approx(90.0)
    assert tasks.tilt_error(upside_down, target) == pytest.approx(180.0)
    assert tasks.tilt_error(-on_side, 2.0 * target) == pytest.approx(90.0)  # sign and norm
    # a tilted target: the lean is measured from the axis the target holds upright
    leaning = tasks.quat_from_yaw_pitch_roll(0.0, 0.5, 0.0)
    assert tasks.tilt_error(leaning, leaning) == pytest.approx(0.0, abs=1e-6)
    assert tasks.tilt_error(target, leaning) == pytest.approx(math.degrees(0.5))
    batch = tasks.tilt_error(np.stack([turned, on_side]), target)
    assert batch.shape == (2,) and batch[1] == pytest.approx(90.0)
    with pytest.raises(ValueError, match=r"quat and target_quat must be \(\.\.\., 4\)"):
        tasks.tilt_error([1.0, 0.0, 0.0], target)
