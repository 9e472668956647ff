"""Robot-hand plants: TriFinger in-hand and Allegro on-palm manipulation, composed with MjSpec.

A scene is the shared ground, object and goal marker (:func:`~torchcontact.sim.scene.scene_spec`)
with the robot's MJCF from ``torchcontact.assets`` attached under the prefix ``robot/`` and
the world frame unchanged, so the fingertip sites of the file are the scene's (and the
:class:`~torchcontact.sim.robot.Robot` read from the same file, :meth:`Hand.robot`, agrees
with them). State ``q = (object position 3, quaternion 4, joints n)``; one :meth:`HandPlant.step`
holds the joint set point ``q_des = q + u`` for ``frame_skip`` MuJoCo substeps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import mujoco
import numpy as np
import torch

from torchcontact.assets import asset_path
from torchcontact.objects import ObjectOptions, resolve
from torchcontact.shapes import OBJECT_SIZES, ObjectMesh
from torchcontact.sim.clearance import clear_joints, robot_overlap
from torchcontact.sim.detect import OVERFLOW_POLICIES, ContactDetector
from torchcontact.sim.plant import Plant, as_pose, as_vector
from torchcontact.sim.robot import Robot
from torchcontact.sim.scene import OBJECT_BODY, scene_spec

ROBOT_PREFIX = "robot/"
"""Prefix of every name the robot's file brings into a scene."""

SERVOS = ("pd", "position")


@dataclass(frozen=True)
class ObjectOverride:
    """Where one object's experiment departs from its hand's defaults (None: the default).

    Attributes:
        mass: object mass [kg].
        size: bounding box (x, y, z) [m] of a built-in object.
        object_friction, ground_friction: sliding friction of the object and of the ground.
    """

    mass: float | None = None
    size: tuple[float, float, float] | None = None
    object_friction: float | None = None
    ground_friction: float | None = None


