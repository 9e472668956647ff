"""A multi-step rollout of a contact model with its contacts from the torch geometry."""

from __future__ import annotations

import torch

from torchcontact.geometry.scene import SceneGeometry
from torchcontact.integrate import JointLayout, integrate
from torchcontact.validation import check_shape


def rollout(
    model: torch.nn.Module,
    system: torch.nn.Module,
    geometry: SceneGeometry,
    layout: JointLayout,
    q0: torch.Tensor,
    controls: torch.Tensor,
    h: float,
) -> torch.Tensor:
    """States ``(..., T + 1, nq)`` from ``q0 (..., nq)`` under ``controls (..., T, nu)``.

    Each step reads as its pipeline, with no MuJoCo call: ``contacts = geometry(q)``;
    ``Q, b = system(u)``; ``v = model(Q, b, contacts, h, q)``; ``q ← q ⊕ h v``. The contacts
    move with the state, so a contact opens, closes or slides off an edge within the rollout;
    gradients of any state reach ``q0``, the controls and the model's parameters (K, D).
    """
    check_shape("q0", q0, f"(..., {layout.nq})", q0.dim() >= 1 and q0.shape[-1] == layout.nq)
    check_shape("controls", controls, "(..., T, nu)", controls.dim() >= 2)
    states = [q0]
    q = q0
    for u in controls.unbind(-2):
        contacts = geometry(q)
        Q, b = system(u)
        v = model(Q, b, contacts, h, q)
        q = integrate(q, v, h, layout)
        states.append(q)
    return torch.stack(states, -2)
