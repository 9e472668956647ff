"""Box pushing (Jin 2024): a bar on a slide joint pushes a row of N cubes; CF against the QP.

The paper's quasi-dynamic step, ``h = 0.02 s``, ``ε = 40``, ``Kᵣ = 500 N/m``, contact stiffness
``K = 1`` on every dual-cone row and a bar command of ``u = −0.001 m`` per step, is rolled out
for 1000 steps twice: once driven by the complementarity-free model (CF), once by the Anitescu
QP solved by OSQP. At every state of both rollouts both models predict ``v⁺`` from the same
``Q``, ``b`` and :class:`~torchcontact.Contacts`, each call timed. One step of :func:`rollout`::

    contacts = scene.detector(q)            # MuJoCo collision → φ, Jⁿ, Jᵈ, μ
    v = model(Q, b, contacts, h)            # ComplementarityFree or AnitescuQP   ← timed
    q = integrate(q, v, h, scene.layout)    # q ⊕ h v⁺

Scene choices (:class:`BoxPushingConfig`): 5 cm cubes of 1 g, 1 cm apart, μ = 0.5, detection
margin 5 mm, the exact ``max(·, 0)`` in the CF model. K = 1 N/m acts per row, so the cube mass
decides how the contacts behave: the explicit CF update is stable only when
``K·λmax(J̃Q⁻¹J̃ᵀ) < 2`` with ``Q = εM/h²``; for a resting cube the stiffest (tilting) mode gives
2.9 at 0.3 g (the cube then rocks with period 2), 1.9 at 0.6 g and 0.9–1.2 at 1 g (on the
ground, in the row). Heavier cubes sink: 0.1 kg would rest 6 cm deep, and 20 of them would
outweigh the bar's ``Kᵣ|u| = 0.5 N`` in friction. The softplus of the paper's MPC (γ = 100)
gives every row a floor of ``log 2/γ ≈ 7 mN``, enough to lift 1 g cubes off the ground, hence
the exact max. The price of one K for every row: a resting cube sits 0.5 mm deep
(``φ = gh²/ε − mg/(16K)``), and the bar's push crosses each face pair through only 16 rows, so
the bar sinks 4 mm into a single cube and up to 2.5 cm into a row of 10–20, where the QP does
not penetrate. CLI: ``python -m torchcontact.experiments.box_pushing --help``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import torch
from tqdm.auto import tqdm

from torchcontact.contacts import Contacts
from torchcontact.integrate import JointLayout, integrate
from torchcontact.model import AnitescuQP, ComplementarityFree, ContactModel
from torchcontact.results import save_figure, write_csv, write_json
from torchcontact.sim import ContactDetector, joint_layout
from torchcontact.stiffness import Constant
from torchcontact.systems import QuasiDynamic
from torchcontact.validation import validate_args

SWEEP = (1, 5, 10, 15, 20)
"""Cube counts of the paper's timing comparison."""

DTYPE = torch.float64

TIMED_REGION = (
    "the call model(Q, b, contacts, h) -> v+ (dual-cone rows, K, lambda or the OSQP solve, v+), "
    "under torch.inference_mode() with value checks off; not detection, not integration"
)


