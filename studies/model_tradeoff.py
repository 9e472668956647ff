"""Speed–accuracy trade-off of the contact models against MuJoCo.

For every (scene × setting) this measures the time per step of the model call and its one-step
and H-step (H = 10) prediction errors against MuJoCo, then draws the Pareto fronts and states,
from the rows, where the complementarity-free model (CF) dominates the QP model (faster and at
least as accurate) and where it does not. One evaluation::

    reference = scene's MuJoCo states           # recorded once per scene
    one_step  = model from every recorded state  # recorded contacts, (Q, b) of that state
    rollout   = H model steps from every stride-th state, contacts re-detected at predicted
                states, compared with MuJoCo's state H steps later
    timing    = median over repeats of model(Q, b, contacts, h)   (no detection, warmed up)

Scenes (:data:`SCENES`; each with its default K₀, damping ratio and step h):

* ``box_pushing``: the quasi-dynamic bar pushing a row of 10 cubes of
  :mod:`~torchcontact.sim.box_pushing` (h = 0.02 s, ε = 40, Kᵣ = 500, K₀ = 1). The
  MuJoCo reference (:func:`box_pushing_reference`) simulates the same MJCF at dt = h/10 with
  μ = 0.5 and drives the bar kinematically: before every substep its x is set to
  ``x₀ + u·t/h`` and its velocity to ``u/h`` (−5 cm/s), so the cubes meet a bar moving exactly
  as commanded; the recorded bar state is the commanded one.
* ``sliding_cube`` and ``falling_cube``: settings 2 and 3 of
  :mod:`~studies.full_dynamic` (full dynamic Q = M/h², h = 0.002 s, K₀ = 1,
  D = 0.3·K). The reference is MuJoCo stepping the same MJCF at h; the model's state is
  (q, v), so its rollouts carry their own velocities, and ``traj_*`` compares the model's
  whole trajectory from the initial state with MuJoCo's over the setting's horizon.
* ``trifinger`` and ``allegro``: transitions recorded from the paper's MPC acting in MuJoCo
  (:func:`torchcontact.learn.data.collect`, cube, MPC actions; collected once into
  ``DATA/{scene}_cube_mpc_steps{S}_seed0``; ``--quick``: random reaching actions),
  modelled by the MPC's quasi-dynamic system (h = 0.1 s, K₀ = 0.5, D = 0.1·K, γ = 100).

Settings (:func:`settings_grid`): CF with γ ∈ {exact max, 10, 100, 1000} × K ∈ K₀·
:data:`STIFFNESS_FACTORS` × damping {none, D = ratio·K} × facets {4, 8} × {float64, float32}
× batch {1, 1024} × the chosen devices; and the QP (OSQP, CPU float64, one problem at a time)
at ``eps_abs = eps_rel`` ∈ :data:`QP_TOLERANCES` × facets {4, 8}.

Errors: per object, position [mm], rotation angle [°] and ``500‖Δp‖² + 5e`` (e = 1 − ⟨q, q*⟩²;
the MPC's final-cost weights of the dataset for the hands), as in ``learn-k``
(:func:`torchcontact.learn.evaluate.pose_metrics`), averaged over states (one step), windows
(H steps) or steps (``traj_*``). Batch size changes the timing only: both batch sizes get the
errors of one evaluation, batched over all states. Timing (:data:`TIMED_REGION`): one
measurement per timing class (model, exact or softplus, damping or not, facets, dtype, batch,
device; QP: tolerance and facets), shared by the K and γ values of the class, since they are
constants of the same operations.

Outputs (``--out``, each written atomically): ``tradeoff.csv`` (one row per scene × setting:
the setting, ``call_ms``, ``sample_ms`` = per state, the errors, ``front_*`` flags),
``tradeoff.json`` (the rows, :func:`dominance` records, run metadata), ``pareto_{metric}.png``
(one panel per scene) and ``tradeoff.md`` (the dominance statements, generated from the rows).
Run ``python benchmarks/tradeoff.py --help``.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from studies import full_dynamic as fd
from studies import report
from torchcontact.cli.learn_k import collection_mpc
from torchcontact.contacts import Contacts
from torchcontact.integrate import JointLayout, integrate
from torchcontact.learn.data import Transitions, collect, load, system_header
from torchcontact.learn.evaluate import pose_metrics
from torchcontact.learn.fit import object_indices, system_terms
from torchcontact.learn.scenes import make_scene
from torchcontact.model import AnitescuQP, ComplementarityFree, ContactModel
from torchcontact.results import pareto_front
from torchcontact.sim import ContactDetector
from torchcontact.sim import box_pushing as bp
from torchcontact.sim.box_pushing import BoxPushingPlant
from torchcontact.stiffness import Constant, Relative
from torchcontact.systems import full_dynamic
from torchcontact.validation import validate_args

SCENES = ("box_pushing", "sliding_cube", "falling_cube", "trifinger", "allegro")
GAMMAS = (None, 10.0, 100.0, 1000.0)
"""Softplus sharpness γ of the CF settings; None is the exact ``max(·, 0)``."""
STIFFNESS_FACTORS = (0.1, 0.3, 1.0, 3.0, 10.0)
"""The K sweep, as multiples of each scene's K₀."""
QUICK_STIFFNESS_FACTORS = (1.0, 3.0)
FACETS = (4, 8)
DTYPES = ("float64", "float32")
BATCH = 1024
"""The large batch of the batched settings (the others call the model on one state)."""
QP_TOLERANCES = (1e-3, 1e-6)
"""OSQP ``eps_abs = eps_rel`` of the QP settings (1e-3 is OSQP's own default)."""
HORIZON = 10
POSE_WEIGHTS = (500.0, 5.0)
"""Position [1/m²] and orientation weights of the combined error where no dataset gives them."""

