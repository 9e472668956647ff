"""Contact geometry in pure torch: shapes on bodies, poses from q, ``Contacts`` at any q.

The torch twin of MuJoCo's collision stage: :class:`SceneGeometry` maps ``q (..., nq)`` to
the same :class:`~torchcontact.contacts.Contacts` a
:class:`~torchcontact.sim.detect.ContactDetector` returns, differentiably, batched, on any
device. :func:`torchcontact.sim.geometry.scene_geometry` reads it from a MuJoCo scene;
:func:`rollout` steps a contact model with it, with no MuJoCo in the loop.
"""

from torchcontact.geometry.kinematics import BodyTree, Joint
from torchcontact.geometry.rollout import rollout
from torchcontact.geometry.scene import Pair, SceneGeometry
from torchcontact.geometry.shapes import Shape

__all__ = ["BodyTree", "Joint", "Pair", "SceneGeometry", "Shape", "rollout"]
