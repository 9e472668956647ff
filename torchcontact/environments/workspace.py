"""What a robot's MJCF says about its task: initial joints, control bound, reach, placement.

:func:`robot_defaults` reads the file alone (initial joints from its first keyframe or the
joints' reference positions; the control bound from the ranges its position actuators
command). :func:`reach` samples the joints over those ranges, keeps the fingertip positions
from which a tip touches an object's side, and turns them into where the object is placed
and the region its targets are drawn from: a target is offered along an axis only as far as
a tip that starts on the far side of the object can push it (the far half of that where the
object can be pushed one way only), and a lift only where two tips on opposite sides can
squeeze it and rise.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from torchcontact.sim.kinematics import load_model, robot_joints, site_ids

STEPS_ACROSS = 40
"""The control bound lets the narrowest commanded joint range be crossed in this many steps."""

REACH_SAMPLES = 4096
"""Joint configurations sampled (uniformly, seed 0) to map the tips' workspace."""

TARGET_SHARE = 0.5
"""Targets are drawn from this share of the reachable range, leaving room to hold the pose."""


@dataclass(frozen=True)
class RobotDefaults:
    """What the MJCF says about a trial's robot, and where each value came from.

    Attributes:
        initial_joints: ``(n_joints,)`` joints at the start of a trial [rad or m].
        initial_source: in words, where they come from.
        control_bound: |u| per joint and step [rad or m].
        control_source: in words, how it was derived.
        joint_ranges: ``(n_joints, 2)`` the range each joint is commanded over [rad or m].
    """

    initial_joints: tuple[float, ...]
    initial_source: str
    control_bound: float
    control_source: str
    joint_ranges: np.ndarray

    def describe(self) -> str:
        joints = ", ".join(f"{x:g}" for x in self.initial_joints)
        return (
            f"initial joints ({joints}) from {self.initial_source}; control bound "
            f"{self.control_bound:.3g} per step ({self.control_source})"
        )


def robot_defaults(mjcf: str | Path) -> RobotDefaults:
    """The :class:`RobotDefaults` of the robot file ``mjcf``: ``ValueError`` naming ``mjcf``
    when a joint has neither a joint range nor a commanded control range."""
    path, model = load_model(mjcf)
    joints = robot_joints(model, path.name)
    addresses = [int(model.jnt_qposadr[j]) for j in joints]
    if model.nkey > 0:
        key = model.key(0).name or "0"
        initial = model.key_qpos[0][addresses]
        initial_source = f"keyframe {key!r}"
    else:
        initial = model.qpos0[addresses]
        initial_source = "the joints' reference positions"
    ranges = _commanded_ranges(model, joints, path.name)
    widths = ranges[:, 1] - ranges[:, 0]
    narrowest = int(np.argmin(widths))
    bound = float(widths[narrowest]) / STEPS_ACROSS
    source = f"1/{STEPS_ACROSS} of joint {model.joint(joints[narrowest]).name}'s range"
    return RobotDefaults(
        initial_joints=tuple(float(x) for x in initial),
        initial_source=initial_source,
        control_bound=bound,
        control_source=source,
        joint_ranges=ranges,
    )


def _commanded_ranges(model: mujoco.MjModel, joints: list[int], source: str) -> np.ndarray:
    """Per robot joint, its range [rad or m]: the joint's limits, narrowed to what its
    position actuator's ``ctrlrange`` commands (``q = ctrl/gear``)."""
    ranges = np.full((len(joints), 2), [-np.inf, np.inf])
    index = {j: i for i, j in enumerate(joints)}
    for i, j in enumerate(joints):
        if model.jnt_limited[j]:
            ranges[i] = model.jnt_range[j]
    for a in range(model.nu):
        joint = int(model.actuator_trnid[a, 0])
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or joint not in index:
            continue
        if model.actuator_ctrllimited[a]:
            low, high = sorted(model.actuator_ctrlrange[a] / model.actuator_gear[a, 0])
            i = index[joint]
            ranges[i] = max(ranges[i, 0], low), min(ranges[i, 1], high)
    unbounded = [
        model.joint(j).name for i, j in enumerate(joints) if not np.isfinite(ranges[i]).all()
    ]
    if unbounded:
        raise ValueError(
            f"mjcf: every robot joint of {source} needs a range (a joint range or its "
            f"actuator's ctrlrange) to derive the control bound and the reach; {unbounded} "
            "have none: give them one, or give control_bound and the task's target region"
        )
    return ranges


@dataclass(frozen=True)
class Reach:
    """Where an object is placed and where its targets may be, from the tips' workspace.

    Attributes:
        placement: ``(2,)`` the object's initial x, y [m].
        target_x, target_y: the target's offset from ``placement`` along x and y [m], each
            (low, high); (0, 0) where no tip can push the object that way.
        lift: the target's rise above resting (low, high) [m]; (0, 0) where no two tips can
            squeeze the object from opposite sides and rise.
        given: the fields above that were given rather than derived.
    """

    placement: tuple[float, float]
    target_x: tuple[float, float]
    target_y: tuple[float, float]
    lift: tuple[float, float]
    given: tuple[str, ...] = ()

    def describe(self) -> str:
        def span(values):
            return f"{1e3 * values[0]:+.0f} to {1e3 * values[1]:+.0f} mm"

        def given(name):
            return " (given)" if name in self.given else ""

        x, y = self.placement
        derived = len(self.given) < 4
        return (
            f"object placed at ({1e3 * x:.0f}, {1e3 * y:.0f}) mm{given('placement')}; targets "
            f"x {span(self.target_x)}{given('target_x')}, y {span(self.target_y)}"
            f"{given('target_y')}, lift {span(self.lift)}{given('lift')}"
            + (", the rest from the tips' reach" if self.given and derived else "")
            + ("" if self.given else ", from the tips' reach")
        )


