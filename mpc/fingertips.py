"""The paper's MPC settings for the three-fingertip tasks (TASKS.md, fingertips column)."""

from __future__ import annotations

import math

import torch

from torchcontact.environments.costs import ManipulationCost
from torchcontact.environments.tasks import OBJECT_SETTINGS
from torchcontact.integrate import JointLayout
from torchcontact.mpc.controller import ContactImplicitMPC, mpc_model
from torchcontact.systems import QuasiDynamic

OBJECT_MASS = 0.01  # [kg], the model's Mₒ in b = m·g
GRAVITY = 9.8  # [m/s²]
TRANSLATION_METRIC = 50.0  # εMₒ/h² on the object's translation [N/m]
ROBOT_STIFFNESS = 100.0  # Kᵣ [N/m]
CONTROL_BOUND = 0.005  # |u| per element [m of tip displacement per step]
PAPER_STIFFNESS = 1.0  # K, the paper's
STIFFNESS = 4.64
"""The default K: ``torchcontact learn-k --scene fingertips --object cube``'s best constant K
on the cube's MPC rollouts (10-step error 0.066 against 0.084 with the paper's K = 1). Over
the nine pairs × 20 trials it raised success from 75.6 to 86.1 % (docs/journal.md, fingertips)."""
LAYOUT = JointLayout(["free"] + ["slide"] * 9)


def fingertip_positions(q: torch.Tensor) -> torch.Tensor:
    """Forward kinematics of free fingertips: ``q (..., 16) ↦ (..., 3, 3)`` [m]."""
    return q[..., 7:16].unflatten(-1, (3, 3))


def fingertips_mpc(
    obj: str,
    stiffness: float = STIFFNESS,
    model: str = "complementarity_free",
    relaxation: float | None = None,
    bound_tips: bool = False,
    **options,
) -> ContactImplicitMPC:
    """The MPC for object ``obj`` with the paper's fingertip settings.

    ``model``: ``"complementarity_free"`` (K = ``stiffness``, default :data:`STIFFNESS`, the
    paper's is :data:`PAPER_STIFFNESS`; D = 0.1·K, γ = 100) or ``"qp"``
    (the relaxed QP, κ = ``relaxation``, default the paper's), see :func:`mpc_model`; n_d = 4,
    T = 4, h from the object's settings; ``options`` go to :class:`ContactImplicitMPC`
    (``max_iter``, ``memory``, ``compile``, ...).

    ``bound_tips`` keeps the planned tip heights in [0, the object's ``tip_height_max``] as the
    paper's code does (a penalty here, see :class:`ManipulationCost`). Off by default: on
    seeds 0–9 it lowered in-air cube from 8 to 4 successes and in-air foam brick from 6 to 5,
    and left flip cube at 7 (session 5, ``results/explore/ft_bounds``).
    """
    settings = OBJECT_SETTINGS[obj]
    high = math.inf if settings.tip_height_max is None else settings.tip_height_max
    cost = ManipulationCost(tip_height=(0.0, high) if bound_tips else None)
    system = QuasiDynamic(
        object_metric=[TRANSLATION_METRIC] * 3 + [settings.rotational_metric] * 3,
        robot_stiffness=ROBOT_STIFFNESS,
        object_force=[0.0, 0.0, -OBJECT_MASS * GRAVITY, 0.0, 0.0, 0.0],
        n_robot=9,
    )
    return ContactImplicitMPC(
        system,
        mpc_model(model, stiffness, relaxation, settings.model_step),
        LAYOUT,
        fingertip_positions,
        cost,
        -CONTROL_BOUND,
        CONTROL_BOUND,
        h=settings.model_step,
        **options,
    )