TIMED_REGION = (
    "the call model(Q, b, contacts, h) -> v+ under torch.inference_mode() with value checks "
    "off, after warm-up calls; not detection, not (Q, b), not integration; one torch thread"
)
METRICS = {"one_step": "one-step", f"h{HORIZON}": f"{HORIZON}-step", "traj": "whole-trajectory"}
"""Error groups of the Pareto fronts and dominance statements (``traj``: full-dynamic scenes)."""


# --- settings -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setting:
    """One model configuration.

    Attributes:
        model: ``"cf"`` or ``"qp"``.
        facets: friction-cone facets n_d.
        dtype: ``"float64"`` or ``"float32"`` (the QP is always float64).
        batch: states per model call (1 or the batched size).
        device: ``"cpu"`` or ``"cuda"`` (the QP is always CPU).
        gamma: CF softplus γ; None for the exact max.
        stiffness: CF K [N/m per row].
        damping: CF damping ratio r of D = r·K; None for no damping.
        tolerance: QP ``eps_abs = eps_rel``.
    """

    model: str
    facets: int
    dtype: str = "float64"
    batch: int = 1
    device: str = "cpu"
    gamma: float | None = None
    stiffness: float | None = None
    damping: float | None = None
    tolerance: float | None = None

    @property
    def label(self) -> str:
        if self.model == "qp":
            return f"QP eps={self.tolerance:g} nd={self.facets}"
        gamma = "exact" if self.gamma is None else f"γ={self.gamma:g}"
        damping = "D=0" if self.damping is None else f"D={self.damping:g}K"
        precision = {"float64": "f64", "float32": "f32"}[self.dtype]
        device = "" if self.device == "cpu" else f" {self.device}"
        return (
            f"CF {gamma} K={self.stiffness:g} {damping} nd={self.facets} {precision} "
            f"b{self.batch}{device}"
        )

    @property
    def accuracy_key(self) -> Setting:
        """The fields that can change the predictions (not the batch size)."""
        return replace(self, batch=1)

    @property
    def timing_key(self) -> tuple:
        """The fields that can change the time of a call (not K or the γ value)."""
        if self.model == "qp":
            return ("qp", self.facets, self.tolerance)
        return (
            "cf",
            self.gamma is None,
            self.damping is None,
            self.facets,
            self.dtype,
            self.batch,
            self.device,
        )


def settings_grid(
    stiffness: float,
    damping: float,
    quick: bool = False,
    devices: Sequence[str] = ("cpu",),
    batch: int = BATCH,
) -> list[Setting]:
    """Every CF and QP setting of one scene (see the module docstring).

    Args:
        stiffness: the scene's K₀ [N/m]; the sweep is K₀·:data:`STIFFNESS_FACTORS`
            (:data:`QUICK_STIFFNESS_FACTORS` when ``quick``).
        damping: the scene's damping ratio r (D = r·K) of the damped settings.
        devices: devices of the CF settings.
        batch: the large batch size.
    """
    factors = QUICK_STIFFNESS_FACTORS if quick else STIFFNESS_FACTORS
    cf = [
        Setting("cf", facets, dtype, size, device, gamma, stiffness * factor, ratio)
        for device in devices
        for size in (1, batch)
        for dtype in DTYPES
        for facets in FACETS
        for ratio in (None, damping)
        for gamma in GAMMAS
        for factor in factors
    ]
    qp = [Setting("qp", facets, tolerance=tol) for facets in FACETS for tol in QP_TOLERANCES]
    return cf + qp


def build_model(setting: Setting) -> ContactModel:
    """The contact model of ``setting``, in its dtype and on its device."""
    if setting.model == "qp":
        tol = setting.tolerance
        return AnitescuQP(setting.facets, settings={"eps_abs": tol, "eps_rel": tol})
    damping = None if setting.damping is None else Relative(setting.damping, learnable=False)
    model = ComplementarityFree(
        Constant(setting.stiffness, learnable=False), damping, setting.gamma, setting.facets
    )
    return model.to(dtype=getattr(torch, setting.dtype), device=setting.device)


# --- scenes ---------------------------------------------------------------------------------


@dataclass
class Inputs:
    """One model call's inputs: ``Q (nv,)`` shared or ``(R, nv, nv)``, ``b (R, nv)`` and
    contacts of batch ``(R,)``."""

    Q: torch.Tensor
    b: torch.Tensor
    contacts: Contacts

    def select(self, index: torch.Tensor) -> Inputs:
        """Rows ``index`` (a long tensor of any shape, or a 0-d index for one state)."""
        Q = self.Q if self.Q.dim() < self.b.dim() else self.Q[index]
        return Inputs(Q, self.b[index], self.contacts[index])

    def to(self, dtype: torch.dtype, device: str | torch.device) -> Inputs:
        kw = {"dtype": dtype, "device": device}
        return Inputs(self.Q.to(**kw), self.b.to(**kw), self.contacts.to(**kw))


