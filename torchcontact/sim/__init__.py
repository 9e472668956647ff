"""The MuJoCo bridge: the only package of torchcontact that imports ``mujoco``."""

from torchcontact.sim.detect import ContactDetector
from torchcontact.sim.dynamics import bias_force, joint_layout, mass_matrix

__all__ = ["ContactDetector", "bias_force", "joint_layout", "mass_matrix"]
