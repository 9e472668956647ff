"""The paper's tasks: pose samplers, per-object settings, errors and success criteria.

The three-fingertip tasks (rotation, flip, in-air) have per-object settings here; the hand
tasks (TriFinger in-hand, Allegro on-palm) take their resting poses from the plant, which
knows its object's shape and the support it rests on.

Poses are ``(7,)`` arrays: position [m] then a unit quaternion (w, x, y, z), as in MuJoCo.
Every function here is pure NumPy.

Seeding: trial ``k`` of any (task, object) pair draws from ``np.random.default_rng(k)``, in
the order documented by :func:`sample`, so a trial is reproducible from its index alone (the
reference code seeds NumPy's global generator with ``100 + k`` instead; the draws differ, the
distributions are the same).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from torchcontact.sim.plant import as_vector

TASKS = ("rotation", "flip", "in-air")
"""On-ground rotation, on-ground flip, and in-air manipulation."""

TRIALS = 20
"""Trials per (task, object) pair in the paper; trial k uses seed k."""

PAPER_PAIRS: tuple[tuple[str, str], ...] = (
    ("rotation", "cube"),
    ("flip", "cube"),
    ("in-air", "cube"),
    ("rotation", "foam_brick"),
    ("flip", "foam_brick"),
    ("in-air", "foam_brick"),
    ("flip", "stick"),
    ("rotation", "bunny"),
    ("in-air", "bunny"),
)
"""The (task, object) pairs of the paper's fingertip experiments."""

INITIAL_XY_RANGE = 0.025
"""Initial object x, y ~ U[−0.025, 0.025] [m]."""

TARGET_XY_RANGE = 0.1
"""Target object x, y ~ U[−0.1, 0.1] [m]."""

IN_AIR_AXIS = np.array([0.0, 1.0, 1.0])
IN_AIR_AXIS_NOISE = 0.1
"""In-air target rotation axis ~ (0, 1, 1) + 0.1·N(0, I), normalised; angle ~ U[−π, π]."""


@dataclass(frozen=True)
class ObjectSettings:
    """Per-object numbers of the fingertip experiments (plant, sampler and model).

    Attributes:
        rest_height: z [m] of the object origin (its box centre; the bunny's lower, see
            ``OBJECT_ORIGIN_HEIGHTS``) resting upright on the ground, for our meshes
            (``torchcontact.sim.objects``): the initial z and the rotation-task target z.
        flip_height: target z [m] of the flip task; None when the paper has no flip task.
        flip_pitch: whether flip targets tilt in pitch as well as roll (False: roll only).
        in_air_height: (low, high) range [m] of in-air target z; None without that task.
        object_friction: the object's sliding friction in the plant.
        rotational_metric: angular diagonal of the object metric εMₒ/h² in the model.
        contact_slots: contact slots nc of the model.
        model_step: the model's time step h [s].
        tip_height_max: the paper's upper bound [m] on planned tip z (lower bound 0), None:
            unbounded; applied by ``fingertips_mpc(obj, bound_tips=True)``.
        translational_metric: linear diagonal of εMₒ/h² (50 for every object).
    """

    rest_height: float
    flip_height: float | None
    flip_pitch: bool
    in_air_height: tuple[float, float] | None
    object_friction: float
    rotational_metric: float
    contact_slots: int
    model_step: float
    tip_height_max: float | None
    translational_metric: float = 50.0

    def supports(self, task: str) -> bool:
        """Whether ``task`` is defined for this object."""
        if task == "flip":
            return self.flip_height is not None
        if task == "in-air":
            return self.in_air_height is not None
        return task == "rotation"


