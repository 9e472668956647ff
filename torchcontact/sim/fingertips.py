"""The three-fingertip plant: an object on the ground pushed by three position-controlled spheres.

The simulated side of the paper's fingertip experiments. Each fingertip is a sphere (radius
1 cm) on three slide joints; a PD law with gravity compensation drives it towards ``x + u``
over ``frame_skip`` MuJoCo substeps, so one :meth:`FingertipsPlant.step` is one MPC step
(10 × 2 ms = 20 ms by default).

State layout ``q (16,)``: object position (3) [m], object quaternion (w, x, y, z) (4), then
the tips' centres x, y, z × 3 [m]; velocities ``v (15,)``: object linear (world) and angular
(body) velocity, then tip velocities.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from torchcontact.objects import ObjectOptions, resolve
from torchcontact.shapes import ObjectMesh
from torchcontact.sim.detect import OVERFLOW_POLICIES, ContactDetector
from torchcontact.sim.plant import Plant, as_pose, as_vector
from torchcontact.sim.scene import OBJECT_BODY, scene_spec

TIP_RADIUS = 0.01
"""Fingertip sphere radius [m]."""

INITIAL_TIPS = np.array([0.2, 0.0, TIP_RADIUS, 0.0, 0.2, TIP_RADIUS, -0.2, 0.0, TIP_RADIUS])
"""Default tip centres ``(9,)`` [m]: the paper's (0.2, 0), (0, 0.2), (−0.2, 0), resting on the
ground (the reference code starts them at z = 0, half sunk into the floor, which the contact
solver then pushes out)."""

TIP_BODIES = ("tip0", "tip1", "tip2")

CONTACT_CAPACITY = 12
"""The plant's :attr:`~torchcontact.sim.plant.Plant.contact_capacity`: the most slots the
paper's scenes use (8 for cube and stick, 10 for the foam brick, 12 for our bunny), so their
MPCs share one compiled graph where their other settings agree."""


class FingertipsPlant(Plant):
    """MuJoCo plant of the three-fingertip tasks, built in code with ``MjSpec``.

    Args:
        obj: a built-in object name (see :func:`~torchcontact.shapes.object_names`), a
            mesh file path, or an :class:`~torchcontact.sim.objects.ObjectMesh`.
        options: the object's size, scale, mass (default 10 g) and friction
            (:class:`~torchcontact.objects.ObjectOptions`; a mesh file keeps its own size in
            metres unless they set it); names and paths only.
        object_friction, tip_friction, ground_friction: sliding friction coefficients (the
            object's unless ``options`` sets it); MuJoCo combines a pair by the maximum.
        condim: contact dimensionality of every geom (6: sliding, torsional and rolling).
        contact_slots: slots nc of :meth:`contacts` (the paper: 8 for cube and stick, 10 for
            foam brick and bunny; 12 for our multi-part bunny; see
            ``torchcontact.environments.tasks.OBJECT_SETTINGS``).
        contact_mu: μ written into :meth:`contacts` (the model's 0.5), None for MuJoCo's.
        overflow: what :meth:`contacts` does when more object contacts exist than slots:
            ``"error"`` raises (default: nothing is dropped silently); ``"deepest"`` keeps the
            most penetrating ones.
        frame_skip: MuJoCo substeps per :meth:`step`.
        timestep: MuJoCo substep [s].
        kp, kd: PD gains of the tip servo [N/m], [N·s/m].
        collision: how the object collides (``"auto"``, ``"hull"``, ``"parts"``), see
            :func:`~torchcontact.shapes.make_object`.
    """

    def __init__(
        self,
        obj: str | Path | ObjectMesh = "cube",
        *,
        options: ObjectOptions | None = None,
        object_friction: float = 0.9,
        tip_friction: float = 0.5,
        ground_friction: float = 0.5,
        condim: int = 6,
        contact_slots: int = 10,
        contact_mu: float | None = 0.5,
        overflow: str = "error",
        frame_skip: int = 10,
        timestep: float = 0.002,
        kp: float = 100.0,
        kd: float = 2.0,
        collision: str = "auto",
    ):
        if overflow not in OVERFLOW_POLICIES:
            raise ValueError(f"overflow must be one of {OVERFLOW_POLICIES}, got {overflow!r}")
        if not isinstance(frame_skip, int) or frame_skip < 1:
            raise ValueError(f"frame_skip must be a positive integer, got {frame_skip!r}")
        for name, value in (("timestep", timestep), ("kp", kp), ("kd", kd)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for name, value in (("tip_friction", tip_friction), ("ground_friction", ground_friction)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
        super().__init__()
        self.object = resolve(obj, options, collision=collision)
        if options is not None and options.friction is not None:
            object_friction = options.friction
        self.object_friction = float(object_friction)
        self.frame_skip, self.kp, self.kd = frame_skip, float(kp), float(kd)
        spec = _scene_spec(self.object, object_friction, tip_friction, ground_friction, condim)
        spec.option.timestep = timestep
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.detector = ContactDetector(
            self.model, [OBJECT_BODY], contact_slots, mu=contact_mu, overflow=overflow
        )
        self.contact_capacity = CONTACT_CAPACITY
        self._tip_dofs = np.arange(6, 15)
        resting = np.array([0, 0, self.object.resting_height(), 1, 0, 0, 0], dtype=float)
        self.reset(resting, resting)

    # --- state ---------------------------------------------------------------------------

    def reset(self, object_pose, target_pose=None, tips=None) -> np.ndarray:
        """Place the object and tips at rest and move the goal marker; returns :meth:`state`.

        Args:
            object_pose: ``(7,)`` position [m] and quaternion (w, x, y, z), normalised here.
            target_pose: ``(7,)`` pose shown by the goal marker; None keeps the current one.
            tips: ``(9,)`` tip centres [m]; None uses :data:`INITIAL_TIPS`.
        """
        pose = as_pose("object_pose", object_pose)
        tips = INITIAL_TIPS if tips is None else as_vector("tips", tips, 9)
        target = self.target if target_pose is None else as_pose("target_pose", target_pose)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = np.concatenate([pose, tips])
        self.set_target(target)
        mujoco.mj_forward(self.model, self.data)
        return self.state()

    # --- dynamics ------------------------------------------------------------------------

    def step(self, u) -> np.ndarray:
        """Command the tips to move by ``u (9,)`` [m]; simulate ``frame_skip`` substeps.

        The set point ``x_des = x + u`` is fixed for the whole step; every substep applies
        ``τ = kp(x_des − x) − kd ẋ + g_tips`` with ``g_tips`` the tips' gravity load (their
        bias force: slide joints have no velocity terms). With the default gains a free tip
        under a constant command settles at ≈ 2u/3 per step (over-damped servo). Returns the
        new :meth:`state`.
        """
        command = as_vector("u", u, self.nu)
        desired = self.data.qpos[7:] + command
        for _ in range(self.frame_skip):
            error = desired - self.data.qpos[7:]
            velocity = self.data.qvel[self._tip_dofs]
            gravity = self.data.qfrc_bias[self._tip_dofs]
            self.data.ctrl[:] = self.kp * error - self.kd * velocity + gravity
            mujoco.mj_step(self.model, self.data)
        return self.state()


def _scene_spec(
    obj: ObjectMesh, object_friction: float, tip_friction: float, ground_friction: float, condim
) -> mujoco.MjSpec:
    """The shared scene (ground, object, goal marker, camera) plus the tips and their motors."""
    spec = scene_spec(
        f"fingertips_{obj.name}",
        obj,
        object_friction=object_friction,
        ground_friction=ground_friction,
        condim=condim,
        camera_position=(0.0, -0.42, 0.3),
    )
    colours = ([0.8, 0.15, 0.15, 1], [0.15, 0.7, 0.15, 1], [0.15, 0.3, 0.85, 1])
    for body_name, rgba in zip(TIP_BODIES, colours, strict=True):
        tip = spec.worldbody.add_body(name=body_name)
        for axis_name, axis in zip("xyz", np.eye(3), strict=True):
            joint_name = f"{body_name}_{axis_name}"
            tip.add_joint(name=joint_name, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=axis)
            spec.add_actuator(name=joint_name, target=joint_name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        tip.add_geom(
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[TIP_RADIUS, 0.0, 0.0],
            friction=[tip_friction, 0.005, 0.0001],
            condim=condim,
            rgba=rgba,
        )
    return spec
