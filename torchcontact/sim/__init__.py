"""The MuJoCo bridge: the only package of torchcontact that imports ``mujoco``."""

from torchcontact.shapes import OBJECT_SIZES, ObjectMesh, load_object, make_object, object_names
from torchcontact.sim.rendering import select_gl_backend

# mujoco reads MUJOCO_GL once, when first imported: choose the backend before any sim import.
select_gl_backend()

from torchcontact.sim.detect import ContactDetector
from torchcontact.sim.dynamics import bias_force, joint_layout, mass_matrix
from torchcontact.sim.fingertips import INITIAL_TIPS, TIP_RADIUS, FingertipsPlant
from torchcontact.sim.kinematics import FingertipKinematics
from torchcontact.sim.objects import add_goal_marker, add_object
from torchcontact.sim.robot import Actuator, Robot
from torchcontact.sim.user_scene import DEFAULT_EPSILON, UserScene, describe_scene

__all__ = [
    "DEFAULT_EPSILON",
    "INITIAL_TIPS",
    "OBJECT_SIZES",
    "TIP_RADIUS",
    "Actuator",
    "ContactDetector",
    "FingertipKinematics",
    "FingertipsPlant",
    "ObjectMesh",
    "Robot",
    "UserScene",
    "add_goal_marker",
    "add_object",
    "bias_force",
    "describe_scene",
    "joint_layout",
    "load_object",
    "make_object",
    "mass_matrix",
    "object_names",
    "select_gl_backend",
]
