"""Full dynamics (Jin 2024): complementarity-free (CF) vs the Anitescu QP vs MuJoCo.

The step is the full-dynamic system ``Q = M(q)/h²``, ``b = M(q)v/h + τ`` with
``τ = applied − bias`` (MuJoCo's ``qfrc_bias``: gravity, Coriolis), ``M`` and the bias read from
MuJoCo at every state. One step of :func:`rollout`::

    M, bias = dynamics(scene, q, v)          # MuJoCo: mj_forward → M(q), qfrc_bias
    Q, b = full_dynamic(M, v, τ − bias, h)   # Q = M/h², b = Mv/h + τ
    contacts = scene.detector(q)             # φ = MuJoCo contact distance, Jⁿ, Jᵗ, μ
    v = model(Q, b, contacts, h)             # ComplementarityFree or AnitescuQP
    q = integrate(q, v, h, scene.layout)     # q ⊕ h v⁺

The three settings of the paper (:data:`SETTINGS`):

1. a sphere (r = 5 cm, 0.2 kg, three slide joints) resting on a floor under a ceiling 2 mm above
   its top, pushed by 1 N along x; h = 0.01 s, μ = 0.3, K = 20, D = 6, γ = 100.
2. a cube (6 cm, 10 g, inertia 6e−6·I, free joint) resting on the ground and launched at
   v_x = 2 m/s; h = 0.002 s, μ = 0.5, K = 1, D = 0.3.
3. the cube of 2 dropped from p = (0.1, 0, 0.2) m, quat ∝ (0.577, 0.577, 0.577, 0), with
   v = (1, 0, 0) m/s and ω = (20, 0, 0) rad/s; K = 1 and K = 2.

Choices made here (all in :class:`Setting` and printed into the JSON):

* γ = 100 for the sphere; **γ = 10⁴ for the cube**. The softplus floor ``log 2/γ`` is what every
  row pushes with at a zero argument: 6.9 mN at γ = 100, more than the 6.1 mN each of the 16
  ground rows carries under a 10 g cube, so at γ = 100 a resting cube floats up to the edge of
  the detection margin (measured by :func:`resting_clearance`, stored as ``rest_check``).
* detection margins: 1 cm for the sphere (the ceiling, 2 mm away, is always seen), 5 mm for the
  cube (a 2 m/s approach covers 4 mm per step). The CF damping pushes on every *approaching*
  row inside the margin, so for the cube the margin is part of the model: a larger margin gives
  a larger CF lift-off (measured: 17 mm at 2 mm, 34 mm at 1 cm, setting 2).
* MuJoCo reference: the same MJCF stepped by MuJoCo itself at timestep h with its defaults:
  Euler integrator, pyramidal cone, Newton solver, default solref/solimp, condim 3,
  friction μ (both geoms, so the combined friction is μ); ``--mujoco-cone`` and
  ``--mujoco-integrator`` change them.

Metrics (:func:`sphere_metrics`, :func:`cube_metrics`): terminal x-velocity, late acceleration
and the gaps to both planes (setting 1); landing time, vertical excursion (the centre's largest
height above its resting height after landing), lift-off (the lowest corner's largest ground
clearance after landing), settling time (after which the speed bound ``‖v‖ + r‖ω‖``, r the
half-diagonal, stays below 1 cm/s), roughness (total variation of the speed beyond its net
change; 0 for a monotone trace) and the vertical-velocity variation and reversals after landing
(settings 2–3).

What limits CF here (see the JSON's ``rest_check`` and the ``--damping``/``--stiffness``
overrides): λ damps the *predicted* row velocity, so at rest every row gets ``D·h·g``; with
``D > m/(n_d h) − K h`` (4.8 N·s/m for the sphere) an unloaded body hovers. And each dual-cone
row's predicted gap contains ``μ d·v_t``, the term of the Anitescu constraint: the row facing
the slip sees a closing speed μ|v_t| and pushes along ``n + μd``, so a sliding body is lifted
(and a ceiling inside the margin pushes back) as in the QP, over a sheath of about
``(h + D/K)·μ|v_t|``. Small D removes the lift but leaves only viscous friction.

Run ``python benchmarks/full_dynamic.py --help``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import mujoco
import numpy as np
import torch
from tqdm.auto import tqdm

from studies import report
from torchcontact.integrate import JointLayout, integrate
from torchcontact.model import AnitescuQP, ComplementarityFree, ContactModel
from torchcontact.sim import ContactDetector, bias_force, joint_layout, mass_matrix
from torchcontact.stiffness import Constant
from torchcontact.systems import full_dynamic
from torchcontact.validation import validate_args

DTYPE = torch.float64

SETTLE_SPEED = 0.01
"""[m/s] speed bound below which the cube counts as settled."""

LANDING_CLEARANCE = 1e-3
"""[m] ground clearance of the cube's lowest corner that counts as landed."""