@dataclass
class State:
    """Model states of R rollouts: ``q (R, nq)`` and, for full dynamics, ``v (R, nv)``."""

    q: torch.Tensor
    v: torch.Tensor | None = None

    def to(self, dtype: torch.dtype, device: str | torch.device) -> State:
        kw = {"dtype": dtype, "device": device}
        return State(self.q.to(**kw), None if self.v is None else self.v.to(**kw))


class Scene:
    """Recorded MuJoCo states of one scene and the model step around them.

    Subclasses give ``name``, ``title``, ``h`` [s], ``layout``, ``stiffness`` (K₀),
    ``damping`` (ratio r), ``weights``, the recorded ``q (N, nq)`` and ``q_next (N, nq)``,
    and implement :meth:`initial`, :meth:`inputs`, :meth:`advance` and :meth:`windows`.
    """

    name: str
    title: str
    h: float
    layout: JointLayout
    stiffness: float
    damping: float
    weights: tuple[float, float]
    q: torch.Tensor
    q_next: torch.Tensor
    stride: int
    _recorded: Inputs | None = None

    def initial(self, rows: torch.Tensor) -> State:
        """MuJoCo's states at ``rows (R,)`` (float64)."""
        raise NotImplementedError

    def inputs(self, state: State, rows: torch.Tensor) -> Inputs:
        """``(Q, b, contacts)`` at ``state`` (contacts detected there) with the recorded
        controls of ``rows (R,)``; float64 on the CPU."""
        raise NotImplementedError

    def advance(self, state: State, v: torch.Tensor) -> State:
        """The state after one step with next velocity ``v (R, nv)``."""
        raise NotImplementedError

    def windows(self, horizon: int) -> torch.Tensor:
        """``(W, horizon)`` rows of consecutive steps, one window every ``stride`` steps."""
        raise NotImplementedError

    def trajectory(self) -> torch.Tensor | None:
        """``(1, T)`` the rows of the whole reference trajectory for ``traj_*``, or None."""
        return None

    @property
    def object_q(self) -> torch.Tensor:
        """``(n_obj, 7)`` indices of the objects' poses in q."""
        return object_indices(list(self.layout.joints))[0]

    def recorded(self) -> Inputs:
        """Inputs at every recorded state (computed once)."""
        if self._recorded is None:
            rows = torch.arange(len(self.q))
            self._recorded = self.inputs(self.initial(rows), rows)
        return self._recorded

    def timing_rows(self, count: int = 20) -> torch.Tensor:
        """Up to ``count`` recorded rows spread over the states with a contact (all when none)."""
        active = self.recorded().contacts.active.any(-1)
        rows = (
            torch.nonzero(active).squeeze(-1) if bool(active.any()) else torch.arange(len(active))
        )
        pick = torch.linspace(0, len(rows) - 1, min(count, len(rows))).round().long()
        return rows[pick]


class QuasiDynamicScene(Scene):
    """Recorded transitions ``(q, u, contacts, q_next)`` under a quasi-dynamic system.

    Args:
        name, title: the scene's key and one line for tables.
        transitions: the MuJoCo transitions; ``meta`` holds ``joints``, ``h``, ``system``
            (``Q``, ``b0``, ``B``) and ``pose_weights``.
        detector: contacts at predicted states.
        stiffness: K₀ [N/m]; damping: the ratio r of its damped settings.
        stride: steps between the starts of H-step windows.
    """

    def __init__(
        self,
        name: str,
        title: str,
        transitions: Transitions,
        detector: ContactDetector,
        stiffness: float,
        damping: float,
        stride: int,
    ):
        self.name, self.title, self.transitions, self.detector = name, title, transitions, detector
        meta = transitions.meta
        self.h, self.layout = float(meta["h"]), JointLayout(meta["joints"])
        self.stiffness, self.damping, self.stride = stiffness, damping, stride
        self.weights = tuple(meta["pose_weights"])
        self.q, self.q_next = transitions.q, transitions.q_next

    def initial(self, rows):
        return State(self.q[rows])

    def inputs(self, state, rows):
        Q, b = system_terms(self.transitions.meta, self.transitions.u[rows].double())
        q = state.q.detach().to("cpu", torch.float64)
        return Inputs(Q, b, self.detector(q))

    def recorded(self):
        """Inputs at every recorded state, with the recorded contacts."""
        if self._recorded is None:
            Q, b = system_terms(self.transitions.meta, self.transitions.u.double())
            self._recorded = Inputs(Q, b, self.transitions.contacts.to(torch.float64))
        return self._recorded

    def advance(self, state, v):
        return State(integrate(state.q, v, self.h, self.layout))

    def windows(self, horizon):
        return self.transitions.windows(horizon, self.stride)


