"""Parameterizations of the contact stiffness K(q) and damping D(q): positive by construction.

Each is an ``nn.Module`` called as ``param(contacts, facets, q=None, stiffness=None)`` and
returning a non-negative tensor broadcastable to the row shape ``(..., nc·n_d)``. Pick one by
name with :func:`parameterization` (``"constant"``, ``"per_row"``, ``"contact_network"``,
``"state_network"``, ``"relative"``, ``"object_contact_network"``) or pass a float for a
constant; :func:`register_parameterization` adds a name.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from torchcontact.contacts import Contacts
from torchcontact.validation import check_count, check_shape, register


def _log_positive(name: str, value: float) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return math.log(value)


def _inverse_softplus(value: float) -> float:
    _log_positive("value", value)
    return value + math.log(-math.expm1(-value))


def _register_log(module: nn.Module, name: str, log_value: float, learnable: bool) -> None:
    """Store a log-value as a parameter (learned) or a buffer (fixed, still saved)."""
    tensor = torch.tensor(log_value)
    if learnable:
        module.register_parameter(name, nn.Parameter(tensor))
    else:
        module.register_buffer(name, tensor)


class Parameterization(nn.Module):
    """Base class: maps the step's contacts (and optionally q) to per-row values."""

    def forward(
        self,
        contacts: Contacts,
        facets: int,
        q: torch.Tensor | None = None,
        stiffness: torch.Tensor | None = None,
    ) -> torch.Tensor:
        raise NotImplementedError


class Constant(Parameterization):
    """One value for every row, stored as its log so it stays positive while learned."""

    def __init__(self, value: float = 1.0, learnable: bool = True, name: str = "value"):
        super().__init__()
        _register_log(self, "log_value", _log_positive(name, value), learnable)

    @property
    def value(self) -> float:
        """The constant, as a Python float."""
        return float(self.log_value.detach().exp())

    def forward(self, contacts, facets, q=None, stiffness=None) -> torch.Tensor:
        return self.log_value.exp()


class PerRow(Parameterization):
    """A learnable value per dual-cone row (slot × facet): a fixed diagonal K."""

    def __init__(self, rows: int, value: float = 1.0):
        super().__init__()
        if not isinstance(rows, int) or rows < 1:
            raise ValueError(f"rows must be a positive integer, got {rows!r}")
        self.log_value = nn.Parameter(torch.full((rows,), _log_positive("value", value)))

    def forward(self, contacts, facets, q=None, stiffness=None) -> torch.Tensor:
        rows = contacts.slots * facets
        if rows != self.log_value.shape[0]:
            raise ValueError(
                f"contacts have {rows} rows (slots {contacts.slots} × facets {facets}) but this "
                f"PerRow parameterization holds {self.log_value.shape[0]}"
            )
        return self.log_value.exp()


def _mlp(inputs: int, hidden: int, outputs: int, value: float) -> nn.Sequential:
    """Two hidden tanh layers; starts near ``value`` everywhere (small last layer)."""
    check_count("hidden", hidden)
    net = nn.Sequential(
        nn.Linear(inputs, hidden),
        nn.Tanh(),
        nn.Linear(hidden, hidden),
        nn.Tanh(),
        nn.Linear(hidden, outputs),
    )
    with torch.no_grad():
        net[-1].weight.mul_(0.01)
        net[-1].bias.fill_(_inverse_softplus(value))
    return net


