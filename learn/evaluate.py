"""Prediction errors of a contact model against MuJoCo: one step and multi-step rollouts.

One step: from each recorded state with its recorded contacts and control, the model's next
object pose against MuJoCo's. Rollout: from a recorded state, the model's own states for
``horizon`` steps under the recorded controls, contacts re-detected by the scene's
:class:`~torchcontact.sim.ContactDetector` at every predicted state, against MuJoCo's pose
after those steps. Errors are means over transitions (or rollout windows) and objects:
position [mm], rotation angle [deg] and the combined ``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)``
with the MPC's final-cost weights.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import torch

from torchcontact.checkpoint import constant_model
from torchcontact.integrate import JointLayout, integrate
from torchcontact.learn.data import Transitions
from torchcontact.learn.fit import (
    StepData,
    carried,
    model_terms,
    object_indices,
    pose_errors,
    predict_poses,
)
from torchcontact.model import ComplementarityFree
from torchcontact.rotations import quaternion_angle
from torchcontact.sim.detect import ContactDetector
from torchcontact.validation import validate_args


def pose_metrics(pose: torch.Tensor, target: torch.Tensor, weights: tuple[float, float]) -> dict:
    """Errors of poses ``(..., 7)``: means ``pos_mm``, ``angle_deg``, ``combined`` and their
    medians ``pos_mm_median``, ``angle_deg_median``, ``combined_median``."""
    position, quaternion = pose_errors(pose.double(), target.double())
    errors = {
        "pos_mm": 1e3 * position,
        "angle_deg": torch.rad2deg(
            quaternion_angle(pose[..., 3:].double(), target[..., 3:].double())
        ),
        "combined": weights[0] * position.square() + weights[1] * quaternion,
    }
    means = {key: float(value.mean()) for key, value in errors.items()}
    medians = {f"{key}_median": float(value.median()) for key, value in errors.items()}
    return {**means, **medians}


def one_step_error(model: ComplementarityFree, data: StepData, weights) -> dict:
    """:func:`pose_metrics` of the model's one-step predictions on ``data`` (its windows'
    first steps)."""
    model = model.to(data.q.dtype)
    with torch.no_grad(), validate_args(False):
        first = data.first_steps()
        return pose_metrics(predict_poses(model, first)[:, 0], first.target[:, 0], weights)


Detectors = ContactDetector | Mapping[str, ContactDetector]
"""One detector (one object), or each object's by name (``meta["objects"]``)."""


def _object_parts(transitions: Transitions, detectors: Detectors):
    """``(part, detector, system)`` per object of ``transitions``: its rows, its detector and
    its affine system ``(Q, b0, B)`` (float64)."""
    meta = transitions.meta
    B = torch.tensor(meta["system"]["B"], dtype=torch.float64)
    for index in transitions.object_ids():
        name = meta["objects"][index]
        if isinstance(detectors, Mapping):
            if name not in detectors:
                raise ValueError(f"detectors must hold object {name!r}, got {sorted(detectors)}")
            detector = detectors[name]
        else:
            detector = detectors
        system = meta["systems"][index]
        Q, b0 = (torch.tensor(system[key], dtype=torch.float64) for key in ("Q", "b0"))
        yield transitions.select(transitions.object == index), detector, (Q, b0, B)


def rollout_error(
    model: ComplementarityFree,
    transitions: Transitions,
    detectors: Detectors,
    horizon: int = 10,
    stride: int = 5,
    robot: str = "model",
) -> dict:
    """:func:`pose_metrics` after ``horizon``-step rollouts from every ``stride``-th step.

    Per object, all windows roll out together (float64): per step, contacts detected at the
    predicted states by the object's detector, ``(Q, b)`` of the recorded controls (through
    the model's calibration, if any), ``v⁺`` from ``model`` and ``q ⊕ h v⁺``. With
    ``robot="recorded"`` the robot's coordinates are reset to MuJoCo's after every step, so
    only the objects are predicted: the error of the contact model alone, without the
    quasi-dynamic robot's tracking error. Adds ``"windows"``, their number.
    """
    if robot not in ("model", "recorded"):
        raise ValueError(f"robot must be 'model' or 'recorded', got {robot!r}")
    meta = transitions.meta
    layout = JointLayout(meta["joints"])
    q_index, v_index = object_indices(meta["joints"])
    is_object = torch.zeros(layout.nq, dtype=torch.bool)
    is_object[q_index.flatten()] = True
    object_rows = v_index.flatten()
    model = model.to(torch.float64)
    predicted, recorded = [], []
    for part, detector, (Q0, b0, B) in _object_parts(transitions, detectors):
        windows = part.windows(horizon, stride)
        if len(windows) == 0:
            continue
        q = part.q[windows[:, 0]]
        moved = part.previous_displacement()[windows[:, 0]][:, object_rows]
        with torch.no_grad(), validate_args(False):
            for t in range(horizon):
                contacts = detector(q).to(torch.float64)
                u = part.u[windows[:, t]]
                Q, b = model_terms(model, Q0, b0, B, u, object_rows)
                Q, b = carried(model, Q, b, moved, object_rows)
                v = model(Q, b, contacts, meta["h"], q=q)
                moved = meta["h"] * v[:, object_rows]
                q = integrate(q, v, meta["h"], layout)
                if robot == "recorded":
                    q = torch.where(is_object, q, part.q_next[windows[:, t]])
        predicted.append(q[:, q_index])
        recorded.append(part.q_next[windows[:, -1], :][:, q_index])
    if not predicted:
        raise ValueError(f"transitions hold no {horizon}-step window (trajectories too short)")
    metrics = pose_metrics(torch.cat(predicted), torch.cat(recorded), meta["pose_weights"])
    return {**metrics, "windows": sum(len(p) for p in predicted)}


def still_error(transitions: Transitions, horizon: int = 10, stride: int = 5) -> dict:
    """:func:`pose_metrics` of the reference prediction "the objects do not move" over the
    windows of :func:`rollout_error`: how far the objects really moved."""
    meta = transitions.meta
    windows = transitions.windows(horizon, stride)
    q_index, _ = object_indices(meta["joints"])
    start = transitions.q[windows[:, 0], :][:, q_index]
    target = transitions.q_next[windows[:, -1], :][:, q_index]
    return {**pose_metrics(start, target, meta["pose_weights"]), "windows": len(windows)}


def sweep_constant(
    values,
    transitions: Transitions,
    detector: Detectors,
    horizon: int = 10,
    stride: int = 5,
) -> list[dict]:
    """:func:`rollout_error` of the paper's model (D = 0.1·K) at each constant K in
    ``values``; one ``{"stiffness", ...metrics}`` per value, in order."""
    rows = []
    for value in values:
        model = constant_model(float(value), transitions.meta)
        metrics = rollout_error(model, transitions, detector, horizon, stride)
        rows.append({"stiffness": float(value), **metrics})
    return rows


def log_grid(low: float, high: float, count: int) -> list[float]:
    """``count`` log-spaced values from ``low`` to ``high`` (both included)."""
    if not (0 < low < high and math.isfinite(high)) or count < 2:
        raise ValueError(f"need 0 < low < high and count >= 2, got {low}, {high}, {count}")
    return np.geomspace(low, high, count).tolist()