class FullDynamicScene(Scene):
    """A full-dynamic setting of :mod:`~studies.full_dynamic` and MuJoCo's
    trajectory of it (``Q = M(q)/h²``, ``b = M v/h + τ − bias``, both from MuJoCo).

    Args:
        name: the scene's key; setting: the full-dynamic setting (its ``steps`` the horizon).
        stride: steps between the starts of H-step windows.
    """

    def __init__(self, name: str, setting: fd.Setting, stride: int):
        self.name, self.title, self.stride = name, setting.title, stride
        self.scene = fd.build_scene(setting)
        self.h, self.layout = setting.h, self.scene.layout
        self.stiffness = setting.stiffness[0]
        self.damping = setting.damping / self.stiffness
        self.weights = POSE_WEIGHTS
        ref = fd.mujoco_rollout(
            self.scene, setting.qpos0, setting.qvel0, setting.force, setting.steps
        )
        qpos, qvel = torch.from_numpy(ref.qpos), torch.from_numpy(ref.qvel)
        self.q, self.q_next, self.v = qpos[:-1], qpos[1:], qvel[:-1]
        self.force = torch.tensor(setting.force, dtype=torch.float64)

    def initial(self, rows):
        return State(self.q[rows], self.v[rows])

    def inputs(self, state, rows):
        q = state.q.detach().to("cpu", torch.float64)
        v = state.v.detach().to("cpu", torch.float64)
        terms = [fd.dynamics(self.scene, qi, vi) for qi, vi in zip(q, v, strict=True)]
        M, bias = (torch.stack(x) for x in zip(*terms, strict=True))
        Q, b = full_dynamic(M, v, self.force - bias, self.h)
        return Inputs(Q, b, self.scene.detector(q))

    def advance(self, state, v):
        return State(integrate(state.q, v, self.h, self.layout), v)

    def windows(self, horizon):
        starts = torch.arange(0, len(self.q) - horizon + 1, self.stride)
        return starts[:, None] + torch.arange(horizon)

    def trajectory(self):
        return torch.arange(len(self.q))[None]


@dataclass(frozen=True)
class Size:
    """How much of each scene a run uses.

    Attributes:
        cubes, box_steps: box-pushing cubes and reference steps.
        sliding_steps, falling_steps: horizons of the full-dynamic settings.
        trajectories, hand_steps: recorded hand trajectories and their steps.
        actions: the hands' action source (:data:`torchcontact.learn.policies.ACTIONS`).
        stride, full_stride: window stride of the quasi-dynamic and full-dynamic scenes.
        repeats, batch_repeats: timed calls at batch 1 and at the large batch.
    """

    cubes: int = 10
    box_steps: int = 160
    sliding_steps: int = 500
    falling_steps: int = 750
    trajectories: int = 8
    hand_steps: int = 50
    actions: str = "mpc"
    stride: int = 5
    full_stride: int = 10
    repeats: int = 40
    batch_repeats: int = 5


QUICK = Size(3, 30, 40, 100, 2, 12, "random", 5, 10, 10, 2)
"""``--quick``: 3 cubes, short horizons, 2 random-action hand trajectories of 12 steps."""


def box_pushing_reference(config: bp.BoxPushingConfig, steps: int, substeps: int = 10):
    """MuJoCo's box pushing: ``(steps + 1, nq)`` float64 states, one per model step, the bar
    commanded ``config.push`` every step (:class:`BoxPushingPlant`)."""
    plant = BoxPushingPlant(config, substeps)
    plant.reset(plant.initial_state)
    states = [plant.state()]
    for _ in range(steps):
        states.append(plant.step([config.push]))
    return np.stack(states)


def box_pushing_scene(cubes: int, steps: int, stride: int) -> QuasiDynamicScene:
    """The box-pushing scene of ``cubes`` cubes and its MuJoCo reference of ``steps`` steps,
    as transitions of one trajectory under the experiment's quasi-dynamic system."""
    config = bp.BoxPushingConfig(cubes=cubes)
    scene = bp.build_scene(config)
    states = torch.from_numpy(box_pushing_reference(config, steps))
    meta = {
        "h": config.h,
        "joints": list(scene.layout.joints),
        "pose_weights": list(POSE_WEIGHTS),
        "system": system_header(scene.system),
    }
    q = states[:-1]
    transitions = Transitions(
        q=q,
        u=torch.full((steps, 1), config.push, dtype=torch.float64),
        q_next=states[1:],
        contacts=scene.detector(q),
        trajectory=torch.zeros(steps, dtype=torch.long),
        step=torch.arange(steps),
        meta=meta,
    )
    title = f"box pushing, {cubes} cubes (quasi-dynamic, h = {config.h} s)"
    return QuasiDynamicScene(
        "box_pushing", title, transitions, scene.detector, config.contact_stiffness, 0.1, stride
    )


def hand_scene(name: str, data: Path, size: Size, progress: bool = True) -> QuasiDynamicScene:
    """TriFinger or Allegro transitions of the cube task (``size.actions``: the paper's MPC,
    or random reaching) in ``data/{name}_cube_{actions}_steps{S}_seed0`` (the ``learn-k``
    naming; collected there if missing) and the scene's detector."""
    directory = data / f"{name}_cube_{size.actions}_steps{size.hand_steps}_seed0"
    collect(
        directory,
        name,
        "cube",
        trajectories=size.trajectories,
        steps=size.hand_steps,
        actions=size.actions,
        progress=progress,
        planner=functools.partial(collection_mpc, compile=False),
    )
    transitions = load(directory, size.trajectories)
    meta = transitions.meta
    detector = make_scene(name, "cube", meta["task"]).plant.detector
    title = f"{name} cube, {size.actions} actions (quasi-dynamic, h = {meta['h']} s)"
    stiffness = meta["paper_stiffness"]
    return QuasiDynamicScene(name, title, transitions, detector, stiffness, 0.1, size.stride)