class ContactNetwork(Parameterization):
    """K per contact from its features (φ, μ, world normal), shared by the contact's facets.

    Features: ``[φ/scale, μ, n_x, n_y, n_z]``; the normal is taken from ``contacts.frame`` and
    zero when the contacts carry none.
    """

    features = 5

    def __init__(self, hidden: int = 32, value: float = 1.0, distance_scale: float = 0.01):
        super().__init__()
        _log_positive("distance_scale", distance_scale)
        self.distance_scale = distance_scale
        self.net = _mlp(self.features, hidden, 1, value)

    def forward(self, contacts, facets, q=None, stiffness=None) -> torch.Tensor:
        dtype = self.net[0].weight.dtype
        phi = (contacts.phi / self.distance_scale).clamp(-10.0, 10.0).to(dtype)
        if contacts.frame is not None:
            normal = contacts.frame[..., 0, :].to(dtype)
        else:
            normal = phi.new_zeros((*phi.shape, 3))
        features = torch.cat([phi.unsqueeze(-1), contacts.mu.to(dtype).unsqueeze(-1), normal], -1)
        per_contact = F.softplus(self.net(features).squeeze(-1))
        return per_contact.repeat_interleave(facets, dim=-1)


class StateNetwork(Parameterization):
    """K per row from the configuration q: an MLP ``q ↦ (nc·n_d,)`` positive values."""

    def __init__(self, nq: int, rows: int, hidden: int = 64, value: float = 1.0):
        super().__init__()
        check_count("nq", nq)
        check_count("rows", rows)
        self.net = _mlp(nq, hidden, rows, value)

    def forward(self, contacts, facets, q=None, stiffness=None) -> torch.Tensor:
        if q is None:
            raise ValueError("q is required by StateNetwork: pass q=(..., nq) to the model")
        nq = self.net[0].in_features
        check_shape("q", q, f"(..., {nq})", q.dim() >= 1 and q.shape[-1] == nq)
        rows = contacts.slots * facets
        if rows != self.net[-1].out_features:
            raise ValueError(
                f"contacts have {rows} rows but this StateNetwork outputs "
                f"{self.net[-1].out_features}"
            )
        return F.softplus(self.net(q.to(self.net[0].weight.dtype)))


class Relative(Parameterization):
    """Damping as a learnable multiple of the stiffness: D = ratio·K (the paper uses 0.1)."""

    def __init__(self, ratio: float = 0.1, learnable: bool = True):
        super().__init__()
        _register_log(self, "log_ratio", _log_positive("ratio", ratio), learnable)

    @property
    def value(self) -> float:
        """The ratio D/K, as :attr:`Constant.value` is its value."""
        return float(self.log_ratio.detach().exp())

    def forward(self, contacts, facets, q=None, stiffness=None) -> torch.Tensor:
        if stiffness is None:
            raise ValueError("Relative damping needs the stiffness K it scales")
        return self.log_ratio.exp() * stiffness


PARAMETERIZATIONS: dict[str, type[Parameterization]] = {
    "constant": Constant,
    "per_row": PerRow,
    "contact_network": ContactNetwork,
    "state_network": StateNetwork,
    "relative": Relative,
}
"""Parameterizations by name; :mod:`torchcontact.networks` adds ``"object_contact_network"``."""


def register_parameterization(name: str, cls: type[Parameterization]) -> type[Parameterization]:
    """Make ``cls`` buildable by ``name`` in :func:`parameterization`; returns ``cls``.

    ``name`` must be a new non-empty string and ``cls`` a subclass of :class:`Parameterization`.
    """
    register(
        PARAMETERIZATIONS,
        name,
        cls,
        "parameterization",
        lambda c: isinstance(c, type) and issubclass(c, Parameterization),
    )
    return cls


def parameterization(
    spec: Parameterization | float | str, name: str = "spec", **kwargs
) -> Parameterization:
    """Build a parameterization from a module (returned as is), a float (a constant) or a name.

    ``name`` is the argument the spec came from, used in error messages.
    """
    if isinstance(spec, Parameterization):
        return spec
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        if not (math.isfinite(spec) and spec > 0):
            raise ValueError(f"{name} must be a positive finite number, got {spec!r}")
        return Constant(float(spec), **kwargs)
    if isinstance(spec, str) and spec in PARAMETERIZATIONS:
        return PARAMETERIZATIONS[spec](**kwargs)
    raise ValueError(
        f"{name} must be a Parameterization, a positive float or one of "
        f"{sorted(PARAMETERIZATIONS)}, got {spec!r}"
    )