OBJECT_SETTINGS: dict[str, ObjectSettings] = {
    # Rest heights are our meshes' (cube and stick equal the reference's; the reference
    # starts the foam brick at 0.03 m and lets it drop); flip and in-air heights, slots,
    # metrics, h, friction and tip bounds are the reference's numbers.
    "cube": ObjectSettings(
        rest_height=0.03,
        flip_height=0.05,
        flip_pitch=True,
        in_air_height=(0.05, 0.10),
        object_friction=0.9,
        rotational_metric=0.05,
        contact_slots=8,
        model_step=0.1,
        tip_height_max=None,
    ),
    "foam_brick": ObjectSettings(
        rest_height=0.0235,
        flip_height=0.03,
        flip_pitch=True,
        in_air_height=(0.04, 0.09),
        object_friction=0.9,
        rotational_metric=0.05,
        contact_slots=10,
        model_step=0.05,
        tip_height_max=0.1,
    ),
    "stick": ObjectSettings(
        rest_height=0.015,
        flip_height=0.015,
        flip_pitch=False,
        in_air_height=None,
        object_friction=0.5,
        rotational_metric=0.05,
        contact_slots=8,
        model_step=0.1,
        tip_height_max=0.1,
    ),
    # Our bunny is ellipsoid parts, not the reference's scan: its in-air heights keep the
    # reference's lift above rest (0.009–0.059 m); 12 slots instead of 10 because a tip on a
    # seam between two parts touches both (11 contacts seen while squeezing it).
    "bunny": ObjectSettings(
        rest_height=0.03,
        flip_height=None,
        flip_pitch=False,
        in_air_height=(0.039, 0.089),
        object_friction=0.9,
        rotational_metric=0.06,
        contact_slots=12,
        model_step=0.1,
        tip_height_max=None,
    ),
}


@dataclass(frozen=True)
class SuccessCriterion:
    """Success: ``‖p − p*‖ < position_tolerance`` and ``e < quaternion_tolerance`` held for
    ``hold_steps`` consecutive steps, within ``max_steps`` steps."""

    position_tolerance: float = 0.02
    quaternion_tolerance: float = 0.015
    hold_steps: int = 20
    max_steps: int = 2000


FINGERTIPS_SUCCESS = SuccessCriterion()
"""The fingertip tasks' criterion: 2 cm, e < 0.015 (14.1°), 20 steps, 2000 steps at most."""

TRIFINGER_SUCCESS = SuccessCriterion(quaternion_tolerance=0.04, max_steps=500)
"""TriFinger in-hand: 2 cm, e < 0.04 (23.1°), 20 steps, 500 steps at most."""

ALLEGRO_SUCCESS = SuccessCriterion(
    position_tolerance=math.inf, quaternion_tolerance=0.04, max_steps=500
)
"""Allegro on-palm: orientation only, e < 0.04 (23.1°), 20 steps, 500 steps at most."""

AIM_LIFT_FRACTION = 0.5
"""How far :func:`aim_pose` may raise a sunken target, as a fraction of the position tolerance."""


RESTING_TOLERANCE = 1e-9
"""[m] A target sunk by at most this counts as resting: the resting height comes from mesh
vertices, whose rounding leaves a target placed at rest up to ~1e-17 m low."""


def aim_pose(target_pose, resting_height: float, position_tolerance: float) -> np.ndarray:
    """The ``(7,)`` pose the MPC plans toward for ``target_pose (7,)``: raised out of its support.

    The flip targets' height is the object's whatever their tilt (the reference's), so most
    tilted targets sink into the ground: the foam brick's by up to 21 mm. Planning toward
    such a target presses the object down, and the ground's friction then holds it flat. The
    aim is the target raised toward ``resting_height`` [m] (the lowest height at which the
    object in the target's orientation does not sink, :meth:`Plant.resting_height`), by at
    most :data:`AIM_LIFT_FRACTION` of ``position_tolerance`` [m], so that reaching the aim
    still counts as reaching the target; success is judged against the target itself. A
    target at or above its resting height (every sampled rotation and hand target, most
    in-air ones) is returned unchanged, as is one within :data:`RESTING_TOLERANCE` of it.
    """
    target = np.asarray(target_pose, dtype=float)
    if target.shape != (7,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target_pose must be 7 finite numbers, got {target_pose!r}")
    if not math.isfinite(resting_height):
        raise ValueError(f"resting_height must be a finite height [m], got {resting_height!r}")
    if not position_tolerance > 0:
        raise ValueError(f"position_tolerance must be positive, got {position_tolerance!r}")
    sink = resting_height - target[2]
    aim = target.copy()
    if sink > RESTING_TOLERANCE:
        aim[2] += min(sink, AIM_LIFT_FRACTION * position_tolerance)
    return aim


IN_HAND_XY_RANGE = 0.05
"""TriFinger initial and target x, y ~ U[−0.05, 0.05] [m]; yaw ~ U[−π/2, π/2]."""

ON_PALM_XY_STD = 0.005
"""Allegro initial x, y ~ palm centre + N(0, 0.005²) [m]; yaw ~ U[−π/2, π/2]."""

ON_PALM_YAW_RANGE = (-math.pi / 2, math.pi / 2)
"""Allegro initial yaw range [rad]."""

ON_PALM_OBJECT_YAW_RANGES = {"stick": (math.pi / 4, 3 * math.pi / 4)}
"""Per-object exceptions of the paper's code: the 13 cm stick starts across the palm."""

ON_PALM_PLACEMENTS: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "airplane": ((-0.03, -0.01), (-0.02, -0.01)),
    "binoculars": ((-0.03, 0.0), (-0.01, 0.0)),
    "bowl": ((-0.03, 0.0), (-0.03, -0.01)),
    "bunny": ((-0.03, 0.0), (0.0, 0.0)),
    "camera": ((-0.03, 0.0), (-0.01, 0.0)),
    "can": ((-0.02, 0.0), (-0.01, 0.0)),
    "cube": ((-0.03, -0.01), (-0.01, 0.0)),
    "cup": ((-0.03, 0.0), (0.0, 0.0)),
    "elephant": ((-0.02, 0.0), (-0.01, 0.0)),
    "foam_brick": ((-0.01, 0.0), (-0.01, 0.0)),
    "mug": ((0.0, 0.0), (0.0, 0.0)),
    "piggy_bank": ((0.0, 0.0), (0.0, 0.0)),
    "rubber_duck": ((-0.02, 0.0), (0.0, 0.0)),
    "stick": ((-0.01, 0.0), (-0.01, 0.0)),
    "teapot": ((-0.02, 0.0), (0.0, 0.0)),
    "torus": ((-0.02, 0.0), (0.0, 0.0)),
    "water_bottle": ((-0.02, 0.0), (0.0, 0.0)),
}
"""Allegro (initial x, y centre, target x, y) [m] per object in the hand's world frame (the
palm spans x ∈ [−0.095, 0], fingers towards +x), from the paper's per-object settings: most
objects start nearer the wrist and are to end nearer the fingers. Other objects use the palm
centre for both."""