@dataclass(frozen=True)
class Hand:
    """A robot hand and the plant settings of its experiments (the paper's).

    The robot itself (its joints, fingertip sites and kinematics) is read from the MJCF
    ``asset``: :meth:`robot`, :attr:`n_joints`, :attr:`tips`.

    Attributes:
        name: ``"trifinger"`` or ``"allegro"``.
        asset: its MJCF: a file name in ``torchcontact.assets``, or an absolute path.
        initial_joints: joint configuration at the start of every trial [rad].
        frame_skip: MuJoCo substeps per step.
        servo: ``"pd"``: the file's motors apply ``τ = kp(q_des − q) − kd q̇ + bias`` every
            substep (gravity and Coriolis compensated); ``"position"``: the file's position
            actuators get ``ctrl = q_des`` (their gain and the joints' damping act).
        kp, kd: PD gains [N·m/rad], [N·m·s/rad] (``"pd"`` only).
        object_friction, ground_friction: sliding friction of object and ground (defaults;
            ``object_overrides`` may change them per object).
        support_site: the site an object rests on (the palm centre), None for the ground.
        ground_height: z of the ground plane [m].
        camera_position, camera_target: of the ``"overview"`` camera [m].
        elliptic, impratio: friction cone of the plant (MuJoCo's default pyramidal, 1).
        object_mass: default object mass [kg].
        object_overrides: object name ↦ :class:`ObjectOverride`, where the paper's scene of
            that object differs from the defaults.
        contact_margin: detection distance [m] of the MPC's contacts (ours; the paper's is 0):
            object pairs this close enter the contact rows with their gap φ > 0, so the model
            sees a touch coming instead of a fingertip passing through the object.
        tip_sites: fingertip site names in the file; None takes the file's sites named
            ``*tip`` (see :meth:`~torchcontact.sim.robot.Robot.from_mjcf`).
        clear_start: whether :meth:`HandPlant.reset` moves the initial joints out of an object
            placed through a finger (:func:`~torchcontact.sim.clearance.clear_joints`);
            False keeps them, and the servos then press those fingers onto the object.
        contact_capacity: the contact slots the MPC pads every object's contacts to, so that
            one compiled graph serves all of this hand's objects
            (:attr:`~torchcontact.sim.plant.Plant.contact_capacity`); None: each object's own
            slots, rounded up.
    """

    name: str
    asset: str
    initial_joints: tuple[float, ...]
    frame_skip: int
    servo: str
    object_friction: float
    ground_friction: float
    camera_position: tuple[float, float, float]
    camera_target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    kp: float = 0.0
    kd: float = 0.0
    support_site: str | None = None
    ground_height: float = 0.0
    elliptic: bool = False
    impratio: float = 1.0
    object_mass: float = 0.01
    object_overrides: dict[str, ObjectOverride] = field(default_factory=dict)
    contact_margin: float = 0.0
    tip_sites: tuple[str, ...] | None = None
    clear_start: bool = True
    contact_capacity: int | None = None

    def override(self, obj) -> ObjectOverride:
        """The overrides of built-in object ``obj`` (none for other names and meshes)."""
        overrides = self.object_overrides.get(obj) if isinstance(obj, str) else None
        return overrides or ObjectOverride()

    def object_mesh(
        self, obj, options: ObjectOptions | None = None, collision: str = "auto"
    ) -> ObjectMesh:
        """``obj`` (a built-in, generated or mesh-file object, or an :class:`ObjectMesh`) as
        this hand's scene has it: its size override and mass (the override's or the hand's
        default) unless ``options`` set them; ``collision`` as
        :func:`~torchcontact.objects.resolve`."""
        override = self.override(obj)
        mass = _chosen(override.mass, self.object_mass)
        return resolve(obj, options, mass, override.size, collision)

    def robot(
        self, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> Robot:
        """The hand as a :class:`~torchcontact.sim.robot.Robot` read from its MJCF: fingertips
        ``(..., n_tips, 3)`` [m] of ``joints (..., n_joints)`` [rad]."""
        return Robot.from_mjcf(self.mjcf, self.tip_sites, dtype=dtype, device=device)

    @cached_property
    def _description(self) -> tuple[int, tuple[str, ...]]:
        """The file's joint count and fingertip sites, read once."""
        robot = self.robot()
        return robot.n_joints, robot.tips

    @property
    def n_joints(self) -> int:
        """The robot's joint count, from its MJCF."""
        return self._description[0]

    @property
    def tips(self) -> tuple[str, ...]:
        """Fingertip site names in the MJCF (``tip_sites``, or the file's ``*tip`` sites)."""
        return self._description[1]

    @property
    def mjcf(self) -> Path:
        """Path of the robot's model file: ``asset`` itself where it is an absolute path (a
        user's robot), else the bundled asset of that name."""
        path = Path(self.asset)
        return path if path.is_absolute() else asset_path(self.asset)


def _chosen(value, default):
    """``value`` where an override sets it (0 included), else ``default``."""
    return default if value is None else value


def _scaled(obj: str, factor: float) -> tuple[float, float, float]:
    """The listed size of built-in ``obj`` times ``factor`` [m]."""
    x, y, z = OBJECT_SIZES[obj]
    return (x * factor, y * factor, z * factor)


TRIFINGER = Hand(
    name="trifinger",
    asset="trifinger.xml",
    initial_joints=(0.0, -0.7, -1.1) * 3,
    frame_skip=20,
    servo="pd",
    kp=10.0,
    kd=0.05,
    object_friction=0.5,
    # the reference scenes: a 0.9 table under the cube, 0.5 under every mesh object
    ground_friction=0.5,
    camera_position=(0.0, -0.45, 0.45),
    object_overrides={"cube": ObjectOverride(ground_friction=0.9)},
    # tips hovering just off an object left the MPC without rows to push with; 5 mm chosen by
    # measurement (docs/experiments.md, "TriFinger and Allegro MPC")
    contact_margin=0.005,
    tip_sites=("tip0", "tip1", "tip2"),  # the file's sites are tip0..tip2, not named *tip
    # the built-ins need 10 slots (the ground's 4, 2 per tip), generated objects (seeds 0-99,
    # 1000-1099) 10-12: one capacity holds them all (docs/compile_sharing_notes.md)
    contact_capacity=12,
)

ALLEGRO = Hand(
    name="allegro",
    asset="allegro_right_hand.xml",
    initial_joints=(
        0.125,
        1.13,
        1.45,
        1.24,
        -0.02,
        0.445,
        1.17,
        1.5,
        -0.459,
        1.54,
        1.11,
        1.23,
        0.638,
        1.85,
        1.5,
        1.26,
    ),  # fmt: skip
    frame_skip=50,
    servo="position",
    object_friction=0.5,
    ground_friction=0.5,
    support_site="palm_center",
    ground_height=-0.2,
    camera_position=(0.0, -0.3, 0.3),
    elliptic=True,
    impratio=10.0,
    # the paper's start curls the fingers onto whatever lies on the palm, so their servos press
    # it there; moved clear, generated objects fell more (53 against 40 of 200 reported
    # trials) and the stick turned less (8 against 15 of 20) (docs/experiments.md, scenes 10)
    clear_start=False,
    # objects resting on the palm touch it and the finger links curled around them: the
    # built-ins need 13-20 slots, generated objects (seeds 0-99, 1000-1099) 12-34; one multiple
    # of 4 holds them all (docs/compile_sharing_notes.md)
    contact_capacity=36,
    # contact_margin stays 0: under the paper's soft K = 0.5 a row's force falls off over
    # 1/(γK) = 2 cm, so hovering links would push the modelled object (docs/experiments.md,
    # "TriFinger and Allegro MPC")
    # the reference scenes: a heavier cube and stick, binoculars with friction 0.9, and three
    # meshes scaled smaller than on the TriFinger (whose scale the listed sizes are)
    object_overrides={
        "cube": ObjectOverride(mass=0.1, size=(0.05, 0.05, 0.05)),
        "stick": ObjectOverride(mass=0.1),
        "binoculars": ObjectOverride(object_friction=0.9, size=_scaled("binoculars", 0.65 / 0.75)),
        "airplane": ObjectOverride(size=_scaled("airplane", 0.9)),
        "bunny": ObjectOverride(size=_scaled("bunny", 0.9)),
    },
)

HANDS = {hand.name: hand for hand in (TRIFINGER, ALLEGRO)}


MODEL_FRICTION = 0.5
"""μ the paper's hand models use in every contact row (HandPlant's default ``contact_mu``)."""

CONTACTS_PER_TIP = 2
"""Slots kept per fingertip beyond the resting contacts (a tip on a seam touches two parts)."""

CONTACTS_PER_PAIR = 4
"""Contacts kept per pair of bodies, spanning the patch (see :class:`ContactDetector`'s
``per_pair``): a decomposed cup on the ground keeps 4 of its ~36 contacts."""


def support_footprint(
    model: mujoco.MjModel, data: mujoco.MjData, body: int
) -> tuple[float, float, float, float]:
    """``(x_min, y_min, x_max, y_max)`` [m]: the world x, y bounds of ``body``'s colliding
    geoms (their bounding boxes' corners at ``data``'s kinematics), the region that body can
    hold an object over."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    corners = []
    for geom in np.flatnonzero(model.geom_bodyid == body):
        if not (model.geom_contype[geom] or model.geom_conaffinity[geom]):
            continue  # visual only
        centre, half = model.geom_aabb[geom, :3], model.geom_aabb[geom, 3:]
        rotation = data.geom_xmat[geom].reshape(3, 3)
        corners.append(data.geom_xpos[geom] + (centre + signs * half) @ rotation.T)
    if not corners:
        raise ValueError(f"body {model.body(body).name!r} has no colliding geom to support with")
    xy = np.concatenate(corners)[:, :2]
    return (*map(float, xy.min(0)), *map(float, xy.max(0)))


_ROUND_GEOMS = (int(mujoco.mjtGeom.mjGEOM_SPHERE), int(mujoco.mjtGeom.mjGEOM_CAPSULE))


def tip_clearance(model: mujoco.MjModel, data: mujoco.MjData, sites) -> float:
    """[m] How close the fingertip ``sites`` can come to a surface: the least, over the sites,
    of how deep each lies inside the colliding spheres and capsules of its body (0 where none
    holds it), at ``data``'s kinematics. A site at the centre of a 1 cm tip sphere stays 1 cm
    above any surface the sphere rests on."""
    depths = []
    for site in sites:
        body, point = model.site_bodyid[site], data.site_xpos[site]
        depth = 0.0
        for geom in np.flatnonzero(model.geom_bodyid == body):
            kind = int(model.geom_type[geom])
            collides = model.geom_contype[geom] or model.geom_conaffinity[geom]
            if not collides or kind not in _ROUND_GEOMS:
                continue
            offset = data.geom_xmat[geom].reshape(3, 3).T @ (point - data.geom_xpos[geom])
            half = model.geom_size[geom, 1] if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            offset[2] -= np.clip(offset[2], -half, half)  # to the nearest point of the axis
            depth = max(depth, float(model.geom_size[geom, 0] - np.linalg.norm(offset)))
        depths.append(depth)
    return min(depths, default=0.0)


def scene_contact_slots(model: mujoco.MjModel, resting_qpos: np.ndarray, n_tips: int) -> int:
    """Slots a scene needs: the object's contacts when it rests at ``resting_qpos (nq,)``,
    within 1 mm and at most :data:`CONTACTS_PER_PAIR` per body pair, at least 4, plus
    :data:`CONTACTS_PER_TIP` per fingertip, so resting contacts never crowd out the tips."""
    # 1 mm of margin also counts parts that touch once the object settles into the support
    probe = ContactDetector(
        model, [OBJECT_BODY], 0, margin=1e-3, overflow="deepest", per_pair=CONTACTS_PER_PAIR
    )
    probe(resting_qpos)
    return max(probe.found, 4) + CONTACTS_PER_TIP * n_tips


class HandPlant(Plant):
    """MuJoCo plant of a robot hand manipulating one object.

    Args:
        hand: a :class:`Hand` or its name (``"trifinger"``, ``"allegro"``).
        obj: a built-in object name, a mesh path, or an :class:`ObjectMesh`.
        options: the object's size, scale, mass and friction
            (:class:`~torchcontact.objects.ObjectOptions`); what it leaves None is the hand's
            default and per-object override (a mesh file keeps its own size in metres).
        condim: contact dimensionality of the scene's own geoms (ground, object).
        contact_slots: slots nc of :meth:`contacts`; None sizes them from the scene
            (:func:`scene_contact_slots`).
        contact_mu: μ written into :meth:`contacts` (the model's 0.5), None for MuJoCo's.
        contact_margin: detection distance [m] of :meth:`contacts`; None takes the hand's
            (:attr:`Hand.contact_margin`). The simulation itself keeps MuJoCo's 0.
        overflow: ``"error"`` or ``"deepest"`` when more object contacts exist than slots.
        timestep: MuJoCo substep [s].
        collision: how the object collides (``"auto"``, ``"hull"``, ``"parts"``), see
            :func:`~torchcontact.shapes.make_object` and
            :func:`~torchcontact.objects.resolve`.

    What holds the object: ``support_centre (2,)`` and ``support_height`` [m], the support
    site's (or the ground's), and ``support_footprint``, the supporting body's x, y bounds
    (:func:`support_footprint`), None on the ground; ``tip_clearance`` [m], how far above a
    surface the fingertip sites stay when the tips rest on it (:func:`tip_clearance`).
    """

    def __init__(
        self,
        hand: Hand | str,
        obj: str | Path | ObjectMesh = "cube",
        *,
        options: ObjectOptions | None = None,
        collision: str = "auto",
        condim: int = 6,
        contact_slots: int | None = None,
        contact_mu: float | None = MODEL_FRICTION,
        contact_margin: float | None = None,
        overflow: str = "error",
        timestep: float = 0.002,
    ):
        super().__init__()
        if isinstance(hand, str):
            if hand not in HANDS:
                raise ValueError(f"hand must be one of {tuple(HANDS)}, got {hand!r}")
            hand = HANDS[hand]
        if hand.servo not in SERVOS:
            raise ValueError(f"hand.servo must be one of {SERVOS}, got {hand.servo!r}")
        if len(hand.initial_joints) != hand.n_joints:
            raise ValueError(
                f"hand.initial_joints must have {hand.n_joints} values (the joints of "
                f"{hand.asset}), got {len(hand.initial_joints)}"
            )
        if overflow not in OVERFLOW_POLICIES:
            raise ValueError(f"overflow must be one of {OVERFLOW_POLICIES}, got {overflow!r}")
        if not (math.isfinite(timestep) and timestep > 0):
            raise ValueError(f"timestep must be a positive finite number, got {timestep!r}")
        margin = _chosen(contact_margin, hand.contact_margin)
        if not (math.isfinite(margin) and margin >= 0):
            raise ValueError(f"contact_margin must be a non-negative finite number, got {margin!r}")
        self.hand = hand
        override = hand.override(obj)
        self.options = ObjectOptions() if options is None else options
        self.object = hand.object_mesh(obj, options, collision)
        friction = self.options.friction
        self.object_friction = _chosen(
            friction, _chosen(override.object_friction, hand.object_friction)
        )
        self.ground_friction = _chosen(override.ground_friction, hand.ground_friction)
        spec = self._scene_spec(condim)
        spec.option.timestep = timestep
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        if self.model.nu != hand.n_joints:
            raise ValueError(f"{hand.asset} must have one actuator per joint ({hand.n_joints})")
        self.tip_sites = np.array(
            [self.model.site(ROBOT_PREFIX + name).id for name in hand.tips], dtype=int
        )
        self._joint_dofs = np.arange(6, self.model.nv)
        self.initial_joints = np.array(hand.initial_joints, dtype=float)
        mujoco.mj_kinematics(self.model, self.data)
        self.support_footprint = None  # the ground: no edge to fall over
        if hand.support_site is None:
            support = np.array([0.0, 0.0, hand.ground_height])
        else:
            site = self.model.site(ROBOT_PREFIX + hand.support_site).id
            support = self.data.site_xpos[site].copy()
            body = self.model.site_bodyid[site]
            self.support_footprint = support_footprint(self.model, self.data, body)
        self.support_centre, self.support_height = support[:2], float(support[2])
        self.tip_clearance = tip_clearance(self.model, self.data, self.tip_sites)
        resting = self.resting_pose(self.support_centre, [1.0, 0.0, 0.0, 0.0])
        if contact_slots is None:
            qpos = np.concatenate([resting, self.initial_joints])
            contact_slots = scene_contact_slots(self.model, qpos, len(hand.tips))
        self.detector = ContactDetector(
            self.model,
            [OBJECT_BODY],
            contact_slots,
            mu=contact_mu,
            margin=margin or None,  # None: the model's own margins (0)
            overflow=overflow,
            per_pair=CONTACTS_PER_PAIR,
        )
        self.contact_capacity = hand.contact_capacity
        self.reset(resting, resting)

    def _scene_spec(self, condim: int) -> mujoco.MjSpec:
        hand = self.hand
        spec = scene_spec(
            f"{hand.name}_{self.object.name}",
            self.object,
            object_friction=self.object_friction,
            ground_friction=self.ground_friction,
            condim=condim,
            camera_position=hand.camera_position,
            camera_target=hand.camera_target,
            ground_height=hand.ground_height,
        )
        if hand.elliptic:
            spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        spec.option.impratio = hand.impratio
        robot = mujoco.MjSpec.from_file(str(hand.mjcf))
        spec.attach(robot, prefix=ROBOT_PREFIX, frame=spec.worldbody.add_frame())
        return spec

    # --- state ---------------------------------------------------------------------------

    def resting_pose(self, xy, quat) -> np.ndarray:
        """``(7,)`` pose at ``xy (2,)`` [m] turned by ``quat (4,)`` whose lowest point is at the
        support's height (the palm centre, or the ground). A large object there may overlap
        the fingers at their initial joints: :meth:`reset` moves them out where
        :attr:`Hand.clear_start` (a base link that no joint moves far may stay inside)."""
        xy = as_vector("xy", xy, 2)
        quat = as_pose("quat", [0.0, 0.0, 0.0, *as_vector("quat", quat, 4)])[3:]
        z = self.resting_height(quat)
        return np.concatenate([xy, [z], quat])

    def reset(self, object_pose, target_pose=None, joints=None) -> np.ndarray:
        """Place the object and the robot at rest and move the goal marker; returns q.

        Args:
            object_pose: ``(7,)`` position [m] and quaternion (w, x, y, z), normalised here.
            target_pose: ``(7,)`` pose shown by the goal marker; None keeps the current one.
            joints: ``(n_joints,)`` [rad], kept as given; None: the hand's initial
                configuration, moved out of the object wherever a finger would start inside
                it if :attr:`Hand.clear_start`
                (:func:`~torchcontact.sim.clearance.clear_joints`).

        The robot's deepest overlap with the object left at the start is
        :attr:`start_penetration` [m].
        """
        pose = as_pose("object_pose", object_pose)
        clear = joints is None and self.hand.clear_start
        n = self.hand.n_joints
        joints = self.initial_joints if joints is None else as_vector("joints", joints, n)
        target = self.target if target_pose is None else as_pose("target_pose", target_pose)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = np.concatenate([pose, joints])
        measure = clear_joints if clear else robot_overlap
        object_body = self.model.body(OBJECT_BODY).id
        self.start_penetration = measure(self.model, self.data, object_body, self._joint_dofs)
        if self.hand.servo == "position":
            self.data.ctrl[:] = self.data.qpos[7:]
        self.set_target(target)
        mujoco.mj_forward(self.model, self.data)
        return self.state()

    def fingertips(self) -> np.ndarray:
        """``(n_tips, 3)`` world positions of the fingertip sites [m]."""
        return self.data.site_xpos[self.tip_sites].copy()

    # --- dynamics ------------------------------------------------------------------------

    def step(self, u) -> np.ndarray:
        """Command the joints to move by ``u (n_joints,)`` [rad]; simulate ``frame_skip``
        substeps with the set point ``q_des = q + u`` held; returns the new state."""
        command = as_vector("u", u, self.hand.n_joints)
        desired = self.data.qpos[7:] + command
        if self.hand.servo == "position":
            self.data.ctrl[:] = desired
            mujoco.mj_step(self.model, self.data, nstep=self.hand.frame_skip)
            return self.state()
        for _ in range(self.hand.frame_skip):
            error = desired - self.data.qpos[7:]
            velocity = self.data.qvel[self._joint_dofs]
            bias = self.data.qfrc_bias[self._joint_dofs]
            self.data.ctrl[:] = self.hand.kp * error - self.hand.kd * velocity + bias
            mujoco.mj_step(self.model, self.data)
        return self.state()