def build_scene(name: str, size: Size, data: Path, progress: bool = True) -> Scene:
    """Scene ``name`` (one of :data:`SCENES`) at ``size``; hand data cached under ``data``."""
    if name == "box_pushing":
        return box_pushing_scene(size.cubes, size.box_steps, size.stride)
    if name in ("sliding_cube", "falling_cube"):
        setting = fd.sliding_cube_setting() if name == "sliding_cube" else fd.falling_cube_setting()
        steps = size.sliding_steps if name == "sliding_cube" else size.falling_steps
        return FullDynamicScene(name, replace(setting, steps=steps), size.full_stride)
    if name in ("trifinger", "allegro"):
        return hand_scene(name, data, size, progress)
    raise ValueError(f"name must be one of {SCENES}, got {name!r}")


# --- errors and timing ----------------------------------------------------------------------


def _predict(model: ContactModel, inputs: Inputs, h: float) -> torch.Tensor:
    return model(inputs.Q, inputs.b, inputs.contacts, h)


def rollout_poses(scene: Scene, model: ContactModel, windows: torch.Tensor, dtype, device):
    """Object poses ``(W, T, n_obj, 7)`` after each of T model steps from the recorded states
    at ``windows[:, 0]``, under the recorded controls of ``windows (W, T)``; contacts and
    ``(Q, b)`` at the predicted states, except the first step's (recorded)."""
    state = scene.initial(windows[:, 0]).to(dtype, device)
    poses = []
    for t in range(windows.shape[1]):
        if t == 0:
            inputs = scene.recorded().select(windows[:, 0])
        else:
            inputs = scene.inputs(state, windows[:, t])
        v = _predict(model, inputs.to(dtype, device), scene.h)
        state = scene.advance(state, v)
        poses.append(state.q[:, scene.object_q.to(device)])
    return torch.stack(poses, 1).cpu()


def errors(scene: Scene, model: ContactModel, setting: Setting, horizon: int = HORIZON) -> dict:
    """One-step, H-step and (full-dynamic scenes) whole-trajectory errors of ``model``.

    Keys ``{one_step, h10, traj}_{pos_mm, angle_deg, combined}`` (means of
    :func:`~torchcontact.learn.evaluate.pose_metrics`), ``states`` and ``windows``; ``traj_*``
    is None without a reference trajectory. A diverged prediction gives NaN.
    """
    dtype, device = getattr(torch, setting.dtype), setting.device
    object_q = scene.object_q
    rows = torch.arange(len(scene.q))[:, None]
    windows = scene.windows(horizon)
    groups = {"one_step": rows, f"h{horizon}": windows, "traj": scene.trajectory()}
    out = {"states": len(rows), "windows": len(windows)}
    with torch.inference_mode(), validate_args(False):
        for group, index in groups.items():
            keys = [f"{group}_{k}" for k in ("pos_mm", "angle_deg", "combined")]
            if index is None:
                out.update(dict.fromkeys(keys))
                continue
            poses = rollout_poses(scene, model, index, dtype, device)
            target = scene.q_next[index][..., object_q]
            if group != "traj":
                poses, target = poses[:, -1], target[:, -1]
            metrics = pose_metrics(poses, target, scene.weights)
            out.update({key: metrics[key.removeprefix(f"{group}_")] for key in keys})
    return out