# --- rotations ---------------------------------------------------------------------------


def quat_from_yaw_pitch_roll(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """``(4,)`` quaternion of R = R_z(yaw) R_y(pitch) R_x(roll) [rad]."""
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_from_axis_angle(axis, angle: float) -> np.ndarray:
    """``(4,)`` quaternion of a rotation by ``angle`` [rad] about ``axis (3,)`` (any length)."""
    axis = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(axis)
    if axis.shape != (3,) or not norm > 0:
        raise ValueError(f"axis must be a non-zero 3-vector, got {axis!r}")
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis / norm])


# --- errors ------------------------------------------------------------------------------


def quaternion_error(quat, target_quat) -> np.ndarray:
    """``e = 1 − ⟨q, q*⟩²`` (= sin²(θ/2)) for unit quaternions ``(..., 4)``; 0 when aligned.

    The NumPy form of :func:`torchcontact.rotations.quaternion_error` for the success test and
    the trial records, kept in NumPy: for one quaternion, NumPy's scalar ``dot**2`` (``pow``)
    and ``arccos`` differ from torch's in the last bit now and then, and the records must not.
    """
    dot = np.sum(np.asarray(quat, dtype=float) * np.asarray(target_quat, dtype=float), axis=-1)
    return 1.0 - dot**2


def angle_error(quat, target_quat) -> np.ndarray:
    """Rotation angle θ = arccos(2⟨q, q*⟩² − 1) [deg] between unit quaternions ``(..., 4)``
    (the NumPy form of :func:`torchcontact.rotations.quaternion_angle`, in degrees)."""
    cosine = 1.0 - 2.0 * quaternion_error(quat, target_quat)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def position_error(position, target_position) -> np.ndarray:
    """Euclidean distance [m] between positions ``(..., 3)``."""
    delta = np.asarray(position, dtype=float) - np.asarray(target_position, dtype=float)
    return np.linalg.norm(delta, axis=-1)


FALL_DROP = 0.05
"""[m] How far below its initial height an object must end to count as fallen off its support.
The Allegro's palm lies about 0.2 m above the floor; in the other tasks the object starts on
the floor and cannot end lower."""


def fell(initial_pose, final_pose) -> bool:
    """Whether the object ended more than :data:`FALL_DROP` below its initial height (it left
    the palm), for poses ``(7,)``: position [m], quaternion (w, x, y, z)."""
    start, end = np.asarray(initial_pose, dtype=float), np.asarray(final_pose, dtype=float)
    if start.shape != (7,) or end.shape != (7,):
        raise ValueError(
            f"initial_pose and final_pose must be (7,) poses, got {start.shape} and {end.shape}"
        )
    return bool(end[2] < start[2] - FALL_DROP)


