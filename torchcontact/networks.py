"""A learned K (or D) per dual-cone row from each contact's geometry in the object's frame.

:class:`~torchcontact.stiffness.ContactNetwork` sees a contact's distance, μ and world normal;
:class:`ObjectContactNetwork` adds where the contact sits on the object and how the object is
turned, and gives each friction facet its own value: per contact the features are
``[φ/scale, n_world (3), n_object (3), p_object/size (3), up_object (3)]`` with the normal
``n`` and the contact point ``p`` (relative to the object's origin) rotated into the
object's frame, and ``up`` the world's z axis seen from the object; the network outputs
``n_d`` positive values, one per facet row.

Registered in :data:`~torchcontact.stiffness.PARAMETERIZATIONS` as ``"object_contact_network"``.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from torchcontact.contacts import Contacts
from torchcontact.rotations import quaternion_to_matrix
from torchcontact.stiffness import Parameterization, register_parameterization


class ObjectContactNetwork(Parameterization):
    """K per row from contact features in the object's frame (see the module docstring).

    Args:
        facets: friction facets n_d per contact (the network's output size).
        hidden: hidden units of its two tanh layers.
        value: the value every row starts near.
        distance_scale: φ scale [m] of the distance feature (φ/scale, clamped to ±10).
        object_size: length [m] that contact points are divided by.

    Needs ``q (..., nq)`` whose first 7 entries are the object's position and quaternion, and
    contacts with ``frame`` and ``position``.
    """

    features = 13

    def __init__(
        self,
        facets: int,
        hidden: int = 64,
        value: float = 1.0,
        distance_scale: float = 1e-4,
        object_size: float = 0.05,
    ):
        super().__init__()
        values = (
            ("value", value),
            ("distance_scale", distance_scale),
            ("object_size", object_size),
        )
        for name, number in values:
            if not number > 0:
                raise ValueError(f"{name} must be positive, got {number!r}")
        self.facets, self.distance_scale, self.object_size = facets, distance_scale, object_size
        self.net = nn.Sequential(
            nn.Linear(self.features, hidden),
            nn.Tanh(),
            nn.Linear(hidden, hidden),
            nn.Tanh(),
            nn.Linear(hidden, facets),
        )
        with torch.no_grad():
            self.net[-1].weight.mul_(0.01)
            self.net[-1].bias.fill_(math.log(math.expm1(value)))  # softplus⁻¹(value)

    def contact_features(self, contacts: Contacts, q: torch.Tensor) -> torch.Tensor:
        """``(..., nc, 13)`` features of every slot."""
        if q is None:
            raise ValueError("q is required by ObjectContactNetwork: pass q=(..., nq)")
        if contacts.frame is None or contacts.position is None:
            raise ValueError("contacts must carry frame and position for ObjectContactNetwork")
        dtype = self.net[0].weight.dtype
        q = q.to(dtype)
        rotation = quaternion_to_matrix(q[..., 3:7]).unsqueeze(-3)  # (..., 1, 3, 3)
        normal = contacts.frame[..., 0, :].to(dtype)
        offset = (contacts.position.to(dtype) - q[..., None, :3]) / self.object_size
        up = rotation[..., 2, :].expand(*normal.shape[:-1], 3)  # world z in the object frame
        phi = (contacts.phi.to(dtype) / self.distance_scale).clamp(-10.0, 10.0).unsqueeze(-1)

        def to_object(x):
            return (x.unsqueeze(-2) @ rotation).squeeze(-2)

        return torch.cat([phi, normal, to_object(normal), to_object(offset), up], dim=-1)

    def forward(self, contacts, facets, q=None, stiffness=None) -> torch.Tensor:
        if facets != self.facets:
            raise ValueError(f"facets must be {self.facets} (the network's outputs), got {facets}")
        per_facet = F.softplus(self.net(self.contact_features(contacts, q)))
        return per_facet.flatten(-2)


register_parameterization("object_contact_network", ObjectContactNetwork)
