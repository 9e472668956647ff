"""A user's robot as an environment: one MJCF file plus :func:`from_mjcf`.

The file holds the robot only, in the scene's world frame (ground at z = 0, the object near
the origin), as ``torchcontact/assets/*.xml`` do: the plant attaches it beside the ground and
the object, the robot's joints, actuators and fingertip sites are read from it, and the MPC's
model takes the plant's object mass. Run it with ``torchcontact run custom --robot FILE --tips
a,b --object cube`` or, in Python::

    env = from_mjcf("examples/two_finger_gripper.xml", task=PoseTask(target_x=(0, 0)))
    plant = env.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(env, plant)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchcontact.environments import tasks
from torchcontact.environments.costs import Cost, ManipulationCost
from torchcontact.environments.hands import TRIFINGER_PRESETS, HandEnvironment, HandModel
from torchcontact.sim.hands import Hand, HandEnv
from torchcontact.sim.robot import Robot


@dataclass(frozen=True)
class PoseTask:
    """Move the object from a resting pose to a target pose near the support's centre.

    Trial ``seed`` draws from ``np.random.default_rng(seed)``: the initial x, y ~ centre +
    U[−initial_xy, initial_xy]² [m] and yaw ~ U[−yaw, yaw] [rad], resting; then the target's
    offset from the centre, x ~ U[``target_x``], y ~ U[``target_y``] [m], and its yaw ~
    U[−yaw, yaw], raised above its resting height by U[``lift``] [m].
    """

    name: str = "reposition"
    initial_xy: float = 0.0
    target_x: tuple[float, float] = (-0.03, 0.03)
    target_y: tuple[float, float] = (-0.03, 0.03)
    lift: tuple[float, float] = (0.0, 0.0)
    yaw: float = 0.0
    criterion: tasks.SuccessCriterion = tasks.TRIFINGER_SUCCESS

    def __post_init__(self):
        for name in ("initial_xy", "yaw"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
        for name in ("target_x", "target_y", "lift"):
            low, high = getattr(self, name)
            if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                raise ValueError(f"{name} must be finite (low, high) with low <= high")
        if self.lift[0] < 0:
            raise ValueError(f"lift must not be negative, got {self.lift}")

    def __call__(self, plant: HandEnv, task: str, seed: int):
        """Initial and target poses ``(7,), (7,)`` of trial ``seed`` on ``plant``."""
        rng = np.random.default_rng(seed)
        centre = plant.support_centre
        initial = plant.resting_pose(
            centre + rng.uniform(-self.initial_xy, self.initial_xy, 2),
            tasks.quat_from_yaw_pitch_roll(rng.uniform(-self.yaw, self.yaw)),
        )
        offset = rng.uniform(*zip(self.target_x, self.target_y, strict=True))
        target = plant.resting_pose(
            centre + offset, tasks.quat_from_yaw_pitch_roll(rng.uniform(-self.yaw, self.yaw))
        )
        target[2] += rng.uniform(*self.lift)
        return initial, target


def from_mjcf(
    robot: str | Path,
    tips: tuple[str, ...] | None = None,
    *,
    name: str = "custom",
    task: PoseTask | None = None,
    cost: Cost | None = None,
    initial_joints: tuple[float, ...] | None = None,
    control_bound: float = 0.005,
    robot_stiffness: float = 100.0,
    stiffness: float = 0.5,
    frame_skip: int = 50,
    objects: tuple[str, ...] = ("cube",),
    clear_start: bool = True,
) -> HandEnvironment:
    """The environment of the robot in MJCF file ``robot``.

    Args:
        robot: the robot's MJCF (joints at their body's origin; one position actuator per
            joint, driven with ``ctrl = q + u``, or motors driven as a PD servo is not
            supported here).
        tips: fingertip site names; None: the file's sites named ``*tip``.
        name: the environment's name (its records' prefix).
        task: the sampler and success criterion (default :class:`PoseTask`'s).
        cost: the MPC cost (default the paper's manipulation cost with TriFinger's weights and
            its contact floor, :attr:`HandModel.contact_floor`).
        initial_joints: joints at the start of every trial; None: the file's ``qpos0``.
        control_bound: |u| per joint and step [rad or m].
        robot_stiffness: Kᵣ of the quasi-dynamic robot.
        stiffness: K of the paper's contact model.
        frame_skip: MuJoCo substeps (2 ms) per control step.
        objects: the built-in objects of ``--object all``.
        clear_start: move the initial joints out of an object placed through a finger at
            the start of a trial (:attr:`~torchcontact.sim.hands.Hand.clear_start`).
    """
    path = Path(robot).resolve()
    description = Robot.from_mjcf(path, tips)
    if any(actuator.kind != "position" for actuator in description.actuators):
        raise ValueError(f"robot must drive every joint with a position actuator: {path.name}")
    if initial_joints is None:
        initial_joints = tuple(0.0 for _ in description.joint_names)
    task = PoseTask() if task is None else task
    hand = Hand(
        name=name,
        asset=str(path),
        initial_joints=tuple(float(x) for x in initial_joints),
        frame_skip=frame_skip,
        servo="position",
        object_friction=0.5,
        ground_friction=0.5,
        camera_position=(0.0, -0.4, 0.35),
        tip_sites=None if tips is None else tuple(tips),
        clear_start=clear_start,
    )
    model = HandModel(
        robot_stiffness=robot_stiffness,
        stiffness=stiffness,
        control_bound=control_bound,
        cost=ManipulationCost(contact=0.5, grasp=0.05, control=10.0) if cost is None else cost,
        contact_floor=cost is None,  # the default cost draws tips no lower than they can go
    )
    return HandEnvironment(hand, model, task.name, task.criterion, task, TRIFINGER_PRESETS, objects)
