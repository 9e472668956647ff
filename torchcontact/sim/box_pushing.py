"""The box-pushing scene (Jin 2024): a bar on a slide joint and a row of N cubes on the ground.

:class:`BoxPushingConfig` holds the constants, :func:`scene_xml` writes the MJCF,
:func:`build_scene` compiles it with its contact detector and the paper's quasi-dynamic
system, and :class:`BoxPushingPlant` simulates it in MuJoCo with the bar driven kinematically.
The CF-vs-QP timing experiment (``studies/box_pushing.py``) and data collection
(:mod:`torchcontact.learn`) use it.

Scene choices (:class:`BoxPushingConfig`): 5 cm cubes of 1 g, 1 cm apart, μ = 0.5, detection
margin 5 mm, the exact ``max(·, 0)`` in the CF model. K = 1 N/m acts per row, so the cube mass
decides how the contacts behave: the explicit CF update is stable only when
``K·λmax(J̃Q⁻¹J̃ᵀ) < 2`` with ``Q = εM/h²``, which a resting 1 g cube's stiffest (tilting) mode
meets (0.9–1.2) and much lighter cubes break (they rock with period 2). Heavier cubes sink:
0.1 kg would rest 6 cm deep, and 20 of them would outweigh the bar's ``Kᵣ|u| = 0.5 N`` in
friction. The softplus of the paper's MPC (γ = 100) gives every row a floor of
``log 2/γ ≈ 7 mN``, enough to lift 1 g cubes off the ground, hence the exact max. The price of
one K for every row: a resting cube sits 0.5 mm deep (``φ = gh²/ε − mg/(16K)``), and the bar's
push crosses each face pair through only 16 rows, so the bar sinks 4 mm into a single cube and
up to 2.5 cm into a row of 10–20, where the QP does not penetrate.

The plant (:class:`BoxPushingPlant`) runs the same MJCF at a MuJoCo time step of
``h/substeps``, every geom's sliding friction set to μ. One :meth:`BoxPushingPlant.step` is one
model step h: before every substep the bar's x is set on the straight line from its start to
``x + u`` and its velocity to ``u/h``, so the cubes meet a bar that moves exactly as commanded
(the quasi-dynamic model's robot, ``Kᵣ → ∞``); the cubes answer through MuJoCo's contact
dynamics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch

from torchcontact.contacts import Contacts
from torchcontact.integrate import JointLayout
from torchcontact.sim.detect import ContactDetector
from torchcontact.sim.dynamics import joint_layout
from torchcontact.systems import QuasiDynamic

DTYPE = torch.float64
"""dtype of the compiled scene's tensors (Q, b, q0, the detector's contacts)."""


@dataclass(frozen=True)
class BoxPushingConfig:
    """The scene's and the experiment's constants; the model ones (h, ε, Kᵣ, K, u) are the paper's.

    Attributes:
        cubes: number of cubes N in the row.
        steps: time steps of each rollout.
        h: time step [s].
        epsilon: ε of the object metric ``εMₒ/h²``.
        robot_stiffness: Kᵣ of the bar [N/m].
        contact_stiffness: K of every dual-cone row [N/m].
        push: bar displacement command u per step [m] (negative: towards −x).
        edge: cube edge length [m].
        mass: cube mass [kg] (the module docstring says why 1 g).
        gap: distance between neighbouring cubes, and between the bar and the first cube [m].
        mu: friction coefficient of every contact.
        margin: detection margin of the cube geoms [m]; MuJoCo adds the margins of a pair, so
            contacts are seen from 5 mm (ground, bar) and 10 mm (cube–cube), more than the
            1 mm a step moves.
        gamma: softplus sharpness of the CF model; None for the exact ``max(·, 0)``.
        facets: friction-cone facets per contact.
        qp_settings: OSQP settings of the QP baseline, over the library's
            (:data:`torchcontact.qp.OSQP_SETTINGS`): tolerances 1e-6, as much tighter ones
            end in "solved inaccurate" at 10 cubes.
        warmup: first steps of each rollout left out of the timing medians.
    """

    cubes: int = 10
    steps: int = 1000
    h: float = 0.02
    epsilon: float = 40.0
    robot_stiffness: float = 500.0
    contact_stiffness: float = 1.0
    push: float = -0.001
    edge: float = 0.05
    mass: float = 1e-3
    gap: float = 0.01
    mu: float = 0.5
    margin: float = 0.005
    gamma: float | None = None
    facets: int = 4
    qp_settings: dict = field(default_factory=lambda: {"eps_abs": 1e-6, "eps_rel": 1e-6})
    warmup: int = 5

    def __post_init__(self) -> None:
        numbers = ("h", "epsilon", "robot_stiffness", "contact_stiffness", "push", "edge")
        for name in (*numbers, "mass", "gap", "mu", "margin"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise TypeError(f"{name} must be a number, got {value!r}")
        if self.gamma is not None and not (
            isinstance(self.gamma, (int, float)) and math.isfinite(self.gamma) and self.gamma > 0
        ):
            raise ValueError(f"gamma must be a positive finite number or None, got {self.gamma!r}")
        for name in ("facets", "cubes", "steps"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.warmup, int) or self.warmup < 0:
            raise ValueError(f"warmup must be a non-negative integer, got {self.warmup!r}")
        for name in ("h", "epsilon", "robot_stiffness", "contact_stiffness", "edge", "mass"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for name in ("gap", "mu", "margin"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
        if not math.isfinite(self.push):
            raise ValueError(f"push must be finite, got {self.push!r}")

    @property
    def slots(self) -> int:
        """Contact slots, 12 per cube: 4 ground corners and up to 8 points of the face pair
        towards +x (the bar or the previous cube).

        MuJoCo gives a face-to-face box pair 4 contacts, 6 when the faces are slightly offset
        (seen in the QP rollouts) and at most 8; the detector raises if they are not enough.
        """
        return 12 * self.cubes


def scene_xml(config: BoxPushingConfig) -> str:
    """MJCF of the scene: ground plane, cubes ``cube0…`` in a row along −x, then the bar.

    The cubes come first in the body order, so q = (cube₀ position, quaternion, …, bar x) and
    v = (cube₀ linear, angular, …, bar ẋ). Collision bits keep the bar off the ground: the bar
    touches only cubes.
    """
    half = config.edge / 2
    pitch = config.edge + config.gap
    cubes = "\n".join(
        f'    <body name="cube{i}" pos="{-i * pitch:.6f} 0 {half:.6f}">\n'
        f"      <freejoint/>\n"
        f'      <geom type="box" size="{half} {half} {half}" mass="{config.mass}"'
        f' contype="3" conaffinity="3" rgba="0.8 0.5 0.2 1"/>\n'
        f"    </body>"
        for i in range(config.cubes)
    )
    bar_half = (0.01, 1.5 * config.edge, 0.8 * half)  # thickness, width, height (halves) [m]
    bar_x = half + config.gap + bar_half[0]
    return f"""<mujoco model="box_pushing">
  <option timestep="{config.h}"/>
  <worldbody>
    <geom name="ground" type="plane" size="2 2 0.1" contype="1" conaffinity="1"/>
{cubes}
    <body name="bar" pos="{bar_x:.6f} 0 {half:.6f}">
      <joint name="bar" type="slide" axis="1 0 0"/>
      <geom type="box" size="{bar_half[0]} {bar_half[1]} {bar_half[2]:.6f}" mass="1"
            contype="2" conaffinity="2" rgba="0.3 0.3 0.8 1"/>
    </body>
  </worldbody>