@dataclass(frozen=True)
class BoxPushingConfig:
    """The experiment's constants; the model ones (h, ε, Kᵣ, K, u) are the paper's.

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
            (:data:`torchcontact.qp.OSQP_SETTINGS`). 1e-10 ends in "solved inaccurate" at
            10 cubes; 1e-6 keeps v⁺ within ~2e-4 m/s of the 1e-10 solution.
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
        for name in ("cubes", "steps"):
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


def contact_model(name: str, config: BoxPushingConfig) -> ContactModel:
    """``"cf"``: the CF model with the fixed K (no damping); ``"qp"``: the OSQP baseline."""
    if name == "cf":
        stiffness = Constant(config.contact_stiffness, learnable=False)
        return ComplementarityFree(stiffness, gamma=config.gamma, facets=config.facets).to(DTYPE)
    if name == "qp":
        return AnitescuQP(facets=config.facets, settings=config.qp_settings)
    raise ValueError(f"name must be 'cf' or 'qp', got {name!r}")


@dataclass
class Rollout:
    """One trajectory and what was measured along it (per-step lists have ``steps`` entries).

    Attributes:
        q: ``(steps + 1, nq)`` configurations.
        detect_s, driver_s, other_s: seconds of detection and of each model's prediction.
        linear_diff, angular_diff: ``max |v_driver − v_other|`` over the linear velocities
            (cubes and bar) [m/s] and the cubes' angular velocities [rad/s].
        active: number of active contacts.
        phi_ground, phi_side: the smallest φ [m] of the active contacts with a vertical normal
            (cube–ground) and with a horizontal one (cube–cube, cube–bar); +inf when none.
    """

    q: torch.Tensor | None = None
    detect_s: list[float] = field(default_factory=list)
    driver_s: list[float] = field(default_factory=list)
    other_s: list[float] = field(default_factory=list)
    linear_diff: list[float] = field(default_factory=list)
    angular_diff: list[float] = field(default_factory=list)
    active: list[int] = field(default_factory=list)
    phi_ground: list[float] = field(default_factory=list)
    phi_side: list[float] = field(default_factory=list)


def _timed(model: ContactModel, scene: BoxPushingScene, contacts: Contacts):
    """``(v⁺, seconds)`` of one prediction: exactly the call ``model(Q, b, contacts, h)``."""
    start = time.perf_counter()
    v = model(scene.Q, scene.b, contacts, scene.config.h)
    return v, time.perf_counter() - start


def _smallest_phi(contacts: Contacts) -> tuple[float, float]:
    vertical = contacts.frame[:, 0, 2].abs() > 0.7  # normal ≈ ±z: a cube–ground contact

    def smallest(mask: torch.Tensor) -> float:
        selected = contacts.phi[mask & contacts.active]
        return float(selected.min()) if selected.numel() else math.inf

    return smallest(vertical), smallest(~vertical)


def rollout(
    scene: BoxPushingScene,
    driver: ContactModel,
    steps: int,
    other: ContactModel | None = None,
    progress: Callable[[], object] | None = None,
) -> Rollout:
    """Roll out ``steps`` steps driven by ``driver``: detect → v⁺ → q ⊕ h v⁺.

    When ``other`` is given it predicts from the same ``(Q, b, contacts)`` at every state,
    timed like ``driver``; it never changes the trajectory. Runs under
    ``torch.inference_mode()`` with value checks off (:func:`validate_args`), as a simulator
    calls a model in its loop. ``progress`` is called once per step.
    """
    h, layout = scene.config.h, scene.layout
    q = scene.q0
    trajectory = [q]
    out = Rollout()
    with torch.inference_mode(), validate_args(False):
        for _ in range(steps):
            start = time.perf_counter()
            contacts = scene.detector(q)
            out.detect_s.append(time.perf_counter() - start)
            v, seconds = _timed(driver, scene, contacts)
            out.driver_s.append(seconds)
            if other is not None:
                v_other, seconds = _timed(other, scene, contacts)
                out.other_s.append(seconds)
                difference = (v - v_other).abs()
                out.linear_diff.append(float(difference[scene.linear_v].max()))
                out.angular_diff.append(float(difference[scene.angular_v].max()))
            out.active.append(int(contacts.active.sum()))
            ground, side = _smallest_phi(contacts)
            out.phi_ground.append(ground)
            out.phi_side.append(side)
            q = integrate(q, v, h, layout)
            trajectory.append(q)
            if progress is not None:
                progress()
    out.q = torch.stack(trajectory)
    return out


def _median_ms(*runs: Sequence[float], warmup: int) -> float:
    """Median [ms] of the timings of several rollouts, each without its first ``warmup``."""
    timed = [t for run_ in runs for t in (run_[warmup:] or run_)]
    return 1e3 * statistics.median(timed)


def _angle_deg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle [deg] between unit quaternions ``(..., 4)``: θ = arccos(2⟨a, b⟩² − 1)."""
    dot = (a * b).sum(-1)
    return torch.rad2deg(torch.arccos((2 * dot**2 - 1).clamp(-1.0, 1.0)))