REVERSAL_SPEED = 0.01
"""[m/s] vertical speed a v_z sign change must exceed on both sides to count as a reversal."""

MUJOCO_CONES = ("pyramidal", "elliptic")
MUJOCO_INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")

QP_SETTINGS = {"polishing": False}
"""OSQP at the library's 1e-10 tolerances, without polishing: polishing prints "Polishing not
needed" to stdout from C whenever no constraint is active (every free-flight step)."""


# --- scenes ---------------------------------------------------------------------------------


def sphere_between_planes_xml(
    radius: float, mass: float, gap: float, mu: float, h: float, cone: str, integrator: str
) -> str:
    """MJCF: a sphere on three slide joints (x, y, z) resting on a floor, a ceiling ``gap`` [m]
    above its top. qpos = the sphere's displacement from its resting centre (0, 0, radius).
    Gravity is MuJoCo's default (:func:`gravity` reads it back)."""
    ceiling = 2 * radius + gap
    return f"""<mujoco model="sphere_between_planes">
  <option timestep="{h}" integrator="{integrator}" cone="{cone}"/>
  <default><geom condim="3" friction="{mu} 0 0"/></default>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <geom name="ceiling" type="plane" size="2 2 0.1" pos="0 0 {ceiling}" euler="180 0 0"/>
    <body name="sphere" pos="0 0 {radius}">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="z" type="slide" axis="0 0 1"/>
      <geom name="sphere" type="sphere" size="{radius}" mass="{mass}"/>
    </body>
  </worldbody>
</mujoco>
"""


def cube_on_ground_xml(
    edge: float, mass: float, inertia: float, mu: float, h: float, cone: str, integrator: str
) -> str:
    """MJCF: a cube on a free joint above a ground plane; its pose is set through qpos.
    Gravity is MuJoCo's default (:func:`gravity` reads it back)."""
    half = edge / 2
    return f"""<mujoco model="cube_on_ground">
  <option timestep="{h}" integrator="{integrator}" cone="{cone}"/>
  <default><geom condim="3" friction="{mu} 0 0"/></default>
  <worldbody>
    <geom name="ground" type="plane" size="2 2 0.1"/>
    <body name="cube" pos="0 0 {half}">
      <freejoint/>
      <inertial pos="0 0 0" mass="{mass}" diaginertia="{inertia} {inertia} {inertia}"/>
      <geom name="cube" type="box" size="{half} {half} {half}"/>
    </body>
  </worldbody>
</mujoco>
"""


@dataclass(frozen=True)
class Setting:
    """One experiment: scene, initial state, load and model constants.

    Attributes:
        number: 1, 2 or 3.
        title: one line for tables and plots.
        xml: the scene's MJCF (also MuJoCo's reference plant).
        body: the modelled body (its contacts go to the detector).
        slots: contact slots of the detector.
        qpos0: ``(nq,)`` initial configuration.
        qvel0: ``(nv,)`` initial velocity (free joint: world linear, body angular).
        force: ``(nv,)`` applied generalized force [N, N·m], constant.
        h: time step [s].
        mu: friction coefficient of every contact.
        steps: time steps of each rollout.
        stiffness: K values [N/m]; one CF rollout each.
        damping: D [N·s/m].
        gamma: softplus sharpness γ [1/N]; None for the exact ``max(·, 0)``.
        margin: detection distance [m].
        facets: friction-cone facets n_d (CF and QP alike).
        mujoco_cone, mujoco_integrator: options of MuJoCo's reference run.
    """

    number: int
    title: str
    xml: str
    body: str
    slots: int
    qpos0: tuple[float, ...]
    qvel0: tuple[float, ...]
    force: tuple[float, ...]
    h: float
    mu: float
    steps: int
    stiffness: tuple[float, ...]
    damping: float
    gamma: float | None
    margin: float
    facets: int = 4
    mujoco_cone: str = "pyramidal"
    mujoco_integrator: str = "Euler"


SPHERE = {"radius": 0.05, "mass": 0.2, "gap": 0.002}
"""Setting 1's sphere: radius [m], mass [kg], gap between its top and the ceiling [m]."""

CUBE = {"edge": 0.06, "mass": 0.01, "inertia": 6e-6}
"""Settings 2–3's cube: edge [m], mass [kg], principal inertia [kg·m²] (6e−6·I)."""


