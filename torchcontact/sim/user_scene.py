"""Your own scene, in a training loop, with one call: the model's pieces read from one MJCF.

A user's MJCF holds a robot (hinge and slide joints, fingertip sites) and one free-jointed
object. :func:`describe_scene` reads from it everything the contact step needs: the joint
layout of ``q``, the quasi-dynamic system whose object metric comes from MuJoCo's mass and
inertia, the contact detector of the object, the robot's fingertip kinematics and the map from
a model control to MuJoCo's ``ctrl``::

    scene = describe_scene("pusher.xml", "box")
    model = torchcontact.ComplementarityFree(stiffness=1.0)
    contacts = scene.detector(q)                 # q: (..., nq)
    Q, b = scene.system(u)                       # u: (..., n_joints)
    q_next = torchcontact.integrate(q, model(Q, b, contacts, scene.h), scene.h, scene.layout)
    data.ctrl[:] = scene.control(data.qpos, u)   # the same u on the MuJoCo plant
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import mujoco
import numpy as np
import torch

from torchcontact.integrate import JointLayout
from torchcontact.sim.detect import OVERFLOW_POLICIES, ContactDetector
from torchcontact.sim.dynamics import joint_layout
from torchcontact.sim.kinematics import FREE, load_model
from torchcontact.sim.robot import Robot
from torchcontact.systems import QuasiDynamic

DEFAULT_EPSILON = 50.0
"""ε of the object metric εMₒ/h² (see :func:`describe_scene`)."""


@dataclass(frozen=True)
class UserScene:
    """The contact model's pieces for one MJCF scene (built by :func:`describe_scene`).

    Attributes:
        mjcf: the scene's file.
        model: its compiled ``MjModel``.
        object_body: name of the free-jointed object.
        object_mass: its mass m [kg], from MuJoCo.
        object_inertia: ``(3,)`` diagonal of its inertia in its body frame [kg·m²].
        h: the model's time step [s].
        epsilon: ε of the object metric εMₒ/h².
        layout: joints of ``q (nq,)``: the object's free joint, then the robot's joints.
        system: :class:`~torchcontact.systems.QuasiDynamic` with ``Q = (εMₒ/h², Kᵣ)`` and
            ``b = (m·g, 0, Kᵣu)``.
        detector: contacts of the object with the robot and the rest of the scene.
        robot: the robot's fingertips, ``robot(q[..., robot_qpos])`` ``(..., n_tips, 3)`` [m].
        robot_qpos: addresses of the robot's joints in ``q`` (MuJoCo's qpos).
    """

    mjcf: Path
    model: mujoco.MjModel
    object_body: str
    object_mass: float
    object_inertia: tuple[float, float, float]
    h: float
    epsilon: float
    layout: JointLayout
    system: QuasiDynamic
    detector: ContactDetector
    robot: Robot
    robot_qpos: tuple[int, ...]

    def control(self, q, u):
        """MuJoCo's ``ctrl (..., nu)`` that servos the robot by the model control ``u``.

        Args:
            q: ``(..., nq)`` scene state (MuJoCo's qpos) [m, quaternion, rad or m].
            u: ``(..., n_joints)`` joint displacement per step [rad or m].

        Each position actuator of joint k gets ``ctrl = gear·(q_k + u_k)``, its set point
        ``q_k + u_k``. NumPy in, NumPy out; tensors in, a tensor out. Raises ``ValueError``
        unless every robot joint has exactly one position actuator and nothing else acts.
        """
        joints, gear = self._servos
        qpos = [self.robot_qpos[j] for j in joints]
        nq, n = self.model.nq, self.robot.n_joints
        if isinstance(q, torch.Tensor) or isinstance(u, torch.Tensor):
            q = torch.as_tensor(q)
            u = torch.as_tensor(u, dtype=q.dtype, device=q.device)
            gear = torch.as_tensor(gear, dtype=q.dtype, device=q.device)
        else:
            q, u = np.asarray(q, dtype=np.float64), np.asarray(u, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != nq:
            raise ValueError(f"q must have shape (..., {nq}), got {tuple(q.shape)}")
        if u.ndim == 0 or u.shape[-1] != n:
            raise ValueError(f"u must have shape (..., {n}), got {tuple(u.shape)}")
        return (q[..., qpos] + u[..., joints]) * gear

    @cached_property
    def _servos(self) -> tuple[list[int], np.ndarray]:
        """Per actuator, the robot joint it servos and its gear; ``ValueError`` for others."""
        names = self.robot.joint_names
        actuators = self.robot.actuators
        other = [a.name or f"#{i}" for i, a in enumerate(actuators) if a.kind != "position"]
        if other:
            kinds = sorted({a.kind for a in actuators if a.kind != "position"})
            raise ValueError(
                f"control maps u to position actuators only; {self.mjcf.name} has {kinds} "
                f"actuators {other}: send their ctrl yourself"
            )
        joints = [names.index(a.joint) if a.joint in names else -1 for a in actuators]
        if sorted(joints) != list(range(len(names))):
            driven = [a.joint for a in actuators]
            raise ValueError(
                f"control needs one position actuator per robot joint {list(names)}, "
                f"{self.mjcf.name}'s drive {driven}"
            )
        return joints, np.array([a.gear for a in actuators])


def describe_scene(
    mjcf: str | Path,
    object_body: str,
    *,
    tips: Sequence[str] | None = None,
    h: float = 0.1,
    epsilon: float = DEFAULT_EPSILON,
    robot_stiffness: float = 10.0,
    contact_slots: int = 8,
    mu: float | None = 0.5,
    margin: float | None = None,
    overflow: str = "error",
    per_pair: int | None = 4,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
) -> UserScene:
    """Read the contact model's pieces from an MJCF of a robot and one free-jointed object.

    Args:
        mjcf: the scene file. Its first joint must be the object's free joint (MuJoCo numbers
            joints in the order their bodies appear: put the object's ``<body>`` before the
            robot's); every other joint is the robot's, a hinge or a slide.
        object_body: name of the object's body (one rigid body: child bodies carry no mass).
        tips: the robot's fingertip sites; None takes its sites named ``*tip``.
        h: the model's time step [s].
        epsilon: ε of the object metric ``εMₒ/h² = diag(ε·m/h² ×3, ε·I/h² ×3)``, with m and
            the body-frame diagonal inertia I from MuJoCo. The quasi-dynamic object has no
            velocity of its own; ε scales how heavy it is against contact: larger ε, a
            heavier object that moves less per step under the same push (and sinks less per
            step, ``g·h²/ε``, when nothing holds it), so the robot must press deeper to move
            it; smaller ε, a light object that jumps at every touch. The paper's scenes use
            ``εMₒ/h² = 50`` on translation for a 10 g object at h = 0.1 s, i.e. ε = 50 (the
            default), and 0.05–0.1 on rotation for its 6 cm cube (I = 6e−6 kg·m²), i.e.
            ε ≈ 80–170.
        robot_stiffness: Kᵣ, the robot's stiffness per joint [N/m or N·m/rad]: free of
            contact the robot moves by exactly u; against contact it gives way by force/Kᵣ.
            The paper's: 100 (point fingertips, m), 10 (TriFinger, rad), 1 (Allegro, rad).
        contact_slots, mu, margin, overflow, per_pair: of the
            :class:`~torchcontact.sim.detect.ContactDetector` (slots nc, μ of every row, None
            for MuJoCo's; detection distance [m]; ``"error"`` or ``"deepest"`` beyond nc;
            contacts kept per body pair).
        dtype, device: of the system, the robot and the contacts.

    Raises ``ValueError`` naming the argument for a missing file or body, a joint order other
    than (object, robot), or joints the model cannot take (ball joints, a second object).
    """
    for name, value in (("h", h), ("epsilon", epsilon), ("robot_stiffness", robot_stiffness)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    if overflow not in OVERFLOW_POLICIES:
        raise ValueError(f"overflow must be one of {OVERFLOW_POLICIES}, got {overflow!r}")
    path, model = load_model(mjcf)
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, object_body)
    if body < 0:
        raise ValueError(f"object_body must name a body of {path.name}, got {object_body!r}")
    _check_joint_order(model, body, path.name, object_body)
    robot = Robot.from_mjcf(path, tips, dtype=dtype, device=device)
    if robot.n_joints != model.njnt - 1:
        raise ValueError(
            f"mjcf: every joint after the object's must be the robot's; {path.name} has "
            f"{model.njnt - 1} such joints, the robot {robot.n_joints}"
        )
    mass, inertia = _rigid_body(model, body, object_body)
    gravity = model.opt.gravity
    metric = torch.tensor([mass] * 3 + list(inertia), dtype=dtype, device=device)
    system = QuasiDynamic(
        object_metric=epsilon * metric / (h * h),
        robot_stiffness=torch.full((robot.n_joints,), float(robot_stiffness), dtype=dtype),
        object_force=torch.tensor([*(mass * gravity), 0.0, 0.0, 0.0], dtype=dtype),
    ).to(device)
    detector = ContactDetector(
        model,
        [body],
        contact_slots,
        mu=mu,
        margin=margin,
        overflow=overflow,
        per_pair=per_pair,
        dtype=dtype,
        device=device,
    )
    return UserScene(
        mjcf=path,
        model=model,
        object_body=object_body,
        object_mass=mass,
        object_inertia=inertia,
        h=float(h),
        epsilon=float(epsilon),
        layout=joint_layout(model),
        system=system,
        detector=detector,
        robot=robot,
        robot_qpos=tuple(int(model.jnt_qposadr[j]) for j in range(1, model.njnt)),
    )


def _check_joint_order(model: mujoco.MjModel, body: int, source: str, name: str) -> None:
    """``ValueError`` unless joint 0 is ``body``'s free joint, its only one, and no other
    joint is free."""
    own = range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body])
    if len(own) != 1 or model.jnt_type[own[0]] != FREE:
        raise ValueError(f"object_body {name!r} must have one free joint (and no other)")
    if own[0] != 0:
        raise ValueError(
            f"mjcf: the object's free joint must be the first joint of {source}, it is joint "
            f"{own[0]}; MuJoCo numbers joints in the order their bodies appear, so put the "
            f"{name!r} body before the robot's in <worldbody> (q = (object pose 7, robot joints))"
        )
    others = [model.joint(j).name or f"#{j}" for j in range(1, model.njnt)]
    free = [
        n for n, j in zip(others, range(1, model.njnt), strict=True) if model.jnt_type[j] == FREE
    ]
    if free:
        raise ValueError(f"mjcf: {source} must hold one free-jointed object, also has {free}")


def _rigid_body(model: mujoco.MjModel, body: int, name: str) -> tuple[float, tuple]:
    """The mass [kg] and body-frame diagonal inertia ``(3,)`` [kg·m²] of one rigid body."""
    mass = float(model.body_mass[body])
    if mass <= 0:
        raise ValueError(f"object_body {name!r} must have a positive mass, got {mass}")
    if not math.isclose(float(model.body_subtreemass[body]), mass):
        raise ValueError(f"object_body {name!r} must be one rigid body: its child bodies have mass")
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.body_iquat[body])
    rotation = rotation.reshape(3, 3)
    # the principal inertia turned into the body frame, where the free joint's ω is measured
    inertia = np.diag(rotation @ np.diag(model.body_inertia[body]) @ rotation.T)
    return mass, tuple(float(i) for i in inertia)