def _synchronize(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def time_call(model: ContactModel, calls: Sequence[Inputs], h: float, repeats: int, device: str):
    """Seconds of ``repeats`` calls ``model(Q, b, contacts, h)``, cycling through ``calls``,
    after one warm-up call on each."""
    seconds = []
    with torch.inference_mode(), validate_args(False):
        for inputs in calls:
            _predict(model, inputs, h)
        _synchronize(device)
        for i in range(repeats):
            start = time.perf_counter()
            _predict(model, calls[i % len(calls)], h)
            _synchronize(device)
            seconds.append(time.perf_counter() - start)
    return seconds


def timing(scene: Scene, model: ContactModel, setting: Setting, size: Size) -> dict:
    """``call_ms`` (median per call), ``sample_ms`` (per state) and ``repeats`` of ``model``:
    at batch 1 over :meth:`Scene.timing_rows` one at a time, at a larger batch on those rows
    repeated to the batch size."""
    dtype = getattr(torch, setting.dtype)
    rows = scene.timing_rows()
    recorded = scene.recorded()
    if setting.batch == 1:
        calls, repeats = [recorded.select(r).to(dtype, setting.device) for r in rows], size.repeats
    else:
        index = rows[torch.arange(setting.batch) % len(rows)]
        calls, repeats = [recorded.select(index).to(dtype, setting.device)], size.batch_repeats
    seconds = statistics.median(time_call(model, calls, scene.h, repeats, setting.device))
    return {
        "call_ms": 1e3 * seconds,
        "sample_ms": 1e3 * seconds / setting.batch,
        "repeats": repeats,
    }


def evaluate_scene(scene: Scene, settings: Sequence[Setting], size: Size, progress=True) -> list:
    """One CSV row per setting: the scene, the setting, its timing and its errors."""
    accuracy, timed, rows = {}, {}, []
    for setting in tqdm(settings, desc=scene.name, disable=not progress, leave=False):
        model = build_model(setting)
        if setting.accuracy_key not in accuracy:
            accuracy[setting.accuracy_key] = errors(scene, model, setting)
        if setting.timing_key not in timed:
            timed[setting.timing_key] = timing(scene, model, setting, size)
        fields = asdict(setting)
        rows.append(
            {
                "scene": scene.name,
                "label": setting.label,
                **fields,
                **timed[setting.timing_key],
                **accuracy[setting.accuracy_key],
            }
        )
    return rows


# --- Pareto fronts and dominance ------------------------------------------------------------


def _error(row: dict, metric: str) -> float:
    value = row.get(f"{metric}_combined")
    return math.nan if value is None else float(value)


def _brief(row: dict | None, metric: str) -> tuple[str, float, float] | None:
    """``(label, ms per state, combined error)`` of a row, or None."""
    return None if row is None else (row["label"], row["sample_ms"], _error(row, metric))


def _most_accurate(rows: Sequence[dict], metric: str) -> dict | None:
    finite = [r for r in rows if math.isfinite(_error(r, metric))]
    return min(finite, key=lambda r: _error(r, metric), default=None)


def _dominates(row: dict, qp: dict, metric: str) -> bool:
    """Strictly faster per state and a combined error no larger."""
    return row["sample_ms"] < qp["sample_ms"] and _error(row, metric) <= _error(qp, metric)


def dominance(rows: Sequence[dict], metric: str) -> list[dict]:
    """For each scene and QP row with a finite ``metric`` error: which CF rows dominate it.

    Returns one record per QP row: ``scene``, ``metric``, ``qp`` (its label), ``qp_ms`` (per
    state), ``qp_error`` (combined), ``cf_b1`` (number of batch-1 CF rows), ``dominated_b1``
    and ``dominated_any`` (CF rows dominating it at batch 1 and at any batch size),
    ``best_b1`` (the most accurate dominating batch-1 row), ``most_accurate_faster_b1`` (the
    most accurate faster batch-1 row) and ``fastest_as_accurate_b1`` (the fastest batch-1 row
    at least as accurate): each ``(label, ms, error)`` or None.
    """
    records = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        cf = [r for r in rows if r["scene"] == scene and r["model"] == "cf"]
        single = [r for r in cf if r["batch"] == 1]
        qps = [r for r in rows if r["scene"] == scene and r["model"] == "qp"]
        for qp in (r for r in qps if math.isfinite(_error(r, metric))):
            faster = [r for r in single if r["sample_ms"] < qp["sample_ms"]]
            accurate = [r for r in single if _error(r, metric) <= _error(qp, metric)]
            fastest = min(accurate, key=lambda r: r["sample_ms"], default=None)
            records.append(
                {
                    "scene": scene,
                    "metric": metric,
                    "qp": qp["label"],
                    "qp_ms": qp["sample_ms"],
                    "qp_error": _error(qp, metric),
                    "cf_b1": len(single),
                    "dominated_b1": sum(_dominates(r, qp, metric) for r in single),
                    "dominated_any": sum(_dominates(r, qp, metric) for r in cf),
                    "best_b1": _brief(
                        _most_accurate([r for r in faster if r in accurate], metric), metric
                    ),
                    "most_accurate_faster_b1": _brief(_most_accurate(faster, metric), metric),
                    "fastest_as_accurate_b1": _brief(fastest, metric),
                }
            )
    return records


def _statement(record: dict) -> str:
    """One sentence on one QP setting, from a :func:`dominance` record."""
    head = f"{record['qp']} ({record['qp_ms']:.3g} ms, error {record['qp_error']:.3g}): "
    if record["dominated_b1"]:
        label, ms, error = record["best_b1"]
        return head + (
            f"CF dominates it: {record['dominated_b1']} of {record['cf_b1']} batch-1 CF "
            f"settings are faster and at least as accurate (most accurate: {label}, "
            f"{ms:.3g} ms, error {error:.3g}); {record['dominated_any']} at any batch size."
        )
    parts = [f"CF does not dominate it at batch 1 (0 of {record['cf_b1']})"]
    if record["most_accurate_faster_b1"] is not None:
        label, ms, error = record["most_accurate_faster_b1"]
        parts.append(f"the most accurate faster CF is {label} with error {error:.3g}")
    if record["fastest_as_accurate_b1"] is not None:
        label, ms, error = record["fastest_as_accurate_b1"]
        parts.append(f"the fastest CF at least as accurate is {label} at {ms:.3g} ms")
    else:
        parts.append("no batch-1 CF setting is as accurate")
    parts.append(f"{record['dominated_any']} CF settings dominate it per state at any batch size")
    return head + "; ".join(parts) + "."


def summary_markdown(rows: Sequence[dict], meta: dict) -> str:
    """``tradeoff.md``: per scene and error metric, which QP settings CF dominates and which
    not, every sentence computed from ``rows`` (:func:`dominance`)."""
    lines = [
        "# Speed–accuracy trade-off: complementarity-free (CF) vs QP (OSQP)",
        "",
        f"Generated by `{meta['command']}`. Time: {TIMED_REGION}; per state (a batched "
        "call's time divided by its batch size). Error: the combined 500‖Δp‖² + 5e (hands: "
        f"the dataset's MPC weights) against MuJoCo. Load average {meta['load_average'][0]:.2f} → "
        f"{meta['load_average'][1]:.2f} on {meta['cpus']} CPUs during the run.",
        "A CF setting dominates a QP setting when it is faster per state and at least as accurate.",
    ]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        title = meta["scenes"].get(scene, {}).get("title", scene)
        lines += ["", f"## {scene}: {title}"]
        for metric, name in METRICS.items():
            records = [d for d in dominance(rows, metric) if d["scene"] == scene]
            if not records:
                continue
            dominated = sum(d["dominated_b1"] > 0 for d in records)
            lines += [
                "",
                f"**{name} error**: CF dominates {dominated} of {len(records)} QP settings at "
                "batch 1.",
                "",
            ]
            lines += [f"- {_statement(d)}" for d in records]
    return "\n".join(lines) + "\n"


# --- reporting ------------------------------------------------------------------------------


def mark_fronts(rows: list[dict]) -> None:
    """Add ``front_{metric}`` (bool) for each of :data:`METRICS`: on the scene's Pareto front
    of time per state against that combined error."""
    for scene in dict.fromkeys(r["scene"] for r in rows):
        group = [r for r in rows if r["scene"] == scene]
        for metric in METRICS:
            front = set(pareto_front([(r["sample_ms"], _error(r, metric)) for r in group]))
            for i, row in enumerate(group):
                row[f"front_{metric}"] = i in front


COLUMNS = (
    ("label", "setting", "{}"),
    ("call_ms", "ms/call", "{:.3f}"),
    ("sample_ms", "ms/state", "{:.4f}"),
    ("one_step_pos_mm", "1-step mm", "{:.3f}"),
    ("one_step_angle_deg", "1-step °", "{:.3f}"),
    ("one_step_combined", "1-step comb", "{:.3g}"),
    ("h10_pos_mm", "10-step mm", "{:.3f}"),
    ("h10_angle_deg", "10-step °", "{:.3f}"),
    ("h10_combined", "10-step comb", "{:.3g}"),
    ("traj_pos_mm", "traj mm", "{:.2f}"),
    ("traj_combined", "traj comb", "{:.3g}"),
)


def format_table(rows: Sequence[dict]) -> str:
    """Per scene: the QP rows and the CF rows on either Pareto front, by time per state."""
    blocks = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        shown = [
            r
            for r in rows
            if r["scene"] == scene and (r["model"] == "qp" or any(r[f"front_{m}"] for m in METRICS))
        ]
        shown.sort(key=lambda r: r["sample_ms"])
        cells = [
            ["-" if r[key] is None else fmt.format(r[key]) for key, _, fmt in COLUMNS]
            for r in shown
        ]
        text = report.format_table([title for _, title, _ in COLUMNS], cells, left=1)
        total = sum(r["scene"] == scene for r in rows)
        blocks.append(f"{scene}: QP and Pareto-front settings ({len(shown)} of {total})\n{text}")
    return "\n\n".join(blocks)


COLORS = {None: "tab:blue", 10.0: "tab:orange", 100.0: "tab:green", 1000.0: "tab:purple"}
MARKERS = {("float64", True): "o", ("float32", True): "s", ("float64", False): "^"}
MARKERS[("float32", False)] = "v"
"""CF markers by (dtype, batch 1 or not)."""


def _plot_scene(ax, group: Sequence[dict], metric: str) -> None:
    """One panel: the rows of a scene (CF filled on the CPU, hollow on CUDA), QP as red
    crosses, the Pareto front as a step line."""
    styles = {}
    for r in group:
        if r["model"] == "cf":
            style = (r["gamma"], r["dtype"], r["batch"] == 1, r["device"])
            styles.setdefault(style, []).append(r)
    for (gamma, dtype, single, device), members in styles.items():
        color = COLORS[gamma]
        ax.scatter(
            [r["sample_ms"] for r in members],
            [_error(r, metric) for r in members],
            marker=MARKERS[(dtype, single)],
            s=18,
            facecolors=color if device == "cpu" else "none",
            edgecolors=color,
            alpha=0.7,
        )
    qp = [r for r in group if r["model"] == "qp"]
    times, errors_ = [r["sample_ms"] for r in qp], [_error(r, metric) for r in qp]
    ax.scatter(times, errors_, marker="X", s=90, c="red", zorder=3)
    front = [group[i] for i in pareto_front([(r["sample_ms"], _error(r, metric)) for r in group])]
    times, errors_ = [r["sample_ms"] for r in front], [_error(r, metric) for r in front]
    ax.step(times, errors_, where="post", color="k", lw=1)
    ax.set(xscale="log", yscale="log", xlabel="time per state [ms]")
    ax.grid(True, which="both", alpha=0.3)


def _legend(batch: int) -> list:
    """Legend entries of the Pareto plots: γ colours, dtype and batch markers, QP, front."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], ls="", marker="o", color=c, label="exact" if g is None else f"γ={g:g}")
        for g, c in COLORS.items()
    ]
    handles += [
        Line2D([], [], ls="", marker=m, color="gray", label=f"{d}, batch {1 if one else batch}")
        for (d, one), m in MARKERS.items()
    ]
    return handles + [
        Line2D([], [], ls="", marker="X", color="red", label="QP (OSQP)"),
        Line2D([], [], color="k", label="Pareto front"),
    ]


def plot_pareto(path: Path, rows: Sequence[dict], metric: str) -> None:
    """Combined error against time per state, log axes, one panel per scene (three per
    line): CF coloured by γ, marker by dtype and batch size, QP as red crosses, the Pareto
    front as a black step line."""
    scenes = list(dict.fromkeys(r["scene"] for r in rows if math.isfinite(_error(r, metric))))
    columns = min(3, len(scenes))
    lines = math.ceil(len(scenes) / columns)
    size = (4.6 * columns, 3.8 * lines)
    fig, axes = report.figure(lines, columns, size=size, squeeze=False)
    for ax, scene in zip(axes.flat, scenes, strict=False):
        group = [r for r in rows if r["scene"] == scene and math.isfinite(_error(r, metric))]
        _plot_scene(ax, group, metric)
        ax.set_title(scene)
        ax.set_ylabel(f"{METRICS[metric]} error (combined)")
    for ax in axes.flat[len(scenes) :]:
        ax.set_axis_off()
    handles = _legend(max(r["batch"] for r in rows))
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8)
    fig.tight_layout(rect=(0, 0.1 / lines, 1, 1))
    report.save_figure(fig, path)


def write_outputs(out: Path, rows: list[dict], meta: dict) -> list[Path]:
    """``tradeoff.csv``, ``tradeoff.json``, ``pareto_{metric}.png`` for each of
    :data:`METRICS` with data and ``tradeoff.md`` in ``out``, each written atomically."""
    records = {metric: dominance(rows, metric) for metric in METRICS}
    payload = {**meta, "timed_region": TIMED_REGION, "rows": rows, "dominance": records}
    paths = [
        report.write_csv(out / "tradeoff.csv", rows),
        report.write_json(out / "tradeoff.json", payload),
    ]
    for metric in METRICS:
        if any(math.isfinite(_error(r, metric)) for r in rows):
            path = out / f"pareto_{metric}.png"
            plot_pareto(path, rows, metric)
            paths.append(path)
    paths.append(report.write_text(out / "tradeoff.md", summary_markdown(rows, meta)))
    return paths


# --- command line ---------------------------------------------------------------------------


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The options: ``--quick``, ``--scenes``, ``--device``, ``--batch``, the outputs; adds
    ``command`` (the command line, for the report)."""
    parser = report.parser(
        "python benchmarks/tradeoff.py",
        "Speed-accuracy trade-off of the contact models (CF settings and the QP) against "
        "MuJoCo: time per step, one-step and 10-step errors, Pareto plots.",
        "results/tradeoff",
    )
    parser.add_argument("--quick", action="store_true", help="small scenes and grid (< 1 min)")
    parser.add_argument(
        "--scenes", nargs="+", default=list(SCENES), metavar="SCENE", help=f"of {SCENES}"
    )
    parser.add_argument(
        "--device",
        nargs="+",
        default=["cpu"],
        metavar="DEVICE",
        help="devices of the CF settings: cpu, cuda or both",
    )
    parser.add_argument("--batch", type=int, default=BATCH, help=f"the large batch ({BATCH})")
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="hand datasets (default OUT/data; collected if missing)",
    )
    args = parser.parse_args(argv)
    unknown = [s for s in args.scenes if s not in SCENES]
    if unknown:
        parser.error(f"--scenes: unknown {unknown}; choose from {', '.join(SCENES)}")
    bad = [d for d in args.device if d not in ("cpu", "cuda")]
    if bad:
        parser.error(f"--device: unknown {bad}; choose from cpu, cuda")
    if "cuda" in args.device and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA device is available (torch.cuda.is_available())")
    if args.batch < 2:
        parser.error(f"--batch must be at least 2, got {args.batch}")
    if args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out} exists and is not a directory")
    args.scenes = list(dict.fromkeys(args.scenes))
    args.device = list(dict.fromkeys(args.device))
    args.data = args.out / "data" if args.data is None else args.data
    args.command = " ".join(
        ["python benchmarks/tradeoff.py", *(sys.argv[1:] if argv is None else argv)]
    )
    return args


