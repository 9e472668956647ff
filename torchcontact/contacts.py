"""Per-step contact geometry, padded to a fixed slot count, and its dual-cone rows."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields, replace

import torch

from torchcontact.validation import check_finite, check_nonnegative, check_shape, check_tensor

PAD_DISTANCE = 1.0
"""φ [m] given to empty slots; their Jacobian rows are zero, so they never push."""


def facet_directions(facets: int, dtype=None, device=None) -> torch.Tensor:
    """``(facets, 2)`` unit tangent directions (cos, sin of 2πk/n_d) of the polyhedral cone.

    With ``facets=4`` they are t₁, t₂, −t₁, −t₂. The tensor is cached and shared: read only.
    """
    if not isinstance(facets, int) or facets < 3:
        raise ValueError(f"facets must be an integer >= 3, got {facets!r}")
    return _facet_directions(
        facets, dtype or torch.get_default_dtype(), torch.device(device or "cpu")
    )


@functools.lru_cache(maxsize=64)
def _facet_directions(facets: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    # A normal tensor even on a first call under inference_mode: the cached one is later used
    # in autograd, which refuses inference tensors.
    with torch.inference_mode(False):
        angles = torch.arange(facets, dtype=torch.float64) * (2 * math.pi / facets)
        directions = torch.stack([torch.cos(angles), torch.sin(angles)], dim=-1)
        # Snap round-off (cos(π/2) = 6e-17) so the 4-facet rows are exactly ±t₁, ±t₂.
        directions = torch.where(directions.abs() < 1e-12, torch.zeros_like(directions), directions)
        return directions.to(dtype=dtype, device=device)


@dataclass(frozen=True)
class Contacts:
    """Contacts of one step, padded to ``nc`` slots; every field shares the batch shape ``...``.

    Attributes:
        phi: ``(..., nc)`` signed distance [m], positive when apart.
        jac_normal: ``(..., nc, nv)`` normal Jacobian Jⁿ: ``Jⁿ v`` is the opening speed [m/s].
        jac_tangent: ``(..., nc, 2, nv)`` Jacobians of the two tangent directions t₁, t₂.
        mu: ``(..., nc)`` friction coefficient μ ≥ 0.
        active: ``(..., nc)`` bool, False for padding slots.
        frame: optional ``(..., nc, 3, 3)`` world frame, rows (n, t₁, t₂), for features/plots.
        position: optional ``(..., nc, 3)`` world contact point [m].
    """

    phi: torch.Tensor
    jac_normal: torch.Tensor
    jac_tangent: torch.Tensor
    mu: torch.Tensor
    active: torch.Tensor
    frame: torch.Tensor | None = None
    position: torch.Tensor | None = None

    def __post_init__(self) -> None:
        for name in ("phi", "jac_normal", "jac_tangent", "mu"):
            check_tensor(name, getattr(self, name))
        nc, nv = self.jac_normal.shape[-2:] if self.jac_normal.dim() >= 2 else (-1, -1)
        batch = self.phi.shape[:-1]
        check_shape("phi", self.phi, "(..., nc)", self.phi.dim() >= 1)
        check_shape(
            "jac_normal",
            self.jac_normal,
            f"{(*batch, self.phi.shape[-1])} + (nv,)",
            self.jac_normal.shape[:-1] == self.phi.shape,
        )
        check_shape(
            "jac_tangent",
            self.jac_tangent,
            f"{(*batch, nc, 2, nv)}",
            self.jac_tangent.shape == (*batch, nc, 2, nv),
        )
        check_shape("mu", self.mu, f"{tuple(self.phi.shape)}", self.mu.shape == self.phi.shape)
        check_shape(
            "active", self.active, f"{tuple(self.phi.shape)}", self.active.shape == self.phi.shape
        )
        if self.active.dtype != torch.bool:
            raise TypeError(f"active must be a bool tensor, got {self.active.dtype}")
        if self.frame is not None:
            check_shape(
                "frame", self.frame, f"{(*batch, nc, 3, 3)}", self.frame.shape == (*batch, nc, 3, 3)
            )
        if self.position is not None:
            check_shape(
                "position",
                self.position,
                f"{(*batch, nc, 3)}",
                self.position.shape == (*batch, nc, 3),
            )
        for name in ("phi", "jac_normal", "jac_tangent"):
            check_finite(name, getattr(self, name))
        check_nonnegative("mu", self.mu)

    @classmethod
    def empty(cls, slots: int, nv: int, batch: tuple[int, ...] = (), dtype=None, device=None):
        """All-padding contacts: ``slots`` inactive slots for ``nv`` velocities."""
        kw = {"dtype": dtype or torch.get_default_dtype(), "device": device}
        return cls(
            phi=torch.full((*batch, slots), PAD_DISTANCE, **kw),
            jac_normal=torch.zeros((*batch, slots, nv), **kw),
            jac_tangent=torch.zeros((*batch, slots, 2, nv), **kw),
            mu=torch.zeros((*batch, slots), **kw),
            active=torch.zeros((*batch, slots), dtype=torch.bool, device=device),
        )

    def padded(self, slots: int) -> Contacts:
        """These contacts with padding slots appended up to ``slots`` in all (inactive, at
        ``PAD_DISTANCE``, zero Jacobians: they add zero rows to J̃, and no force)."""
        if isinstance(slots, bool) or not isinstance(slots, int) or slots < self.slots:
            raise ValueError(f"slots must be an integer ≥ the {self.slots} slots, got {slots!r}")
        if slots == self.slots:
            return self
        pad = Contacts.empty(
            slots - self.slots, self.nv, self.batch_shape, self.phi.dtype, self.phi.device
        )
        optional = {}
        for name, shape in (("frame", (3, 3)), ("position", (3,))):
            value = getattr(self, name)
            if value is not None:
                filler = value.new_zeros(*self.batch_shape, slots - self.slots, *shape)
                optional[name] = torch.cat([value, filler], dim=-1 - len(shape))
        return Contacts(
            **{
                name: torch.cat(
                    [getattr(self, name), getattr(pad, name)], dim=len(self.batch_shape)
                )
                for name in ("phi", "jac_normal", "jac_tangent", "mu", "active")
            },
            **optional,
        )

    @property
    def slots(self) -> int:
        """Number of slots ``nc`` (active or padding)."""
        return self.phi.shape[-1]

    @property
    def nv(self) -> int:
        """Number of generalized velocities the Jacobians act on."""
        return self.jac_normal.shape[-1]

    @property
    def batch_shape(self) -> torch.Size:
        return self.phi.shape[:-1]

    def n_active(self) -> torch.Tensor:
        """``(...)`` number of active contacts."""
        return self.active.sum(-1)

    def to(self, *args, **kwargs) -> Contacts:
        """Move/cast the floating fields like ``Tensor.to``; ``active`` keeps its bool dtype."""

        def move(x):
            if x is None:
                return None
            if x.is_floating_point():
                return x.to(*args, **kwargs)
            device = torch.empty(0).to(*args, **kwargs).device
            return x.to(device=device)

        return replace(self, **{f.name: move(getattr(self, f.name)) for f in fields(self)})

    def dual_rows(self, facets: int = 4) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The dual-cone rows of the step, ordered contact-major (row = i·n_d + j).

        Returns:
            jac: ``(..., nc·n_d, nv)`` J̃ rows ``Jⁿᵢ + μᵢ(cos θⱼ Jᵗ¹ᵢ + sin θⱼ Jᵗ²ᵢ)``, zero for
                padding slots.
            phi: ``(..., nc·n_d)`` φ̃, each contact distance repeated n_d times.
            active: ``(..., nc·n_d)`` bool mask of rows of active contacts.
        """
        directions = facet_directions(facets, self.phi.dtype, self.phi.device)
        # Padding slots get zero rows: mask Jⁿ and μ (smaller than masking the rows).
        mask = self.active.to(self.phi.dtype)
        normal = (self.jac_normal * mask.unsqueeze(-1)).unsqueeze(-2)
        tangent = directions @ self.jac_tangent  # (..., nc, n_d, nv): one direction per facet
        rows = torch.addcmul(normal, (self.mu * mask)[..., None, None], tangent)
        jac = rows.flatten(-3, -2)
        phi = self.phi.repeat_interleave(facets, dim=-1)
        active = self.active.repeat_interleave(facets, dim=-1)
        return jac, phi, active

    def impulses(
        self, row_impulse: torch.Tensor, facets: int = 4
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Split per-row impulses β ``(..., nc·n_d)`` into contact-frame impulses.

        Returns ``normal (..., nc)`` = Σⱼ βᵢⱼ and ``friction (..., nc, 2)`` = μᵢ Σⱼ βᵢⱼ (cos θⱼ,
        sin θⱼ) in the (t₁, t₂) basis [N·s in full dynamics]. ``‖friction‖ ≤ μ·normal`` holds
        whenever β ≥ 0: every impulse lies in its friction cone.
        """
        directions = facet_directions(facets, row_impulse.dtype, row_impulse.device)
        beta = row_impulse.unflatten(-1, (self.slots, facets))
        normal = beta.sum(-1)
        friction = self.mu.unsqueeze(-1) * (beta @ directions)
        return normal, friction