def run(config: BoxPushingConfig, progress: bool = True) -> dict:
    """Both rollouts for one cube count; the measured figures as a JSON-ready dict.

    Timing (``cf_ms_median``, ``qp_ms_median``): the median over both rollouts' states, each
    after ``config.warmup`` steps, of one call ``model(Q, b, contacts, h)`` (see
    :data:`TIMED_REGION`); CF and QP predict from the same inputs at every state.
    ``trajectories`` holds the cube x positions [m], ``(steps + 1, N)`` lists, of both rollouts.
    """
    scene = build_scene(config)
    cf, qp = contact_model("cf", config), contact_model("qp", config)
    with tqdm(
        total=2 * config.steps, desc=f"N={config.cubes}", disable=not progress, leave=False
    ) as bar:
        by_cf = rollout(scene, cf, config.steps, other=qp, progress=bar.update)
        by_qp = rollout(scene, qp, config.steps, other=cf, progress=bar.update)
    warmup = config.warmup
    cf_ms = _median_ms(by_cf.driver_s, by_qp.other_s, warmup=warmup)
    qp_ms = _median_ms(by_cf.other_s, by_qp.driver_s, warmup=warmup)
    final_cf, final_qp = by_cf.q[-1, scene.cube_q], by_qp.q[-1, scene.cube_q]  # (N, 7)
    x0 = scene.q0[scene.cube_q[:, 0]]

    def height_error(r: Rollout) -> float:  # max |z − edge/2| of any cube [m]
        return float((r.q[:, scene.cube_q[:, 2]] - config.edge / 2).abs().max())

    return {
        "cubes": config.cubes,
        "cf_ms_median": cf_ms,
        "qp_ms_median": qp_ms,
        "speedup": qp_ms / cf_ms,
        "detect_ms_median": _median_ms(by_cf.detect_s, by_qp.detect_s, warmup=warmup),
        "steps": config.steps,
        "timed_predictions": 2 * max(config.steps - warmup, 0) or 2 * config.steps,
        "slots": config.slots,
        "active_contacts_max": max(by_cf.active + by_qp.active),
        "linear_v_diff_max_cf_states": max(by_cf.linear_diff),
        "linear_v_diff_median_cf_states": statistics.median(by_cf.linear_diff),
        "angular_v_diff_max_cf_states": max(by_cf.angular_diff),
        "linear_v_diff_max_qp_states": max(by_qp.linear_diff),
        "linear_v_diff_median_qp_states": statistics.median(by_qp.linear_diff),
        "angular_v_diff_max_qp_states": max(by_qp.angular_diff),
        "final_position_diff_max": float((final_cf[:, :3] - final_qp[:, :3]).norm(dim=-1).max()),
        "final_angle_diff_max_deg": float(_angle_deg(final_cf[:, 3:], final_qp[:, 3:]).max()),
        "cube_dx_mean_cf": float((final_cf[:, 0] - x0).mean()),
        "cube_dx_mean_qp": float((final_qp[:, 0] - x0).mean()),
        "bar_dx_cf": float(by_cf.q[-1, scene.bar_q] - scene.q0[scene.bar_q]),
        "bar_dx_qp": float(by_qp.q[-1, scene.bar_q] - scene.q0[scene.bar_q]),
        "ground_phi_min_cf": min(by_cf.phi_ground),
        "ground_phi_min_qp": min(by_qp.phi_ground),
        "side_phi_min_cf": min(by_cf.phi_side),
        "side_phi_min_qp": min(by_qp.phi_side),
        "height_error_max_cf": height_error(by_cf),
        "height_error_max_qp": height_error(by_qp),
        "trajectories": {
            "x_cf": by_cf.q[:, scene.cube_q[:, 0]].tolist(),
            "x_qp": by_qp.q[:, scene.cube_q[:, 0]].tolist(),
        },
    }


# --- reporting ------------------------------------------------------------------------------

HEADER = (
    "N",
    "contacts",
    "detect ms",
    "CF ms",
    "QP ms",
    "speedup",
    "max|dv| CF/QP states [m/s]",
    "final dp [mm]",
    "cube dx CF/QP [m]",
    "min phi ground/side [mm]",
)


def _cells(result: dict) -> list[str]:
    r = result
    return [
        f"{r['cubes']:d}",
        f"{r['active_contacts_max']:d}",
        f"{r['detect_ms_median']:.3f}",
        f"{r['cf_ms_median']:.3f}",
        f"{r['qp_ms_median']:.2f}",
        f"{r['speedup']:.1f}",
        f"{r['linear_v_diff_max_cf_states']:.3f} / {r['linear_v_diff_max_qp_states']:.3f}",
        f"{1e3 * r['final_position_diff_max']:.1f}",
        f"{r['cube_dx_mean_cf']:.3f} / {r['cube_dx_mean_qp']:.3f}",
        f"{1e3 * r['ground_phi_min_cf']:.2f} / {1e3 * r['side_phi_min_cf']:.1f}",
    ]


def format_table(results: Sequence[dict]) -> str:
    """A plain-text table of the main figures, one row per cube count."""
    rows = [list(HEADER)] + [_cells(r) for r in results]
    widths = [max(len(row[i]) for row in rows) for i in range(len(HEADER))]
    return "\n".join(
        "  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in rows
    )


def _summary(result: dict) -> dict:
    """The scalar figures (no trajectories); a φ of +inf (no such contact) becomes None."""
    return {
        k: None if isinstance(v, float) and math.isinf(v) else v
        for k, v in result.items()
        if k != "trajectories"
    }