def run(args: argparse.Namespace) -> tuple[list[dict], dict]:
    """Build each scene, evaluate its settings; returns the rows and the run's metadata."""
    size = QUICK if args.quick else Size()
    progress = not args.no_progress
    load_start = os.getloadavg()[0]
    rows, scenes = [], {}
    for name in tqdm(args.scenes, desc="scenes", disable=not progress):
        scene = build_scene(name, size, args.data, progress)
        grid = settings_grid(scene.stiffness, scene.damping, args.quick, args.device, args.batch)
        rows += evaluate_scene(scene, grid, size, progress)
        scenes[name] = {
            "title": scene.title,
            "stiffness": scene.stiffness,
            "damping_ratio": scene.damping,
            "h": scene.h,
            "states": len(scene.q),
            "windows": len(scene.windows(HORIZON)),
            "pose_weights": list(scene.weights),
        }
    mark_fronts(rows)
    meta = {
        "command": args.command,
        "quick": args.quick,
        "size": asdict(size),
        "horizon": HORIZON,
        "scenes": scenes,
        "torch_threads": torch.get_num_threads(),
        "cpus": os.cpu_count(),
        "load_average": [load_start, os.getloadavg()[0]],
    }
    return rows, meta


def main(argv: Sequence[str] | None = None) -> int:
    """Run, print the table and the dominance summary, write the outputs; exit status 0."""
    args = parse_args(argv)
    torch.set_num_threads(1)
    rows, meta = run(args)
    print(format_table(rows))
    paths = write_outputs(args.out, rows, meta)
    print()
    print((args.out / "tradeoff.md").read_text())
    report.written(paths)
    return 0


if __name__ == "__main__":
    report.run_main(main)