def sphere_setting(cone: str = "pyramidal", integrator: str = "Euler") -> Setting:
    """Setting 1: the sphere between two planes pushed by 1 N along x for 2 s."""
    h, mu = 0.01, 0.3
    return Setting(
        number=1,
        title="sphere between planes, 1 N along x",
        xml=sphere_between_planes_xml(**SPHERE, mu=mu, h=h, cone=cone, integrator=integrator),
        body="sphere",
        slots=2,
        qpos0=(0.0, 0.0, 0.0),
        qvel0=(0.0, 0.0, 0.0),
        force=(1.0, 0.0, 0.0),
        h=h,
        mu=mu,
        steps=200,
        stiffness=(20.0,),
        damping=6.0,
        gamma=100.0,
        margin=0.01,
        mujoco_cone=cone,
        mujoco_integrator=integrator,
    )


def _unit_quaternion(wxyz: Sequence[float]) -> tuple[float, ...]:
    q = np.asarray(wxyz, dtype=np.float64)
    return tuple((q / np.linalg.norm(q)).tolist())


def sliding_cube_setting(cone: str = "pyramidal", integrator: str = "Euler") -> Setting:
    """Setting 2: the cube resting on the ground, launched at v_x = 2 m/s, for 1 s."""
    h, mu = 0.002, 0.5
    return Setting(
        number=2,
        title="sliding cube, v_x(0) = 2 m/s",
        xml=cube_on_ground_xml(**CUBE, mu=mu, h=h, cone=cone, integrator=integrator),
        body="cube",
        slots=8,
        qpos0=(0.0, 0.0, CUBE["edge"] / 2, 1.0, 0.0, 0.0, 0.0),
        qvel0=(2.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        force=(0.0,) * 6,
        h=h,
        mu=mu,
        steps=500,
        stiffness=(1.0,),
        damping=0.3,
        gamma=1e4,
        margin=0.005,
        mujoco_cone=cone,
        mujoco_integrator=integrator,
    )


def falling_cube_setting(cone: str = "pyramidal", integrator: str = "Euler") -> Setting:
    """Setting 3: the cube dropped spinning from 0.2 m, for 1.5 s; K = 1 and K = 2."""
    base = sliding_cube_setting(cone, integrator)
    return replace(
        base,
        number=3,
        title="falling spinning cube",
        qpos0=(0.1, 0.0, 0.2, *_unit_quaternion((0.577, 0.577, 0.577, 0.0))),
        qvel0=(1.0, 0.0, 0.0, 20.0, 0.0, 0.0),
        steps=750,
        stiffness=(1.0, 2.0),
    )


SETTINGS: dict[int, Callable[..., Setting]] = {
    1: sphere_setting,
    2: sliding_cube_setting,
    3: falling_cube_setting,
}


@dataclass
class Scene:
    """A compiled setting: MuJoCo model, dynamics scratch data, detector and joint layout."""

    setting: Setting
    model: mujoco.MjModel
    data: mujoco.MjData
    detector: ContactDetector
    layout: JointLayout
    geom: int

    @property
    def h(self) -> float:
        return self.setting.h


def build_scene(setting: Setting) -> Scene:
    """Compile ``setting.xml`` and its detector (``setting.body``'s contacts, margin, μ)."""
    model = mujoco.MjModel.from_xml_string(setting.xml)
    detector = ContactDetector(
        model,
        bodies=[setting.body],
        slots=setting.slots,
        mu=setting.mu,
        margin=setting.margin,
        dtype=DTYPE,
    )
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, setting.body)
    return Scene(setting, model, mujoco.MjData(model), detector, joint_layout(model), geom)


# --- rollouts -------------------------------------------------------------------------------


@dataclass
class Trajectory:
    """States of one rollout: ``time (T+1,)`` [s], ``qpos (T+1, nq)``, ``qvel (T+1, nv)``."""

    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray


def dynamics(scene: Scene, q: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """MuJoCo's ``M(q)`` ``(nv, nv)`` [kg, kg·m²] and bias force ``(nv,)`` [N, N·m] at (q, v)."""
    data = scene.data
    data.qpos[:] = q.numpy()
    data.qvel[:] = v.numpy()
    mujoco.mj_forward(scene.model, data)
    return torch.from_numpy(mass_matrix(scene.model, data)), torch.from_numpy(bias_force(data))


def contact_model(setting: Setting, name: str, stiffness: float | None = None) -> ContactModel:
    """``"cf"``: CF with constant K = ``stiffness`` [N/m], D, γ of the setting; ``"qp"``: the
    Anitescu QP by OSQP (``stiffness`` unused)."""
    if name == "cf":
        if stiffness is None:
            raise ValueError("stiffness is required for the 'cf' model")
        return ComplementarityFree(
            Constant(stiffness, learnable=False),
            Constant(setting.damping, learnable=False),
            gamma=setting.gamma,
            facets=setting.facets,
        ).to(DTYPE)
    if name == "qp":
        return AnitescuQP(facets=setting.facets, settings=QP_SETTINGS)
    raise ValueError(f"name must be 'cf' or 'qp', got {name!r}")


def rollout(
    model: ContactModel,
    scene: Scene,
    qpos0: Sequence[float],
    qvel0: Sequence[float],
    force: Sequence[float],
    steps: int,
    progress: tqdm | None = None,
) -> Trajectory:
    """Full-dynamic rollout of ``steps`` steps of ``model`` from ``(qpos0, qvel0)``.

    Args:
        model: a contact model mapping ``(Q, b, contacts, h)`` to ``v⁺``.
        scene: the compiled scene (M, bias and contacts come from its MuJoCo model).
        qpos0: ``(nq,)`` initial configuration; qvel0: ``(nv,)`` initial velocity.
        force: ``(nv,)`` constant applied generalized force [N, N·m].
        steps: number of steps; progress: an optional bar advanced once per step.
    """
    h = scene.h
    q = torch.tensor(qpos0, dtype=DTYPE)
    v = torch.tensor(qvel0, dtype=DTYPE)
    applied = torch.tensor(force, dtype=DTYPE)
    qs, vs = [q], [v]
    with torch.inference_mode(), validate_args(False):
        for _ in range(steps):
            M, bias = dynamics(scene, q, v)
            Q, b = full_dynamic(M, v, applied - bias, h)
            contacts = scene.detector(q)
            v = model(Q, b, contacts, h)
            q = integrate(q, v, h, scene.layout)
            qs.append(q)
            vs.append(v)
            if progress is not None:
                progress.update()
    return Trajectory(h * np.arange(steps + 1), torch.stack(qs).numpy(), torch.stack(vs).numpy())


def mujoco_rollout(
    scene: Scene,
    qpos0: Sequence[float],
    qvel0: Sequence[float],
    force: Sequence[float],
    steps: int,
    progress: tqdm | None = None,
) -> Trajectory:
    """The reference: ``steps`` calls of ``mj_step`` on the scene's own MuJoCo model (its
    timestep is h), ``force`` applied through ``qfrc_applied``. Arguments as :func:`rollout`."""
    data = mujoco.MjData(scene.model)
    data.qpos[:] = qpos0
    data.qvel[:] = qvel0
    qs, vs = [data.qpos.copy()], [data.qvel.copy()]
    for _ in range(steps):
        data.qfrc_applied[:] = force
        mujoco.mj_step(scene.model, data)
        qs.append(data.qpos.copy())
        vs.append(data.qvel.copy())
        if progress is not None:
            progress.update()
    return Trajectory(scene.h * np.arange(steps + 1), np.stack(qs), np.stack(vs))


# --- geometry and metrics -------------------------------------------------------------------


def vertical_extent(scene: Scene, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest world z [m] of the body's geom (sphere or box) at each ``qpos (T, nq)``.

    A box reaches ``Σᵢ |R₂ᵢ| sᵢ`` above and below its centre (R its rotation, s its half sizes).
    """
    model, data, geom = scene.model, mujoco.MjData(scene.model), scene.geom
    size = model.geom_size[geom]
    low, high = np.empty(len(qpos)), np.empty(len(qpos))
    for i, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        centre = data.geom_xpos[geom, 2]
        if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_SPHERE:
            reach = size[0]
        else:
            reach = np.abs(data.geom_xmat[geom].reshape(3, 3)[2]) @ size
        low[i], high[i] = centre - reach, centre + reach
    return low, high


def speed_roughness(speed: np.ndarray) -> float:
    """Total variation of ``speed (T,)`` beyond its net change [m/s]: 0 for a monotone trace."""
    if len(speed) < 2:
        return 0.0
    return float(np.abs(np.diff(speed)).sum() - abs(speed[-1] - speed[0]))


def reversals(velocity: np.ndarray, threshold: float = REVERSAL_SPEED) -> int:
    """Sign changes of ``velocity (T,)`` between excursions beyond ±``threshold`` [m/s]."""
    signs = np.sign(velocity[np.abs(velocity) > threshold])
    return int((np.diff(signs) != 0).sum())


def settling_time(time: np.ndarray, speed: np.ndarray, threshold: float) -> float | None:
    """First time after which ``speed`` stays below ``threshold`` [s]; None if it never does."""
    above = np.flatnonzero(speed >= threshold)
    if len(above) == 0:
        return float(time[0])
    if above[-1] == len(speed) - 1:
        return None
    return float(time[above[-1] + 1])


def sphere_metrics(scene: Scene, trajectory: Trajectory) -> dict:
    """Setting 1: terminal and late behaviour of the x-velocity, and the gaps to both planes.

    ``late_acceleration``: the least-squares slope of v_x over the second half [m/s²] (a plateau
    reads ≈ 0; Coulomb sliding (1 − μmg)/m). ``floor_gap_min`` / ``ceiling_gap_min``: the
    smallest distance to the floor / ceiling over the run [m] (negative: penetration).
    """
    low, high = vertical_extent(scene, trajectory.qpos)
    ceiling = 2 * SPHERE["radius"] + SPHERE["gap"]
    half = len(trajectory.time) // 2
    slope = np.polyfit(trajectory.time[half:], trajectory.qvel[half:, 0], 1)[0]
    return {
        "terminal_vx": float(trajectory.qvel[-1, 0]),
        "late_acceleration": float(slope),
        "floor_gap_min": float(low.min()),
        "ceiling_gap_min": float((ceiling - high).min()),
        "floor_gap_final": float(low[-1]),
        "ceiling_gap_final": float(ceiling - high[-1]),
        "terminal_height": float(trajectory.qpos[-1, 2]),
    }


def gravity(scene: Scene) -> float:
    """g [m/s²]: the magnitude of the scene's gravity, MuJoCo's own (``model.opt.gravity``)."""
    return float(np.linalg.norm(scene.model.opt.gravity))


def coulomb_acceleration(scene: Scene) -> float:
    """(F − μmg)/m [m/s²]: setting 1's sphere sliding on the floor alone under Coulomb
    friction."""
    setting, mass = scene.setting, SPHERE["mass"]
    return (setting.force[0] - setting.mu * mass * gravity(scene)) / mass


def cube_metrics(scene: Scene, trajectory: Trajectory) -> dict:
    """Settings 2–3: landing, vertical excursion, penetration, settling and smoothness.

    * ``landing_time`` [s]: first time the lowest corner is within ``LANDING_CLEARANCE`` of the
      ground (the QP stops a falling cube at φ ≈ +0, never below).
    * ``height_excursion`` [m]: largest height of the centre above its resting height (edge/2)
      after landing; ``clearance_max`` [m]: largest ground clearance of the lowest corner after
      landing (lift-off: 0 while some corner touches).
    * ``penetration_max`` [m]: deepest penetration of the lowest corner (≥ 0).
    * ``settling_time`` [s]: after it ``‖v‖ + r‖ω‖ < SETTLE_SPEED`` for good (r: half-diagonal).
    * ``speed_roughness`` / ``horizontal_roughness`` [m/s]: :func:`speed_roughness` of ``‖v‖``
      and of ``‖(v_x, v_y)‖`` after landing.
    * ``vz_variation`` [m/s]: total variation of v_z after landing; ``vz_reversals``: its sign
      changes beyond ±``REVERSAL_SPEED`` (bounces, rocking).
    """
    low, _ = vertical_extent(scene, trajectory.qpos)
    time, qpos, qvel = trajectory.time, trajectory.qpos, trajectory.qvel
    touching = np.flatnonzero(low <= LANDING_CLEARANCE)
    landing = int(touching[0]) if len(touching) else len(time) - 1
    speed = np.linalg.norm(qvel[:, :3], axis=1)
    horizontal = np.linalg.norm(qvel[:, :2], axis=1)
    radius = math.sqrt(3) * CUBE["edge"] / 2
    bound = speed + radius * np.linalg.norm(qvel[:, 3:], axis=1)
    after = slice(landing, None)
    return {
        "landing_time": float(time[landing]),
        "height_excursion": float((qpos[after, 2] - CUBE["edge"] / 2).max()),
        "clearance_max": float(max(0.0, low[after].max())),
        "penetration_max": float(max(0.0, -low.min())),
        "settling_time": settling_time(time, bound, SETTLE_SPEED),
        "speed_roughness": speed_roughness(speed[after]),
        "horizontal_roughness": speed_roughness(horizontal[after]),
        "vz_variation": float(np.abs(np.diff(qvel[after, 2])).sum()),
        "vz_reversals": reversals(qvel[after, 2]),
        "final_x": float(qpos[-1, 0]),
        "final_height": float(qpos[-1, 2]),
    }


def resting_qpos(setting: Setting) -> tuple[float, ...]:
    """The body at rest on the floor: the sphere's zero displacement, the cube flat."""
    if setting.number == 1:
        return (0.0, 0.0, 0.0)
    return (0.0, 0.0, CUBE["edge"] / 2, 1.0, 0.0, 0.0, 0.0)


def resting_clearance(setting: Setting, gamma: float | None, steps: int) -> float:
    """Floor clearance [m] of the body left at rest on the floor, unloaded, after ``steps`` CF
    steps (K, D of ``setting``, softplus sharpness ``gamma``): ≈ 0 for a model that holds a
    resting body; > 0 when the softplus floor or the damping lifts it."""
    scene = build_scene(setting)
    model = contact_model(replace(setting, gamma=gamma), "cf", setting.stiffness[0])
    zero = (0.0,) * scene.model.nv
    trajectory = rollout(model, scene, resting_qpos(setting), zero, zero, steps)
    low, _ = vertical_extent(scene, trajectory.qpos[-1:])
    return float(low[0])


# --- one setting ----------------------------------------------------------------------------


def run_label(name: str, stiffness: float | None = None) -> str:
    """Key of a run in results: ``"cf_K20"``, ``"qp"``, ``"mujoco"``."""
    return f"cf_K{stiffness:g}" if name == "cf" else name


def run_setting(setting: Setting, progress: bool = True) -> dict:
    """All rollouts of one setting (CF for each K, QP, MuJoCo) and their metrics.

    Returns a JSON-ready dict: ``setting`` (constants), ``metrics`` per run, ``rest_check``
    (:func:`resting_clearance` over as many steps, at γ = 100 and the setting's γ),
    ``reference`` (setting 1) and ``trajectories`` per run: ``time``, ``qpos``, ``qvel``.
    """
    scene = build_scene(setting)
    runs = [("cf", k) for k in setting.stiffness] + [("qp", None), ("mujoco", None)]
    metrics_of = sphere_metrics if setting.number == 1 else cube_metrics
    state = (setting.qpos0, setting.qvel0, setting.force, setting.steps)
    trajectories: dict[str, Trajectory] = {}
    bar = tqdm(
        total=len(runs) * setting.steps,
        desc=f"setting {setting.number}",
        disable=not progress,
        leave=False,
    )
    with bar:
        for name, stiffness in runs:
            label = run_label(name, stiffness)
            bar.set_postfix_str(label)
            if name == "mujoco":
                trajectories[label] = mujoco_rollout(scene, *state, progress=bar)
            else:
                model = contact_model(setting, name, stiffness)
                trajectories[label] = rollout(model, scene, *state, progress=bar)
    metrics = {label: metrics_of(scene, t) for label, t in trajectories.items()}
    result = {
        "setting": {k: v for k, v in asdict(setting).items() if k != "xml"},
        "metrics": metrics,
        "trajectories": {
            label: {"time": t.time.tolist(), "qpos": t.qpos.tolist(), "qvel": t.qvel.tolist()}
            for label, t in trajectories.items()
        },
    }
    if setting.number == 1:
        result["reference"] = {
            "coulomb_acceleration": coulomb_acceleration(scene),
            "coulomb_terminal_vx": coulomb_acceleration(scene) * setting.steps * setting.h,
            "qp_sheath_plateau_vx": SPHERE["gap"] / (2 * setting.mu * setting.h),
        }
    result["rest_check"] = {
        f"clearance_gamma_{g:g}": resting_clearance(setting, g, setting.steps)
        for g in sorted({100.0, setting.gamma})
    }
    return result


# --- output ---------------------------------------------------------------------------------


def trace_columns(result: dict) -> dict[str, np.ndarray]:
    """Per-step columns of a setting for its CSV: time, then per run x-velocity (setting 1) or
    height, v_z and ‖v‖ (settings 2–3)."""
    runs = result["trajectories"]
    first = next(iter(runs.values()))
    columns = {"time": np.asarray(first["time"])}
    for label, t in runs.items():
        qpos, qvel = np.asarray(t["qpos"]), np.asarray(t["qvel"])
        if result["setting"]["number"] == 1:
            columns[f"{label}_vx"] = qvel[:, 0]
            columns[f"{label}_z"] = qpos[:, 2]
        else:
            columns[f"{label}_z"] = qpos[:, 2]
            columns[f"{label}_vz"] = qvel[:, 2]
            columns[f"{label}_speed"] = np.linalg.norm(qvel[:, :3], axis=1)
    return columns


def write_trace_csv(path: Path, columns: dict[str, np.ndarray]) -> Path:
    """One row per step, one column per entry of ``columns`` (each ``(T,)``)."""
    names = list(columns)
    rows = (dict(zip(names, row, strict=True)) for row in zip(*columns.values(), strict=True))
    return report.write_csv(path, rows)


AFTER_IMPACT = 0.01
"""[s] setting 3's plot starts this long after the first landing."""

STYLE = {"qp": ("tab:orange", "-"), "mujoco": ("tab:green", "-")}
CF_COLOURS = ("tab:blue", "tab:purple", "tab:cyan")


def _style(label: str, index: int) -> dict:
    colour, line = STYLE.get(label, (CF_COLOURS[index % len(CF_COLOURS)], "-"))
    name = {"qp": "QP (Anitescu, OSQP)", "mujoco": "MuJoCo"}.get(label, f"CF K={label[4:]}")
    return {"color": colour, "linestyle": line, "label": name, "linewidth": 1.3}


def plot_setting(path: Path, result: dict) -> None:
    """PNG of one setting: x-velocity and plane gaps (1), or height, v_z and ‖v‖ (2–3)."""
    number = result["setting"]["number"]
    columns = trace_columns(result)
    if number == 3:  # after the free fall and the impact: the oscillations are the point
        landing = min(m["landing_time"] for m in result["metrics"].values())
        keep = columns["time"] >= landing + AFTER_IMPACT
        columns = {k: v[keep] for k, v in columns.items()}
    time = columns["time"]
    panels = 2 if number == 1 else 3
    fig, axes = report.figure(panels, 1, size=(7.5, 2.6 * panels), sharex=True)
    fig.set_layout_engine("constrained")
    traces = [("vx", 1.0), ("z", 1e3)] if number == 1 else [("z", 1e3), ("vz", 1.0), ("speed", 1.0)]
    for i, label in enumerate(result["trajectories"]):
        for ax, (name, scale) in zip(axes, traces, strict=True):
            ax.plot(time, scale * columns[f"{label}_{name}"], **_style(label, i))
    if number == 1:
        reference = result["reference"]["coulomb_acceleration"]
        axes[0].plot(time, reference * time, "k--", lw=0.9, label="(F − μmg)/m · t")
        axes[1].axhline(1e3 * SPHERE["gap"], color="k", lw=0.8, ls=":", label="ceiling contact")
        axes[1].axhline(0.0, color="k", lw=0.8, ls="-.", label="floor contact")
        names = ("x-velocity [m/s]", "sphere lift z [mm]")
    else:
        names = ("centre height z [mm]", "vertical velocity [m/s]", "speed ‖v‖ [m/s]")
    for ax, name in zip(axes, names, strict=True):
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    axes[-1].set_xlabel("time [s]")
    window = f" (from {time[0]:.2f} s: after the impact)" if number == 3 else ""
    fig.suptitle(f"Setting {number}: {result['setting']['title']}{window}", fontsize=10)
    report.save_figure(fig, path, dpi=110)


SPHERE_COLUMNS = ("run", "v_x(end) m/s", "late a m/s²", "floor gap min mm", "ceil gap min mm")
CUBE_COLUMNS = (
    "run",
    "landing s",
    "excursion mm",
    "lift-off mm",
    "penetr. mm",
    "settle s",
    "rough |v|",
    "rough |v_xy|",
    "vz TV m/s",
    "vz rev",
)


def _sphere_cells(label: str, m: dict) -> list[str]:
    return [
        label,
        f"{m['terminal_vx']:.3f}",
        f"{m['late_acceleration']:.3f}",
        f"{1e3 * m['floor_gap_min']:.2f}",
        f"{1e3 * m['ceiling_gap_min']:.2f}",
    ]


def _cube_cells(label: str, m: dict) -> list[str]:
    settle = m["settling_time"]
    return [
        label,
        f"{m['landing_time']:.3f}",
        f"{1e3 * m['height_excursion']:.2f}",
        f"{1e3 * m['clearance_max']:.2f}",
        f"{1e3 * m['penetration_max']:.2f}",
        "never" if settle is None else f"{settle:.3f}",
        f"{m['speed_roughness']:.4f}",
        f"{m['horizontal_roughness']:.4f}",
        f"{m['vz_variation']:.3f}",
        f"{m['vz_reversals']:d}",
    ]


def _notes(result: dict) -> list[str]:
    """The lines under a setting's table: what the columns mean, the references, the rest
    check."""
    setting = result["setting"]
    if setting["number"] == 1:
        ref = result["reference"]
        notes = [
            f"Coulomb sliding: a = (F − μmg)/m = {ref['coulomb_acceleration']:.3f} m/s², "
            f"v_x(end) = {ref['coulomb_terminal_vx']:.3f} m/s; "
            f"QP sheath plateau gap/(2μh) = {ref['qp_sheath_plateau_vx']:.3f} m/s"
        ]
    else:
        notes = [
            f"excursion: max centre height above rest (edge/2) after landing; lift-off: max "
            f"clearance of the lowest corner after landing; settle: ‖v‖ + r‖ω‖ < {SETTLE_SPEED}"
            " m/s for good; rough: total variation beyond the net change [m/s] after landing",
        ]
    check = ", ".join(
        f"γ={k.rsplit('_', 1)[1]}: {1e3 * v:.2f} mm" for k, v in result["rest_check"].items()
    )
    duration = setting["steps"] * setting["h"]
    notes.append(f"CF body left at rest, unloaded, floor clearance after {duration:g} s: {check}")
    return notes


def format_table(result: dict) -> str:
    """The key numbers of one setting as a text table: a title, one row per run, notes."""
    setting = result["setting"]
    sphere = setting["number"] == 1
    cells = _sphere_cells if sphere else _cube_cells
    rows = [cells(label, m) for label, m in result["metrics"].items()]
    table = report.format_table(SPHERE_COLUMNS if sphere else CUBE_COLUMNS, rows, left=1)
    ks = ", ".join(f"{k:g}" for k in setting["stiffness"])
    title = (
        f"Setting {setting['number']}: {setting['title']} (h={setting['h']:g} s, "
        f"μ={setting['mu']:g}, K={ks}, D={setting['damping']:g}, γ={setting['gamma']}, "
        f"margin={setting['margin']:g} m, {setting['steps']} steps; MuJoCo "
        f"{setting['mujoco_integrator']}, {setting['mujoco_cone']} cone)"
    )
    return "\n".join([title, table, *_notes(result)])


def summary(result: dict) -> dict:
    """``result`` without its trajectories (for the JSON summary)."""
    return {k: v for k, v in result.items() if k != "trajectories"}


def write_outputs(
    out: Path, results: Sequence[dict], json_path: Path | None, plots: bool
) -> list[Path]:
    """Per setting ``setting{n}.csv`` (traces) and ``setting{n}.png``; ``full_dynamic.json``
    (metrics, constants) in ``out`` and, if given, at ``json_path``. Returns the paths."""
    paths = []
    for result in results:
        number = result["setting"]["number"]
        paths.append(write_trace_csv(out / f"setting{number}.csv", trace_columns(result)))
        if plots:
            plot_setting(out / f"setting{number}.png", result)
            paths.append(out / f"setting{number}.png")
    document = {"settings": [summary(r) for r in results]}
    for path in dict.fromkeys([out / "full_dynamic.json", *([json_path] if json_path else [])]):
        paths.append(report.write_json(path, document))
    return paths


# --- command line ---------------------------------------------------------------------------


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The options: ``--setting``, the overrides of the settings' constants, MuJoCo's cone and
    integrator, the outputs."""
    parser = report.parser(
        "python benchmarks/full_dynamic.py",
        "Full-dynamic settings 1-3 of Jin 2024: complementarity-free vs the Anitescu QP vs "
        "MuJoCo. Prints the key numbers, writes CSV/PNG per setting and JSON.",
        "results/full_dynamic",
    )
    positive_float = report.positive_float
    parser.add_argument("--setting", choices=["1", "2", "3", "all"], default="all")
    parser.add_argument("--json", type=Path, default=None, help="also write the JSON here")
    parser.add_argument("--steps", type=int, default=None, help="override every setting's steps")
    parser.add_argument("--damping", type=positive_float, help="override D [N·s/m]")
    parser.add_argument(
        "--stiffness", type=positive_float, nargs="+", help="override the K values [N/m]"
    )
    parser.add_argument("--gamma", type=float, default=None, help="override γ (0: exact max)")
    parser.add_argument("--mujoco-cone", choices=MUJOCO_CONES, default="pyramidal")
    parser.add_argument("--mujoco-integrator", choices=MUJOCO_INTEGRATORS, default="Euler")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    args = parser.parse_args(argv)
    if args.steps is not None and args.steps < 2:
        parser.error(f"--steps must be at least 2, got {args.steps}")
    if args.gamma is not None and not (math.isfinite(args.gamma) and args.gamma >= 0):
        parser.error(f"--gamma must be non-negative (0: exact max), got {args.gamma}")
    return args


def configured_setting(number: int, args: argparse.Namespace) -> Setting:
    """Setting ``number`` with the command line's overrides applied."""
    setting = SETTINGS[number](args.mujoco_cone, args.mujoco_integrator)
    overrides = {}
    if args.steps is not None:
        overrides["steps"] = args.steps
    if args.damping is not None:
        overrides["damping"] = args.damping
    if args.stiffness is not None:
        overrides["stiffness"] = tuple(args.stiffness)
    if args.gamma is not None:
        overrides["gamma"] = args.gamma or None
    return replace(setting, **overrides)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the chosen settings, print their tables, write CSV/PNG/JSON under ``--out``;
    returns the exit status 0."""
    args = parse_args(argv)
    numbers = sorted(SETTINGS) if args.setting == "all" else [int(args.setting)]
    results = []
    for number in numbers:
        result = run_setting(configured_setting(number, args), progress=not args.no_progress)
        print(format_table(result), end="\n\n", flush=True)
        results.append(result)
    report.written(write_outputs(args.out, results, args.json, plots=not args.no_plots))
    return 0


if __name__ == "__main__":
    report.run_main(main)