TIPPED_TILT = 45.0
"""[deg] The :func:`tilt_error` past which an object counts as tipped over (or, where the
target is tilted, as not stood the way the target stands)."""


def tilt_error(quat, target_quat) -> np.ndarray:
    """[deg] The angle between the object's body axis that stands upright at the target and
    world up, for unit quaternions ``(..., 4)`` (w, x, y, z): the part of the orientation
    error that no turn about the vertical removes (0 for an object turned about it alone,
    90 for one lying on its side, 180 upside down).

    With ``r = q ⊗ q*⁻¹`` the rotation from the target to ``q``, that axis points along
    ``R(r)·ẑ``, whose vertical component is ``1 − 2(r_x² + r_y²)``.
    """
    q = np.asarray(quat, dtype=float)
    t = np.asarray(target_quat, dtype=float)
    if q.shape[-1:] != (4,) or t.shape[-1:] != (4,):
        raise ValueError(
            f"quat and target_quat must be (..., 4) quaternions, got {q.shape} and {t.shape}"
        )
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    tw, tx, ty, tz = np.moveaxis(t, -1, 0)
    # r = q ⊗ conj(t): only its x and y components are needed
    rx = -qw * tx + qx * tw - qy * tz + qz * ty
    ry = -qw * ty + qx * tz + qy * tw - qz * tx
    up = 1.0 - 2.0 * (rx**2 + ry**2) / np.sum(q * q, -1) / np.sum(t * t, -1)
    return np.degrees(np.arccos(np.clip(up, -1.0, 1.0)))


# --- sampling ----------------------------------------------------------------------------


