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

import numpy as np
import torch

from torchcontact.checkpoint import constant_model
from torchcontact.integrate import JointLayout, integrate
from torchcontact.learn.data import Transitions
from torchcontact.learn.fit import (
    StepData,
    object_indices,
    pose_errors,
    predict_poses,
    system_terms,
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
    """:func:`pose_metrics` of the model's one-step predictions on ``data``."""
    model = model.to(data.gap.dtype)
    with torch.no_grad(), validate_args(False):
        return pose_metrics(predict_poses(model, data), data.target, weights)


def rollout_error(
    model: ComplementarityFree,
    transitions: Transitions,
    detector: ContactDetector,
    horizon: int = 10,
    stride: int = 5,
    robot: str = "model",
) -> dict:
    """:func:`pose_metrics` after ``horizon``-step rollouts from every ``stride``-th step.

    All windows roll out together (float64): per step, contacts at the predicted states,
    ``(Q, b)`` of the recorded controls, ``v⁺`` from ``model`` and ``q ⊕ h v⁺``. With
    ``robot="recorded"`` the robot's coordinates are reset to MuJoCo's after every step, so
    only the objects are predicted: the error of the contact model alone, without the
    quasi-dynamic robot's tracking error. Adds ``"windows"``, their number.
    """
    if robot not in ("model", "recorded"):
        raise ValueError(f"robot must be 'model' or 'recorded', got {robot!r}")
    meta = transitions.meta
    windows = transitions.windows(horizon, stride)
    if len(windows) == 0:
        raise ValueError(f"transitions hold no {horizon}-step window (trajectories too short)")
    layout = JointLayout(meta["joints"])
    q_index, _ = object_indices(meta["joints"])
    is_object = torch.zeros(layout.nq, dtype=torch.bool)
    is_object[q_index.flatten()] = True
    model = model.to(torch.float64)
    q = transitions.q[windows[:, 0]]
    with torch.no_grad(), validate_args(False):
        for t in range(horizon):
            contacts = detector(q).to(torch.float64)
            Q, b = system_terms(meta, transitions.u[windows[:, t]])
            v = model(Q, b, contacts, meta["h"], q=q)
            q = integrate(q, v, meta["h"], layout)
            if robot == "recorded":
                q = torch.where(is_object, q, transitions.q_next[windows[:, t]])
    target = transitions.q_next[windows[:, -1], :][:, q_index]
    metrics = pose_metrics(q[:, q_index], target, meta["pose_weights"])
    return {**metrics, "windows": len(windows)}


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
    detector: ContactDetector,
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
