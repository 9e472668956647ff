"""A learned correction of the objects' velocity: what no stiffness K(q) can fix.

The complementarity-free step moves an object only as far as its contacts' impulses push it
through the quasi-dynamic metric. On the Allegro, where curled fingers lift, pinch and flick an
object on the palm, that is a fraction of its motion whatever K is (docs/experiments.md,
"Learning K(q) and D(q)"). An :class:`ObjectResidual` adds a small network's output to the
objects' rows of the step's ``v⁺``:

    v⁺ₒ ← v⁺ₒ + δv(features),   features = [objects' positions and rotation matrices, the other
    coordinates of q, the robot's rows of b (the command), h·v⁺ₒ (the step's own motion)].

It is fitted after K(q), D(q) and the system's factors, on what they leave
(:func:`torchcontact.learn.fit.fit_residual`), and starts at zero: its last layer is zero, so an
unfitted residual changes nothing.
"""

from __future__ import annotations

import torch
from torch import nn

from torchcontact.rotations import quaternion_to_matrix

UNITS = (0.01, 0.01, 0.01, 0.2, 0.2, 0.2)
"""The network's output unit per object velocity row, times 1/h: 1 cm of translation and 0.2
rad of rotation a step, so its outputs are of order one."""


class ObjectResidual(nn.Module):
    """``δv`` on the objects' velocity rows, a two-hidden-layer tanh network.

    Args:
        object_q: ``(n_obj, 7)`` the objects' free-joint indices in q (position, quaternion).
        object_rows: ``(n_obj, 6)`` their indices in v.
        nq, nv: the sizes of q and v.
        hidden: hidden units of each layer.

    Call ``residual(q, b, v, h)`` with ``q (..., nq)``, ``b (..., nv)``, ``v (..., nv)`` the
    step's velocity and ``h`` [s]; returns ``v`` with ``δv`` added to the objects' rows. The
    features are standardized by the buffers ``feature_mean`` and ``feature_std``
    (:meth:`standardize` sets them from training features).
    """

    def __init__(self, object_q, object_rows, nq: int, nv: int, hidden: int = 64):
        super().__init__()
        object_q = torch.as_tensor(object_q, dtype=torch.long)
        object_rows = torch.as_tensor(object_rows, dtype=torch.long)
        if object_q.dim() != 2 or object_q.shape[-1] != 7:
            raise ValueError(f"object_q must have shape (n_obj, 7), got {tuple(object_q.shape)}")
        if object_rows.shape != (object_q.shape[0], 6):
            raise ValueError(
                f"object_rows must have shape ({object_q.shape[0]}, 6), got "
                f"{tuple(object_rows.shape)}"
            )
        for name, size in (("nq", nq), ("nv", nv), ("hidden", hidden)):
            if isinstance(size, bool) or not isinstance(size, int) or size < 1:
                raise ValueError(f"{name} must be a positive integer, got {size!r}")
        if int(object_q.max()) >= nq or int(object_rows.max()) >= nv or object_q.min() < 0:
            raise ValueError(f"object_q and object_rows must index q ({nq}) and v ({nv})")
        other_q = torch.ones(nq, dtype=torch.bool)
        other_q[object_q.flatten()] = False
        robot_rows = torch.ones(nv, dtype=torch.bool)
        robot_rows[object_rows.flatten()] = False
        self.register_buffer("object_q", object_q)
        self.register_buffer("object_rows", object_rows.flatten())
        self.register_buffer("other_q", other_q.nonzero().flatten())
        self.register_buffer("robot_rows", robot_rows.nonzero().flatten())
        self.register_buffer("units", torch.tensor(UNITS).repeat(object_q.shape[0]))
        n_obj = object_q.shape[0]
        features = 12 * n_obj + len(self.other_q) + len(self.robot_rows) + 6 * n_obj
        self.register_buffer("feature_mean", torch.zeros(features))
        self.register_buffer("feature_std", torch.ones(features))
        self.net = nn.Sequential(
            nn.Linear(features, hidden),
            nn.Tanh(),
            nn.Linear(hidden, hidden),
            nn.Tanh(),
            nn.Linear(hidden, 6 * n_obj),
        )
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)
        self.hidden = hidden

    def features(self, q: torch.Tensor, b: torch.Tensor, v: torch.Tensor, h) -> torch.Tensor:
        """Raw features ``(..., F)`` of a step (see the module docstring)."""
        batch = torch.broadcast_shapes(q.shape[:-1], b.shape[:-1], v.shape[:-1])
        q, b, v = q.expand(*batch, -1), b.expand(*batch, -1), v.expand(*batch, -1)
        pose = q[..., self.object_q]
        rotation = quaternion_to_matrix(pose[..., 3:]).flatten(-2)
        moved = v[..., self.object_rows] * _per_row(h) / self.units.to(v)
        parts = [pose[..., :3].flatten(-2), rotation.flatten(-2), q[..., self.other_q]]
        return torch.cat(parts + [b[..., self.robot_rows], moved], -1)

    def standardize(self, features: torch.Tensor) -> None:
        """Set ``feature_mean`` and ``feature_std`` from training features ``(N, F)``."""
        if features.dim() != 2 or features.shape[-1] != len(self.feature_mean):
            raise ValueError(
                f"features must have shape (N, {len(self.feature_mean)}), got "
                f"{tuple(features.shape)}"
            )
        self.feature_mean.copy_(features.mean(0))
        self.feature_std.copy_(features.std(0).clamp_min(1e-6))

    def correction(self, features: torch.Tensor) -> torch.Tensor:
        """The network's output ``(..., 6·n_obj)`` in :data:`UNITS` for raw ``features``."""
        mean, std = self.feature_mean.to(features), self.feature_std.to(features)
        return self.net(((features - mean) / std).to(self.net[0].weight.dtype)).to(features)

    def forward(self, q: torch.Tensor, b: torch.Tensor, v: torch.Tensor, h) -> torch.Tensor:
        delta = self.correction(self.features(q, b, v, h)) * self.units.to(v) / _per_row(h)
        return v.index_add(-1, self.object_rows, delta)

    def extra_repr(self) -> str:
        return f"objects={self.object_q.shape[0]}, hidden={self.hidden}"


def _per_row(h):
    """``h`` [s] broadcastable against rows ``(..., n)``: a float, or a ``(...)`` tensor."""
    return h.unsqueeze(-1) if isinstance(h, torch.Tensor) and h.dim() > 0 else h