def sample(task: str, obj: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Initial and target object poses ``(7,), (7,)`` of trial ``seed``.

    Draws from ``np.random.default_rng(seed)`` in this order: initial x, y ~ U[−0.025,
    0.025]; initial yaw ~ U[−π, π]; target x, y ~ U[−0.1, 0.1]; then per task

    - ``"rotation"``: yaw ~ U[−π, π]; z = rest height.
    - ``"flip"``: yaw ~ U[−π, π], pitch ~ U[−π/2, π/2] (objects with ``flip_pitch``), roll ~
      U[−π/2, π/2]; z = the object's flip height.
    - ``"in-air"``: z ~ U[in_air_height]; angle ~ U[−π, π]; axis = (0, 1, 1) + 0.1·N(0, I).

    The initial pose rests upright (z = rest height) with only yaw.
    """
    if task not in TASKS:
        raise ValueError(f"task must be one of {TASKS}, got {task!r}")
    if obj not in OBJECT_SETTINGS:
        raise ValueError(f"obj must be one of {tuple(OBJECT_SETTINGS)}, got {obj!r}")
    settings = OBJECT_SETTINGS[obj]
    if not settings.supports(task):
        raise ValueError(f"task {task!r} is not defined for obj {obj!r}")
    rng = np.random.default_rng(_seed(seed))
    initial_xy = rng.uniform(-INITIAL_XY_RANGE, INITIAL_XY_RANGE, 2)
    initial_quat = quat_from_yaw_pitch_roll(rng.uniform(-np.pi, np.pi))
    initial = np.concatenate([initial_xy, [settings.rest_height], initial_quat])
    target_xy = rng.uniform(-TARGET_XY_RANGE, TARGET_XY_RANGE, 2)
    if task == "rotation":
        height = settings.rest_height
        quat = quat_from_yaw_pitch_roll(rng.uniform(-np.pi, np.pi))
    elif task == "flip":
        height = settings.flip_height
        yaw = rng.uniform(-np.pi, np.pi)
        pitch = rng.uniform(-np.pi / 2, np.pi / 2) if settings.flip_pitch else 0.0
        quat = quat_from_yaw_pitch_roll(yaw, pitch, rng.uniform(-np.pi / 2, np.pi / 2))
    else:
        height = rng.uniform(*settings.in_air_height)
        angle = rng.uniform(-np.pi, np.pi)
        axis = IN_AIR_AXIS + IN_AIR_AXIS_NOISE * rng.standard_normal(3)
        quat = quat_from_axis_angle(axis, angle)
    target = np.concatenate([target_xy, [height], quat])
    return initial, target


RestingPose = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``(xy (2,), quat (4,)) ↦ (7,)`` pose resting on the support (``HandPlant.resting_pose``)."""


def sample_in_hand(resting_pose: RestingPose, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """TriFinger in-hand trial ``seed``: initial and target poses ``(7,), (7,)``.

    Draws from ``np.random.default_rng(seed)``: initial x, y ~ U[−0.05, 0.05], yaw ~
    U[−π/2, π/2]; then the target's x, y and yaw from the same ranges; both rest upright.
    """
    rng = np.random.default_rng(_seed(seed))
    initial = resting_pose(
        rng.uniform(-IN_HAND_XY_RANGE, IN_HAND_XY_RANGE, 2),
        quat_from_yaw_pitch_roll(rng.uniform(-np.pi / 2, np.pi / 2)),
    )
    target = resting_pose(
        rng.uniform(-IN_HAND_XY_RANGE, IN_HAND_XY_RANGE, 2),
        quat_from_yaw_pitch_roll(rng.uniform(-np.pi / 2, np.pi / 2)),
    )
    return initial, target


def sample_on_palm(
    resting_pose: RestingPose,
    centre,
    target_centre=None,
    *,
    seed: int,
    yaw_range: tuple[float, float] = ON_PALM_YAW_RANGE,
) -> tuple[np.ndarray, np.ndarray]:
    """Allegro on-palm trial ``seed``: initial and target poses ``(7,), (7,)``.

    Draws from ``np.random.default_rng(seed)``: initial x, y ~ ``centre (2,)`` + N(0,
    0.005²), yaw ~ U[``yaw_range``] [rad] (the paper's U[−π/2, π/2]; its code starts the stick
    in U[π/4, 3π/4], see :data:`ON_PALM_OBJECT_YAW_RANGES`), then the turn direction s = ±1
    (fair coin); the target rests at ``target_centre (2,)`` (default ``centre``, see
    :data:`ON_PALM_PLACEMENTS`) with yaw = initial yaw + s·π/2.
    """
    low, high = yaw_range
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise ValueError(f"yaw_range must be finite (low, high) with low <= high, got {yaw_range}")
    rng = np.random.default_rng(_seed(seed))
    centre = as_vector("centre", centre, 2)
    yaw = rng.uniform(low, high)
    initial = resting_pose(
        centre + ON_PALM_XY_STD * rng.standard_normal(2), quat_from_yaw_pitch_roll(yaw)
    )
    turn = np.pi / 2 if rng.uniform() < 0.5 else -np.pi / 2
    end = centre if target_centre is None else as_vector("target_centre", target_centre, 2)
    target = resting_pose(end, quat_from_yaw_pitch_roll(yaw + turn))
    return initial, target


def _seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


# --- success -----------------------------------------------------------------------------


class SuccessTracker:
    """Counts steps and consecutive in-tolerance steps of one trial.

    Call :meth:`update` after every plant step with the object pose; the trial succeeds once
    the pose has been within tolerance for ``hold_steps`` consecutive steps, and is over
    (``done``) on success or after ``max_steps`` steps.
    """

    def __init__(self, target_pose, criterion: SuccessCriterion = FINGERTIPS_SUCCESS):
        target = np.asarray(target_pose, dtype=float)
        if target.shape != (7,) or not np.all(np.isfinite(target)):
            raise ValueError(f"target_pose must be 7 finite numbers, got {target_pose!r}")
        self.target = target
        self.criterion = criterion
        self.steps = 0
        self.consecutive = 0
        self.success_step: int | None = None

    def update(self, object_pose) -> bool:
        """Record the pose ``(7,)`` (or a full state whose first 7 entries are the object
        pose) after one step; returns :attr:`done`."""
        pose = np.asarray(object_pose, dtype=float)
        if pose.ndim != 1 or pose.shape[0] < 7:
            raise ValueError(f"object_pose must have at least 7 entries, got {pose.shape}")
        self.steps += 1
        if self.within_tolerance(pose[:7]):
            self.consecutive += 1
        else:
            self.consecutive = 0
        if self.success_step is None and self.consecutive >= self.criterion.hold_steps:
            self.success_step = self.steps
        return self.done

    def within_tolerance(self, pose: np.ndarray) -> bool:
        """Whether ``pose (7,)`` is within the position and quaternion tolerances."""
        close = position_error(pose[:3], self.target[:3]) < self.criterion.position_tolerance
        aligned = quaternion_error(pose[3:7], self.target[3:]) < self.criterion.quaternion_tolerance
        return bool(close and aligned)

    @property
    def succeeded(self) -> bool:
        return self.success_step is not None

    @property
    def done(self) -> bool:
        return self.succeeded or self.steps >= self.criterion.max_steps
