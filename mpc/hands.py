"""The paper's MPC settings for the robot hands (TASKS.md, TriFinger and Allegro columns)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchcontact.integrate import JointLayout
from torchcontact.mpc.controller import ContactImplicitMPC, mpc_model
from torchcontact.mpc.costs import ManipulationCost
from torchcontact.sim.hands import HANDS, Hand
from torchcontact.sim.kinematics import FingertipKinematics
from torchcontact.systems import QuasiDynamic

GRAVITY = 9.8  # [m/s²]


@dataclass(frozen=True)
class HandMPCSettings:
    """The model and cost of one hand's MPC.

    Attributes:
        object_metric: diagonal of εMₒ/h² (translation [N/m] ×3, rotation ×3).
        robot_stiffness: Kᵣ of the quasi-dynamic robot.
        object_mass: m in the object's gravity load b = m·g [kg].
        stiffness: the paper's K.
        control_bound: |u| per joint and step [rad].
        cost: the paper's weights for this hand.
        h: the model's time step [s].
    """

    object_metric: tuple[float, ...]
    robot_stiffness: float
    stiffness: float
    control_bound: float
    cost: ManipulationCost
    object_mass: float = 0.01
    h: float = 0.1


MPC_SETTINGS = {
    "trifinger": HandMPCSettings(
        object_metric=(50.0, 50.0, 50.0, 0.1, 0.1, 0.1),
        robot_stiffness=10.0,
        stiffness=0.5,
        control_bound=0.01,
        # tilt: ours, not the paper's. Tall objects (binoculars, duck) tipped over when pushed
        # above their centre of mass; keeping the planned states upright stops that.
        cost=ManipulationCost(contact=0.5, grasp=0.05, control=10.0, tilt=100.0),
    ),
    "allegro": HandMPCSettings(
        object_metric=(50.0, 50.0, 50.0, 0.1, 0.1, 0.1),
        robot_stiffness=1.0,
        stiffness=0.5,
        control_bound=0.2,
        cost=ManipulationCost(contact=1.0, grasp=0.0, control=0.1, position=100.0),
    ),
}


class JointFingertips(torch.nn.Module):
    """Fingertip positions ``(..., n_tips, 3)`` [m] of states ``q (..., 7 + n_joints)``."""

    def __init__(self, hand: Hand, dtype: torch.dtype = torch.float64):
        super().__init__()
        self.kinematics = FingertipKinematics(hand.mjcf, hand.tips, dtype=dtype)

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return self.kinematics(q[..., 7:])


def hand_mpc(
    hand: Hand | str,
    stiffness: float | None = None,
    dtype: torch.dtype = torch.float64,
    model: str = "complementarity_free",
    relaxation: float | None = None,
    **options,
) -> ContactImplicitMPC:
    """The MPC of ``hand`` with the paper's settings.

    ``model``: ``"complementarity_free"`` (K = ``stiffness``, default the paper's 0.5, D = 0.1·K,
    γ = 100) or ``"qp"`` (the relaxed QP, κ = ``relaxation``, default the paper's), see
    :func:`mpc_model`; n_d = 4, T = 4, h = 0.1; fingertips by pytorch-kinematics from the hand's
    MJCF; ``options`` go to :class:`ContactImplicitMPC` (``max_iter``, ``memory``, ``compile``,
    ...).
    """
    hand = HANDS[hand] if isinstance(hand, str) else hand
    settings = MPC_SETTINGS[hand.name]
    n = hand.n_joints
    system = QuasiDynamic(
        object_metric=list(settings.object_metric),
        robot_stiffness=settings.robot_stiffness,
        object_force=[0.0, 0.0, -settings.object_mass * GRAVITY, 0.0, 0.0, 0.0],
        n_robot=n,
    )
    return ContactImplicitMPC(
        system,
        mpc_model(
            model,
            settings.stiffness if stiffness is None else stiffness,
            relaxation,
            settings.h,
        ),
        JointLayout(["free"] + ["hinge"] * n),
        JointFingertips(hand, dtype),
        settings.cost,
        -settings.control_bound,
        settings.control_bound,
        h=settings.h,
        dtype=dtype,
        **options,
    )