def tip_workspace(
    mjcf: str | Path, tips, ranges: np.ndarray, initial: tuple[float, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Fingertips ``(REACH_SAMPLES, n_tips, 3)`` [m] at joints drawn uniformly over
    ``ranges (n_joints, 2)``, and ``(n_tips, 3)`` at the ``initial`` joints."""
    path, model = load_model(mjcf)
    sites = site_ids(model, tips, path.name)
    addresses = [int(model.jnt_qposadr[j]) for j in robot_joints(model, path.name)]
    rng = np.random.default_rng(0)
    samples = rng.uniform(ranges[:, 0], ranges[:, 1], (REACH_SAMPLES, len(addresses)))
    data = mujoco.MjData(model)

    def at(joints):
        data.qpos[addresses] = joints
        mujoco.mj_kinematics(model, data)
        return data.site_xpos[sites].copy()

    return np.stack([at(joints) for joints in samples]), at(np.asarray(initial))


def reach(
    points: np.ndarray,
    start: np.ndarray,
    extent: np.ndarray,
    support_height: float,
    centre: np.ndarray,
) -> Reach:
    """The :class:`Reach` of an object of bounding box ``extent (3,)`` [m] resting at
    ``support_height`` [m], for tips reaching ``points (N, n_tips, 3)`` and starting at
    ``start (n_tips, 3)``; the object stays at ``centre (2,)`` where a tip can touch it there.
    """
    half = extent / 2
    low, high = support_height + 0.2 * extent[2], support_height + extent[2]
    beside = (points[..., 2] >= low) & (points[..., 2] <= high)  # (N, n_tips): at its side
    if not beside.any():
        raise ValueError(
            "robot: no fingertip reaches the height of the object's side "
            f"({1e3 * low:.0f} to {1e3 * high:.0f} mm) anywhere in its joint ranges"
        )
    placement = np.asarray(centre, dtype=float)
    if not _touches(points, beside, placement, half):
        placement = points[beside][:, :2].mean(0)
    offsets, squeezers = [], []
    for axis in (0, 1):
        across = 1 - axis
        on_line = beside & (np.abs(points[..., across] - placement[across]) <= half[across])
        c, r = placement[axis], half[axis]
        up, down = 0.0, 0.0
        for tip in range(points.shape[1]):
            reached = points[on_line[:, tip], tip, axis]
            if reached.size == 0:
                continue
            # a tip on the object's − side pushes it + as far as the tip goes, and so on
            if start[tip, axis] < c - r and reached.min() <= c - r:
                up = max(up, reached.max() + r - c)
                squeezers.append((axis, -1, tip))
            if start[tip, axis] > c + r and reached.max() >= c + r:
                down = min(down, reached.min() - r - c)
                squeezers.append((axis, 1, tip))
        offsets.append(_targets(down, up))
    return Reach(
        placement=(float(placement[0]), float(placement[1])),
        target_x=offsets[0],
        target_y=offsets[1],
        lift=_lift(points, squeezers, placement, half, support_height),
    )


def _targets(down: float, up: float) -> tuple[float, float]:
    """Target offsets along one axis the tips push ``down`` ≤ 0 to ``up`` ≥ 0 [m]: both ways,
    :data:`TARGET_SHARE` of each; one way only, the far half of that share, so that no target
    is met by not moving."""
    if down < 0 < up or down == up == 0:
        return (TARGET_SHARE * down, TARGET_SHARE * up)
    far = TARGET_SHARE * (down or up)
    return tuple(sorted((far / 2, far)))


def _touches(points, beside, centre, half) -> bool:
    """Whether some tip at the side's height comes within the object's box around ``centre``
    (grown by half its size): it can touch an object placed there."""
    near = np.abs(points[..., :2] - centre) <= 1.5 * half[:2]
    return bool((beside & near.all(-1)).any())


def _lift(points, squeezers, centre, half, support_height) -> tuple[float, float]:
    """The lift range two tips pressing on opposite faces along one axis can carry the
    object through: up to the lower of the heights each reaches at its face."""
    best = 0.0
    for axis in (0, 1):
        sides = {side: [t for a, s, t in squeezers if a == axis and s == side] for side in (-1, 1)}
        if not (sides[-1] and sides[1]):
            continue
        tops = []
        for side in (-1, 1):
            face = centre[axis] + side * half[axis]
            heights = [
                points[np.abs(points[:, tip, axis] - face) <= 0.5 * half[axis], tip, 2]
                for tip in sides[side]
            ]
            tops.append(max((h.max() for h in heights if h.size), default=support_height))
        # the tips grip the object's side at mid-height: it rises as far as they do
        best = max(best, min(tops) - (support_height + half[2]))
    return (TARGET_SHARE * best / 2, TARGET_SHARE * best) if best > 0 else (0.0, 0.0)
