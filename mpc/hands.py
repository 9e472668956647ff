"""The paper's MPC settings for the robot hands (TASKS.md, TriFinger and Allegro columns)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from torchcontact.environments.costs import ManipulationCost
from torchcontact.integrate import JointLayout
from torchcontact.mpc.controller import ContactImplicitMPC, mpc_model
from torchcontact.sim.hands import HANDS, MODEL_FRICTION, Hand
from torchcontact.sim.kinematics import FingertipKinematics
from torchcontact.sim.objects import ObjectMesh
from torchcontact.systems import QuasiDynamic

GRAVITY = 9.8  # [m/s²]


def tips_before_sliding(obj: ObjectMesh, mu: float = MODEL_FRICTION) -> bool:
    """Whether a push at ``obj``'s pose point tips it over before it slides on friction ``mu``
    (``mu · obj.tipping_ratio() > 1``): the binoculars, camera, rubber duck, water bottle and
    (a rod since scenes v7) the stick."""
    return mu * obj.tipping_ratio() > 1.0


@dataclass(frozen=True)
class HandMPCSettings:
    """The model and cost of one hand's MPC.

    Attributes:
        object_metric: diagonal of εMₒ/h² (translation [N/m] ×3, rotation ×3).
        robot_stiffness: Kᵣ of the quasi-dynamic robot.
        object_mass: m in the object's gravity load b = m·g [kg].
        stiffness: the paper's K.
        control_bound: |u| per joint and step [rad].
        cost: the paper's weights for this hand (the Allegro's position weight is ours).
        h: the model's time step [s].
        tilt: weight of the cost's tilt term (ours, not the paper's) for objects that tip
            before they slide (:func:`tips_before_sliding`); 0 leaves every object without.
    """

    object_metric: tuple[float, ...]
    robot_stiffness: float
    stiffness: float
    control_bound: float
    cost: ManipulationCost
    object_mass: float = 0.01
    h: float = 0.1
    tilt: float = 0.0


MPC_SETTINGS = {
    "trifinger": HandMPCSettings(
        object_metric=(50.0, 50.0, 50.0, 0.1, 0.1, 0.1),
        robot_stiffness=10.0,
        stiffness=0.5,
        control_bound=0.01,
        cost=ManipulationCost(contact=0.5, grasp=0.05, control=10.0),
        # the binoculars tipped over when pushed; a tilt cost on every object costs precision
        # (a cube's final error 4.7 -> 8.5 mm) and the flat airplane's success (75 -> 55 %)
        tilt=100.0,
    ),
    "allegro": HandMPCSettings(
        object_metric=(50.0, 50.0, 50.0, 0.1, 0.1, 0.1),
        robot_stiffness=1.0,
        stiffness=0.5,
        control_bound=0.2,
        # position weight 300, not the paper's 100: success counts orientation only, and with
        # 100 the MPC turned objects off the palm (38 of 54 failed trials, 17 objects × 20);
        # with 300, 16 of 45 (1000: 21 of 54, more objects stuck unturned)
        cost=ManipulationCost(contact=1.0, grasp=0.0, control=0.1, position=300.0),
        # no tilt cost: with one on every object the stick, binoculars and camera fell from
        # 7, 8 and 8 to 2 successes in 10 each
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
    obj: ObjectMesh | None = None,
    **options,
) -> ContactImplicitMPC:
    """The MPC of ``hand`` with the paper's settings.

    ``model``: ``"complementarity_free"`` (K = ``stiffness``, default the paper's 0.5, D = 0.1·K,
    γ = 100) or ``"qp"`` (the relaxed QP, κ = ``relaxation``, default the paper's), see
    :func:`mpc_model`; n_d = 4, T = 4, h = 0.1; fingertips by pytorch-kinematics from the hand's
    MJCF; ``options`` go to :class:`ContactImplicitMPC` (``max_iter``, ``memory``, ``compile``,
    ...). ``obj``, the manipulated object, switches the hand's tilt cost on where it
    :func:`tips_before_sliding`; None plans with the paper's cost.
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
    cost = settings.cost
    if obj is not None and settings.tilt > 0 and tips_before_sliding(obj):
        cost = dataclasses.replace(cost, tilt=settings.tilt)
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
        cost,
        -settings.control_bound,
        settings.control_bound,
        h=settings.h,
        dtype=dtype,
        **options,
    )