</mujoco>
"""


@dataclass
class BoxPushingScene:
    """Everything a rollout needs.

    Attributes:
        config: the constants.
        model: the MuJoCo model (geometry and kinematics only; MuJoCo never steps it).
        detector: cube contacts (cube–ground, cube–cube, cube–bar) in ``config.slots`` slots.
        layout: joint layout of q (N free joints, then the bar's slide joint).
        Q: ``(nv,)`` diagonal metric ``(εMₒ/h², Kᵣ)`` in v order [N/m, N·m/rad].
        b: ``(nv,)`` linear term ``(m·g on each cube's z, Kᵣu)`` [N]; constant, as u is.
        q0: ``(nq,)`` initial configuration, the cubes resting on the ground.
        cube_q: ``(N, 7)`` indices of each cube's position and quaternion in q.
        bar_q: index of the bar's x in q.
        linear_v: indices in v of the cubes' linear velocities and of the bar's.
        angular_v: indices in v of the cubes' angular velocities.
        system: the quasi-dynamic system ``u ↦ (Q, b)`` (float64).
    """

    config: BoxPushingConfig
    model: mujoco.MjModel
    detector: ContactDetector
    layout: JointLayout
    Q: torch.Tensor
    b: torch.Tensor
    q0: torch.Tensor
    cube_q: torch.Tensor
    bar_q: int
    linear_v: torch.Tensor
    angular_v: torch.Tensor
    system: QuasiDynamic


def build_scene(config: BoxPushingConfig) -> BoxPushingScene:
    """Compile the scene; its quasi-dynamic system gives ``Q = diag(εMₒ/h², Kᵣ)`` and ``b``.

    Mₒ is each cube's mass on its 3 translations and its principal inertia on its 3 body-frame
    rotations, as MuJoCo computes them from the geometry.
    """
    model = mujoco.MjModel.from_xml_string(scene_xml(config))
    cube_bodies = [f"cube{i}" for i in range(config.cubes)]
    cube_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in cube_bodies]
    joints = [int(model.body_jntadr[i]) for i in cube_ids]
    dofs = torch.tensor([[int(model.jnt_dofadr[j]) + k for k in range(6)] for j in joints])
    bar_joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "bar")
    bar_dof = int(model.jnt_dofadr[bar_joint])
    masses = model.body_mass[cube_ids]  # (N,) [kg]
    inertia = model.body_inertia[cube_ids]  # (N, 3) [kg·m²]
    metric = np.concatenate([np.repeat(masses[:, None], 3, 1), inertia], 1)
    gravity = np.concatenate([masses[:, None] * model.opt.gravity, np.zeros((len(masses), 3))], 1)
    system = QuasiDynamic(
        object_metric=(config.epsilon / config.h**2 * metric).reshape(-1),
        robot_stiffness=config.robot_stiffness,
        object_force=gravity.reshape(-1),
        object_dofs=dofs.flatten().tolist(),
        n_robot=1,
    ).to(DTYPE)
    Q, b = system(torch.tensor([config.push], dtype=DTYPE))
    detector = ContactDetector(
        model,
        bodies=cube_bodies,
        slots=config.slots,
        mu=config.mu,
        margin=config.margin,
        dtype=DTYPE,
    )
    return BoxPushingScene(
        config=config,
        model=model,
        detector=detector,
        layout=joint_layout(model),
        Q=Q,
        b=b,
        q0=torch.from_numpy(model.qpos0.copy()).to(DTYPE),
        cube_q=torch.tensor([[int(model.jnt_qposadr[j]) + k for k in range(7)] for j in joints]),
        bar_q=int(model.jnt_qposadr[bar_joint]),
        linear_v=torch.cat([dofs[:, :3].flatten(), torch.tensor([bar_dof])]),
        angular_v=dofs[:, 3:].flatten(),
        system=system,
    )


class BoxPushingPlant:
    """The box-pushing scene simulated by MuJoCo, one model step per :meth:`step`.

    Args:
        config: the scene's constants (cubes, h, μ, detection margin, ...).
        substeps: MuJoCo steps per model step.

    Attributes:
        model, data: the MuJoCo scene (q: the cubes' free joints, then the bar's x).
        detector: cube contacts (ground, neighbours, bar) in ``config.slots`` slots, the
            deepest kept if more are found (predicted states may interpenetrate).
        frame_skip: ``substeps``.
    """

    def __init__(self, config: BoxPushingConfig | None = None, substeps: int = 10):
        config = BoxPushingConfig() if config is None else config
        if not isinstance(substeps, int) or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        self.config, self.frame_skip = config, substeps
        self.model = mujoco.MjModel.from_xml_string(scene_xml(config))
        self.model.opt.timestep = config.h / substeps
        self.model.geom_friction[:, 0] = config.mu
        self.data = mujoco.MjData(self.model)
        joint = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, "bar")
        self.bar_q = int(self.model.jnt_qposadr[joint])
        self.bar_v = int(self.model.jnt_dofadr[joint])
        self.detector = ContactDetector(
            self.model,
            bodies=[f"cube{i}" for i in range(config.cubes)],
            slots=config.slots,
            mu=config.mu,
            margin=config.margin,
            overflow="deepest",
        )

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def initial_state(self) -> np.ndarray:
        """``(nq,)`` the MJCF's configuration: the cubes at rest in a row, the bar behind."""
        return self.model.qpos0.copy()

    def reset(self, initial, target=None) -> None:
        """Start from the configuration ``initial (nq,)`` at rest (``target`` is unused: the
        scene has no goal)."""
        q = np.asarray(initial, dtype=np.float64)
        if q.shape != (self.nq,) or not np.all(np.isfinite(q)):
            raise ValueError(f"initial must be {self.nq} finite numbers, got shape {q.shape}")
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = q
        mujoco.mj_forward(self.model, self.data)

    def state(self) -> np.ndarray:
        """``(nq,)`` copy of q."""
        return self.data.qpos.copy()

    def step(self, u) -> np.ndarray:
        """Move the bar by ``u (1,)`` [m] over one model step; returns the new ``q (nq,)``."""
        u = np.asarray(u, dtype=np.float64).reshape(-1)
        if u.shape != (1,) or not np.isfinite(u[0]):
            raise ValueError(f"u must be one finite bar displacement [m], got {u!r}")
        x0, push = float(self.data.qpos[self.bar_q]), float(u[0])
        for sub in range(self.frame_skip):
            self.data.qpos[self.bar_q] = x0 + push * sub / self.frame_skip
            self.data.qvel[self.bar_v] = push / self.config.h
            mujoco.mj_step(self.model, self.data)
        self.data.qpos[self.bar_q] = x0 + push  # exactly where it was sent
        self.data.qvel[self.bar_v] = 0.0
        mujoco.mj_forward(self.model, self.data)
        return self.state()

    def contacts(self, dtype: torch.dtype | None = None) -> Contacts:
        """The cubes' contacts at the current state."""
        contacts = self.detector(self.data.qpos)
        return contacts if dtype is None else contacts.to(dtype)