def write_outputs(
    paths: dict[str, Path], results: Sequence[dict], config: BoxPushingConfig
) -> None:
    """Write the JSON, CSV and PNG (each atomically) to ``paths["json" | "csv" | "plot"]``.

    JSON: one cube count has its figures at the top level, a sweep ``{"runs": [...]}``; both
    add ``config`` (with ``cubes`` the list of cube counts), ``timed_region`` and
    ``torch_threads``. CSV: one row per cube count.
    """
    summaries = [_summary(r) for r in results]
    meta = {
        "config": {**asdict(config), "cubes": [r["cubes"] for r in results]},
        "timed_region": TIMED_REGION,
        "torch_threads": torch.get_num_threads(),
    }
    payload = {**summaries[0], **meta} if len(summaries) == 1 else {"runs": summaries, **meta}
    write_json(paths["json"], payload)
    write_csv(paths["csv"], summaries)
    plot(paths["plot"], results)


def plot(path: Path, results: Sequence[dict]) -> None:
    """Time per step against N (CF, QP, detection), and the cube x-trajectories of the
    largest N, CF (solid) against QP (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (timing, paths) = plt.subplots(1, 2, figsize=(11, 4.2))
    cubes = [r["cubes"] for r in results]
    for key, label, style in (
        ("cf_ms_median", "CF (closed form)", "o-"),
        ("qp_ms_median", "QP (OSQP)", "s-"),
        ("detect_ms_median", "contact detection", "^:"),
    ):
        timing.plot(cubes, [r[key] for r in results], style, label=label)
    timing.set(xlabel="cubes N", ylabel="median time per step [ms]", yscale="log", xticks=cubes)
    timing.set_title("one-step prediction, single thread")
    timing.grid(True, which="both", alpha=0.3)
    timing.legend()
    largest = max(results, key=lambda r: r["cubes"])
    x_cf = np.asarray(largest["trajectories"]["x_cf"])
    x_qp = np.asarray(largest["trajectories"]["x_qp"])
    colors = plt.cm.viridis(np.linspace(0, 0.9, x_cf.shape[1]))
    for i, color in enumerate(colors):
        paths.plot(x_cf[:, i], color=color, lw=1.2)
        paths.plot(x_qp[:, i], color=color, lw=1.2, ls="--")
    paths.plot([], [], "k-", label="CF")
    paths.plot([], [], "k--", label="QP")
    paths.set(xlabel="step", ylabel="cube x [m]", title=f"cube x, N = {largest['cubes']}")
    paths.grid(True, alpha=0.3)
    paths.legend()
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


# --- command line ---------------------------------------------------------------------------


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    defaults = BoxPushingConfig()
    parser = argparse.ArgumentParser(
        prog="box_pushing",
        description="Box pushing: CF vs QP (OSQP) predictions and time per step.",
    )
    parser.add_argument(
        "--cubes", type=_positive_int, help=f"cube count N (default: the sweep {SWEEP})"
    )
    parser.add_argument(
        "--steps", type=_positive_int, default=defaults.steps, help="steps per rollout (1000)"
    )
    parser.add_argument(
        "--mass", type=_positive_float, default=defaults.mass, help="cube mass [kg] (0.001)"
    )
    parser.add_argument(
        "--qp-eps",
        type=_positive_float,
        default=defaults.qp_settings["eps_abs"],
        help="OSQP eps_abs = eps_rel of the QP baseline (1e-6)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("results/box_pushing"),
        help="folder of the outputs not given a path (results/box_pushing)",
    )
    parser.add_argument("--json", type=Path, help="default OUT/box_pushing.json")
    parser.add_argument("--csv", type=Path, help="default OUT/box_pushing.csv")
    parser.add_argument("--plot", type=Path, help="default OUT/box_pushing.png")
    parser.add_argument("--threads", type=_positive_int, default=1, help="torch threads")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one cube count (``--cubes``) or the sweep, print the table, write JSON/CSV/PNG.

    Returns the exit status 0 (the ``torchcontact box-pushing`` command passes it on).
    """
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    counts = [args.cubes] if args.cubes is not None else list(SWEEP)
    qp_settings = {"eps_abs": args.qp_eps, "eps_rel": args.qp_eps}
    configs = [
        BoxPushingConfig(cubes=n, steps=args.steps, mass=args.mass, qp_settings=qp_settings)
        for n in counts
    ]
    results = []
    for config in tqdm(configs, desc="box pushing", disable=args.no_progress or len(configs) < 2):
        results.append(run(config, progress=not args.no_progress))
    print(format_table(results))
    print(f"timed: {TIMED_REGION}; medians over {results[0]['timed_predictions']} predictions")
    outputs = {
        "json": args.json or args.out / "box_pushing.json",
        "csv": args.csv or args.out / "box_pushing.csv",
        "plot": args.plot or args.out / "box_pushing.png",
    }
    write_outputs(outputs, results, configs[0])
    print("wrote " + ", ".join(str(p) for p in outputs.values()), file=sys.stderr)
    return 0


if __name__ == "__main__":
    main()
