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

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchcontact.environments import fingertips, tasks, workspace
from torchcontact.environments.costs import Cost, ManipulationCost
from torchcontact.environments.hands import TRIFINGER_PRESETS, HandEnvironment, HandModel
from torchcontact.sim.hands import Hand, HandPlant
from torchcontact.sim.kinematics import load_model, object_bodies
from torchcontact.sim.robot import Robot
from torchcontact.validation import is_finite_number


@dataclass(frozen=True)
class PoseTask:
    """Move the object from a resting pose to a target pose within the robot's reach.

    Trial ``seed`` draws from ``np.random.default_rng(seed)``: the initial x, y ~ placement +
    U[−initial_xy, initial_xy]² [m] and yaw ~ U[−yaw, yaw] [rad], resting; then the target's
    offset from the placement, x ~ U[``target_x``], y ~ U[``target_y``] [m], and its yaw ~
    U[−yaw, yaw], raised above its resting height by U[``lift``] [m]. Each of ``placement``,
    ``target_x``, ``target_y`` and ``lift`` left None is derived from the robot's reach around
    the plant's object (:func:`~torchcontact.environments.workspace.reach`): the support's
    centre where a tip can touch the object there, and only as far as the tips can push or
    lift it.
    """

    name: str = "reposition"
    initial_xy: float = 0.0
    target_x: tuple[float, float] | None = None
    target_y: tuple[float, float] | None = None
    lift: tuple[float, float] | None = None
    yaw: float = 0.0
    placement: tuple[float, float] | None = None
    criterion: tasks.SuccessCriterion = tasks.TRIFINGER_SUCCESS

    def __post_init__(self):
        for name in ("initial_xy", "yaw"):
            value = getattr(self, name)
            if not (is_finite_number(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
        for name in ("target_x", "target_y", "lift", "placement"):
            value = getattr(self, name)
            if value is None:
                continue
            pair = isinstance(value, tuple) and len(value) == 2
            if not (pair and all(map(is_finite_number, value))):
                raise ValueError(f"{name} must be None or two finite numbers, got {value!r}")
            if name != "placement" and value[0] > value[1]:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {value}")
        if self.lift is not None and self.lift[0] < 0:
            raise ValueError(f"lift must not be negative, got {self.lift}")

    def region(self, plant: HandPlant) -> workspace.Reach:
        """Placement and target region on ``plant``: the given ones, the rest derived."""
        derived = _reach(plant)
        given = {
            name: getattr(self, name)
            for name in ("placement", "target_x", "target_y", "lift")
            if getattr(self, name) is not None
        }
        return dataclasses.replace(derived, **given, given=tuple(given))

    def __call__(self, plant: HandPlant, task: str, seed: int):
        """Initial and target poses ``(7,), (7,)`` of trial ``seed`` on ``plant``."""
        region = self.region(plant)
        rng = np.random.default_rng(seed)
        centre = np.asarray(region.placement)
        initial = plant.resting_pose(
            centre + rng.uniform(-self.initial_xy, self.initial_xy, 2),
            tasks.quat_from_yaw_pitch_roll(rng.uniform(-self.yaw, self.yaw)),
        )
        offset = rng.uniform(*zip(region.target_x, region.target_y, strict=True))
        target = plant.resting_pose(
            centre + offset, tasks.quat_from_yaw_pitch_roll(rng.uniform(-self.yaw, self.yaw))
        )
        target[2] += rng.uniform(*region.lift)
        return initial, target


def _reach(plant: HandPlant) -> workspace.Reach:
    """The derived :class:`~torchcontact.environments.workspace.Reach` of ``plant``'s robot
    around its object (the workspace sampled once per robot)."""
    hand = plant.hand
    points, start = _workspace(str(hand.mjcf), hand.tips, hand.initial_joints)
    extent = np.asarray(plant.object.size, dtype=float)
    return workspace.reach(points, start, extent, plant.support_height, plant.support_centre)


@functools.lru_cache(maxsize=8)
def _workspace(mjcf: str, tips: tuple[str, ...], initial: tuple[float, ...]):
    ranges = workspace.robot_defaults(mjcf).joint_ranges
    return workspace.tip_workspace(mjcf, tips, ranges, initial)


def from_mjcf(
    robot: str | Path,
    tips: tuple[str, ...] | None = None,
    *,
    name: str = "custom",
    task: PoseTask | None = None,
    cost: Cost | None = None,
    initial_joints: tuple[float, ...] | None = None,
    control_bound: float | None = None,
    robot_stiffness: float = 100.0,
    stiffness: float | None = None,
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
        cost: the MPC cost (default the paper's manipulation cost with TriFinger's contact
            and grasp weights, the control weight :data:`CONTROL_SLOPE` / ``control_bound``,
            and its contact floor, :attr:`HandModel.contact_floor`).
        initial_joints: joints at the start of every trial; None: the file's first keyframe,
            or its joints' reference positions where it has none.
        control_bound: |u| per joint and step [rad or m]; None: the narrowest range the
            position actuators command, over
            :data:`~torchcontact.environments.workspace.STEPS_ACROSS` steps.
        robot_stiffness: Kᵣ of the quasi-dynamic robot.
        stiffness: K of the paper's contact model; None: :data:`STIFFNESS`.
        frame_skip: MuJoCo substeps (2 ms) per control step.
        objects: the built-in objects of ``--object all``.
        clear_start: move the initial joints out of an object placed through a finger at
            the start of a trial (:attr:`~torchcontact.sim.hands.Hand.clear_start`).
    """
    stiffness = STIFFNESS if stiffness is None else stiffness
    if not (is_finite_number(stiffness) and stiffness > 0):
        raise ValueError(f"stiffness must be a positive finite number, got {stiffness!r}")
    path = Path(robot).resolve()
    description = Robot.from_mjcf(path, tips)
    _check_robot_only(path)
    if any(actuator.kind != "position" for actuator in description.actuators):
        raise ValueError(f"robot must drive every joint with a position actuator: {path.name}")
    derived = workspace.robot_defaults(path)
    if initial_joints is None:
        initial_joints = derived.initial_joints
    else:
        derived = dataclasses.replace(
            derived,
            initial_joints=tuple(float(x) for x in initial_joints),
            initial_source="the initial joints given",
        )
    if control_bound is None:
        control_bound = derived.control_bound
    elif not (is_finite_number(control_bound) and control_bound > 0):
        raise ValueError(f"control_bound must be a positive finite number, got {control_bound!r}")
    else:
        derived = dataclasses.replace(
            derived, control_bound=float(control_bound), control_source="given"
        )
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
        cost=_default_cost(control_bound) if cost is None else cost,
        contact_floor=cost is None,  # the default cost draws tips no lower than they can go
    )
    return RobotEnvironment(
        hand, model, task.name, task.criterion, task, TRIFINGER_PRESETS, objects, derived=derived
    )


def _check_robot_only(path: Path) -> None:
    """``ValueError`` naming ``robot`` when the file also holds a free-jointed body: the plant
    attaches its own object, so a scene's file belongs to ``describe_scene``."""
    _, model = load_model(path)
    free = sorted(model.body(b).name for b in object_bodies(model) if model.body_jntnum[b])
    if free:
        raise ValueError(
            f"robot must hold the robot only, {path.name} also has the free-jointed bodies "
            f"{free}: remove them (the plant adds the object), or read the whole scene with "
            "torchcontact.sim.user_scene.describe_scene"
        )


PAPER_STIFFNESS = 0.5
"""The paper's K of its hands (TriFinger's), which ``--stiffness paper`` plans with."""

STIFFNESS = fingertips.STIFFNESS
"""The default K [N/m]: the fingertips' K, the constant ``torchcontact learn-k`` fits to
MuJoCo's MPC rollouts of the cube under tip contact, whose object model a user's robot shares
(εMₒ/h² = 50 N/m per 10 g, h = 0.1 s, Kᵣ = 100). The paper's hand K, :data:`PAPER_STIFFNESS`,
is for objects turned on the ground: its friction rows cannot carry a pinched object's weight,
so at K ≤ 1 the example gripper's plans drop the cube they lift; on the gripper's own
transitions with the cube between its pads, 4.64 predicts the cube's next step best of the
K tried (docs/experiments.md, "2026-12-02: holding a grasp with the example gripper")."""


CONTROL_SLOPE = 0.03
"""The default cost's control weight is this over the control bound: a step at the bound
costs every robot the same per unit of bound, whatever its joints' units and ranges."""


def _default_cost(control_bound: float) -> ManipulationCost:
    """The paper's manipulation cost with TriFinger's contact and grasp weights and a control
    weight scaled to the robot's bound (TriFinger's 10 creeps on a robot whose bound is
    large, as a hinge finger's of long links)."""
    return ManipulationCost(contact=0.5, grasp=0.05, control=CONTROL_SLOPE / control_bound)


class RobotEnvironment(HandEnvironment):
    """A user's robot (:func:`from_mjcf`): a :class:`HandEnvironment` that says what it
    derived from the robot's file (:meth:`describe`)."""

    def __init__(self, *args, derived: workspace.RobotDefaults, **kwargs):
        super().__init__(*args, **kwargs)
        self.derived = derived
        self.stiffness = PAPER_STIFFNESS  # the paper's; default_stiffness is the model's K

    def describe(self, plant: HandPlant) -> list[str]:
        lines = [f"robot {self.hand.mjcf.name}: {self.derived.describe()}"]
        if isinstance(self._sample, PoseTask):
            lines.append(self._sample.region(plant).describe())
        return lines
