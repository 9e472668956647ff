"""torchcontact: the complementarity-free multi-contact model (Jin 2024) in PyTorch.

The contact layer is pure torch; ``torchcontact.sim`` bridges MuJoCo, ``torchcontact.mpc``
plans through the model and ``torchcontact.learn`` fits its stiffness from data.
"""

from torchcontact.calibration import SystemCalibration
from torchcontact.contacts import Contacts, facet_directions
from torchcontact.functional import cf_multipliers, cf_velocity, softplus
from torchcontact.integrate import JointLayout, integrate
from torchcontact.model import (
    MODELS,
    AnitescuQP,
    ComplementarityFree,
    ContactModel,
    RelaxedQP,
    contact_model,
)
from torchcontact.networks import ObjectContactNetwork
from torchcontact.qp import qp_solve
from torchcontact.relaxed_qp import relaxed_qp_velocity
from torchcontact.residual import ObjectResidual
from torchcontact.rotations import (
    quaternion_angle,
    quaternion_error,
    quaternion_exp,
    quaternion_multiply,
    quaternion_to_matrix,
    up_axis,
)
from torchcontact.stiffness import (
    PARAMETERIZATIONS,
    Constant,
    ContactNetwork,
    Parameterization,
    PerRow,
    Relative,
    StateNetwork,
    parameterization,
    register_parameterization,
)
from torchcontact.systems import GRAVITY, QuasiDynamic, carry_momentum, full_dynamic
from torchcontact.validation import set_validate_args, validate_args

__all__ = [
    "GRAVITY",
    "MODELS",
    "PARAMETERIZATIONS",
    "AnitescuQP",
    "ComplementarityFree",
    "SystemCalibration",
    "Constant",
    "ContactModel",
    "ContactNetwork",
    "Contacts",
    "JointLayout",
    "ObjectContactNetwork",
    "ObjectResidual",
    "Parameterization",
    "PerRow",
    "QuasiDynamic",
    "RelaxedQP",
    "Relative",
    "StateNetwork",
    "carry_momentum",
    "cf_multipliers",
    "cf_velocity",
    "contact_model",
    "facet_directions",
    "full_dynamic",
    "integrate",
    "parameterization",
    "qp_solve",
    "quaternion_angle",
    "quaternion_error",
    "quaternion_exp",
    "quaternion_multiply",
    "quaternion_to_matrix",
    "register_parameterization",
    "relaxed_qp_velocity",
    "set_validate_args",
    "softplus",
    "up_axis",
    "validate_args",
]
