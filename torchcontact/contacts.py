"""Per-step contact geometry, padded to a fixed slot count, and its dual-cone rows."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import torch
from torch.utils import _pytree as pytree

from torchcontact.validation import (
    check_count,
    check_finite,
    check_nonnegative,
    check_same_kind,
    check_shape,
    check_tensor,
)

PAD_DISTANCE = 1.0
"""φ [m] given to empty slots; their Jacobian rows are zero, so they never push."""


def facet_directions(facets: int, dtype=None, device=None) -> torch.Tensor:
    """``(facets, 2)`` unit tangent directions (cos, sin of 2πk/n_d) of the polyhedral cone.

    With ``facets=4`` they are t₁, t₂, −t₁, −t₂. The tensor is cached and shared: read only.
    While ``torch.compile`` traces, they are computed afresh (the same values, the same ops as
    a traced cache miss), as Dynamo cannot trace a cache and warns when asked to.
    """
    if not isinstance(facets, int) or facets < 3:
        raise ValueError(f"facets must be an integer >= 3, got {facets!r}")
    compute = _directions if torch.compiler.is_compiling() else _facet_directions
    return compute(facets, dtype or torch.get_default_dtype(), torch.device(device or "cpu"))


def _directions(facets: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    # A normal tensor even on a first call under inference_mode: the cached one is later used
    # in autograd, which refuses inference tensors.
    with torch.inference_mode(False):
        angles = torch.arange(facets, dtype=torch.float64) * (2 * math.pi / facets)
        directions = torch.stack([torch.cos(angles), torch.sin(angles)], dim=-1)
        # Snap round-off (cos(π/2) = 6e-17) so the 4-facet rows are exactly ±t₁, ±t₂.
        directions = torch.where(directions.abs() < 1e-12, torch.zeros_like(directions), directions)
        return directions.to(dtype=dtype, device=device)


_facet_directions = functools.lru_cache(maxsize=64)(_directions)


@dataclass(frozen=True)
class Contacts:
    """Contacts of one step, padded to ``nc`` slots; every field shares the batch shape ``...``.

    A batched container: ``contacts[index]`` indexes the batch dimensions of every field,
    :meth:`stack` and :meth:`cat` join several, and it is a torch pytree, so
    ``torch.func.vmap`` maps functions of contacts over a batch (with the model's value checks
    off there, ``validate_args(False)``: vmap cannot read tensor values).

    Attributes:
        phi: ``(..., nc)`` signed distance [m], positive when apart.
        jac_normal: ``(..., nc, nv)`` normal Jacobian Jⁿ: ``Jⁿ v`` is the opening speed [m/s].
        jac_tangent: ``(..., nc, 2, nv)`` Jacobians of the two tangent directions t₁, t₂.
        mu: ``(..., nc)`` friction coefficient μ ≥ 0.
        active: ``(..., nc)`` bool, False for padding slots.
        frame: optional ``(..., nc, 3, 3)`` world frame, rows (n, t₁, t₂), for features/plots.
        position: optional ``(..., nc, 3)`` world contact point [m].
        static: optional ``(..., nc)`` bool, True where the contact's other body is fixed in
            the world (the ground, a palm no joint moves): the MPC's hold term counts the
            other contacts as the fingers'.
    """

    phi: torch.Tensor
    jac_normal: torch.Tensor
    jac_tangent: torch.Tensor
    mu: torch.Tensor
    active: torch.Tensor
    frame: torch.Tensor | None = None
    position: torch.Tensor | None = None
    static: torch.Tensor | None = None

    def __post_init__(self) -> None:
        for name in ("phi", "jac_normal", "jac_tangent", "mu", "frame", "position"):
            value = getattr(self, name)
            if value is not None or name not in ("frame", "position"):
                check_tensor(name, value)
        if not isinstance(self.active, torch.Tensor):
            raise TypeError(f"active must be a bool tensor, got {type(self.active).__name__}")
        nc, nv = self.jac_normal.shape[-2:] if self.jac_normal.dim() >= 2 else (-1, -1)
        batch = self.phi.shape[:-1]
        check_shape("phi", self.phi, "(..., nc)", self.phi.dim() >= 1)
        if self.jac_normal.shape[:-1] != self.phi.shape:
            raise ValueError(
                f"phi (..., nc) and jac_normal (..., nc, nv) must agree on (..., nc), got phi "
                f"{tuple(self.phi.shape)} and jac_normal {tuple(self.jac_normal.shape)}"
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
        if self.static is not None:
            if not isinstance(self.static, torch.Tensor):
                raise TypeError(f"static must be a torch.Tensor, got {type(self.static).__name__}")
            same = self.static.shape == self.phi.shape
            check_shape("static", self.static, f"{tuple(self.phi.shape)}", same)
            if self.static.dtype != torch.bool:
                raise TypeError(f"static must be a bool tensor, got {self.static.dtype}")
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
        check_same_kind("phi", {f.name: getattr(self, f.name) for f in fields(self)}, dtype=False)
        for name in ("phi", "jac_normal", "jac_tangent", "frame", "position"):
            if getattr(self, name) is not None:
                check_finite(name, getattr(self, name))
        check_nonnegative("mu", self.mu)

    @classmethod
    def empty(cls, slots: int, nv: int, batch: tuple[int, ...] = (), dtype=None, device=None):
        """All-padding contacts: ``slots`` inactive slots for ``nv`` velocities."""
        check_count("slots", slots, minimum=0)
        check_count("nv", nv)
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
        extra = slots - self.slots
        # the new slots sit at dimension len(batch) of every field: pad that dimension only
        # (one op a field, no re-validation: a solve pads its contacts at every step)
        padded = {}
        for name, x in self._fields().items():
            if x is not None:
                after = x.dim() - len(self.batch_shape) - 1  # dims after the slot dim
                value = PAD_DISTANCE if name == "phi" else 0
                padded[name] = torch.nn.functional.pad(x, (0, 0) * after + (0, extra), value=value)
        return Contacts._unchecked(padded)

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

    @classmethod
    def _unchecked(cls, values: dict[str, torch.Tensor | None]) -> Contacts:
        """Contacts from fields known to be consistent (derived from valid contacts)."""
        contacts = object.__new__(cls)
        for name in _FIELD_NAMES:
            object.__setattr__(contacts, name, values.get(name))
        return contacts

    def _fields(self) -> dict[str, torch.Tensor | None]:
        return {name: getattr(self, name) for name in _FIELD_NAMES}

    def __getitem__(self, index) -> Contacts:
        """The contacts at ``index`` of the batch dimensions ``...``, as in ``phi[index]``.

        ``index``: an int, a slice, None, an integer or boolean tensor (or a tuple of them)
        addressing the batch dimensions only; ``...`` stands for the batch dimensions left.
        """
        index = self._batch_index(index)
        return Contacts._unchecked(
            {name: None if x is None else x[index] for name, x in self._fields().items()}
        )

    def _batch_index(self, index) -> tuple:
        """``index`` as a tuple without Ellipsis, checked to address the batch dims only."""
        items = list(index) if isinstance(index, tuple) else [index]
        used = 0
        for i, item in enumerate(items):
            if item is None or item is Ellipsis or isinstance(item, bool):
                continue  # None and True/False add a dimension, ... is filled in below
            if not isinstance(item, (torch.Tensor, slice)) and not hasattr(item, "__index__"):
                try:  # a list, range or array of indices or of bools
                    items[i] = item = torch.as_tensor(item)
                except (TypeError, ValueError, RuntimeError):
                    raise IndexError(
                        f"index must hold ints, slices, None, ... or tensors, got {item!r}"
                    ) from None
            is_mask = isinstance(item, torch.Tensor) and item.dtype == torch.bool
            used += item.dim() if is_mask else 1
        batch = len(self.batch_shape)
        ellipses = items.count(Ellipsis)
        if ellipses > 1 or used > batch:
            raise IndexError(
                f"index must address only the {batch} batch dimensions "
                f"{tuple(self.batch_shape)} (and hold at most one ...), got {index!r}"
            )
        if ellipses:
            at = items.index(Ellipsis)
            items[at : at + 1] = [slice(None)] * (batch - used)
        return tuple(items)

    @staticmethod
    def _check_joinable(items: Sequence[Contacts]) -> list[Contacts]:
        items = list(items)
        if not items or not all(isinstance(c, Contacts) for c in items):
            raise ValueError("items must be a non-empty sequence of Contacts")
        first = items[0]
        for c in items[1:]:
            if (c.slots, c.nv) != (first.slots, first.nv):
                raise ValueError(
                    f"items must share slots and nv, got {(first.slots, first.nv)} and "
                    f"{(c.slots, c.nv)}: pad them with Contacts.padded first"
                )
            for name in ("frame", "position", "static"):
                if (getattr(c, name) is None) != (getattr(first, name) is None):
                    raise ValueError(f"items must all carry {name} or all lack it")
        return items

    @classmethod
    def _join(cls, items: list[Contacts], join) -> Contacts:
        """Contacts whose every field is ``join`` of the items' fields."""
        return cls._unchecked(
            {
                name: None if x is None else join([getattr(c, name) for c in items])
                for name, x in items[0]._fields().items()
            }
        )

    @staticmethod
    def _join_dim(dim: int, batch: int) -> int:
        if isinstance(dim, bool) or not isinstance(dim, int) or not -batch - 1 <= dim <= batch:
            raise ValueError(f"dim must be an integer in [{-batch - 1}, {batch}], got {dim!r}")
        return dim + batch + 1 if dim < 0 else dim

    @classmethod
    def stack(cls, items: Sequence[Contacts], dim: int = 0) -> Contacts:
        """Stack contacts of one batch shape ``B`` along a new batch dimension ``dim``.

        ``items`` must share ``slots``, ``nv``, the batch shape and which optional fields they
        carry (:meth:`padded` evens out the slots). Negative ``dim`` counts from the end of the
        new batch shape, as in ``torch.stack``.
        """
        items = cls._check_joinable(items)
        batch = items[0].batch_shape
        if any(c.batch_shape != batch for c in items):
            shapes = [tuple(c.batch_shape) for c in items]
            raise ValueError(f"items must share a batch shape to be stacked, got {shapes}")
        at = cls._join_dim(dim, len(batch))
        return cls._join(items, lambda tensors: torch.stack(tensors, at))

    @classmethod
    def cat(cls, items: Sequence[Contacts], dim: int = 0) -> Contacts:
        """Concatenate contacts along the existing batch dimension ``dim``.

        ``items`` must share ``slots``, ``nv``, the other batch dimensions and which optional
        fields they carry. Negative ``dim`` counts from the end of the batch shape.
        """
        items = cls._check_joinable(items)
        batch = len(items[0].batch_shape)
        if batch == 0:
            raise ValueError("items must have a batch dimension to be concatenated along")
        at = cls._join_dim(dim, batch - 1)
        rest = {c.batch_shape[:at] + c.batch_shape[at + 1 :] for c in items}
        if len(rest) != 1 or any(len(c.batch_shape) != batch for c in items):
            shapes = [tuple(c.batch_shape) for c in items]
            raise ValueError(f"items must share the batch shape but for dim {dim}, got {shapes}")
        return cls._join(items, lambda tensors: torch.cat(tensors, at))

    def to(self, *args, **kwargs) -> Contacts:
        """Move/cast the floating fields like ``Tensor.to``; ``active`` keeps its bool dtype."""

        def move(x):
            if x is None:
                return None
            if x.is_floating_point():
                return x.to(*args, **kwargs)
            device = torch.empty(0).to(*args, **kwargs).device
            return x.to(device=device)

        current = self._fields()
        moved = {name: move(x) for name, x in current.items()}
        if all(moved[name] is x for name, x in current.items()):
            return self  # already there: as Tensor.to, no copy (and no re-validation)
        return replace(self, **moved)

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


_FIELD_NAMES = tuple(field.name for field in fields(Contacts))
"""The field names of :class:`Contacts`, in order (``fields()`` is not traced by Dynamo)."""


def _present(contacts: Contacts) -> list[str]:
    return [name for name, x in contacts._fields().items() if x is not None]


def _flatten(contacts: Contacts) -> tuple[list[torch.Tensor], tuple[str, ...]]:
    names = _present(contacts)
    return [getattr(contacts, name) for name in names], tuple(names)


def _flatten_with_keys(contacts: Contacts) -> tuple[list, tuple[str, ...]]:
    names = _present(contacts)
    return [(pytree.GetAttrKey(name), getattr(contacts, name)) for name in names], tuple(names)


def _unflatten(values, names: tuple[str, ...]) -> Contacts:
    # Unchecked: inside vmap the leaves are batched tensors, whose values cannot be read.
    return Contacts._unchecked(dict(zip(names, values, strict=True)))


pytree.register_pytree_node(
    Contacts,
    _flatten,
    _unflatten,
    serialized_type_name="torchcontact.contacts.Contacts",
    flatten_with_keys_fn=_flatten_with_keys,
)
