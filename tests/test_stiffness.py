"""Stiffness/damping parameterizations: positive, learnable, serializable, castable, checked."""

import math

import pytest
import torch
from test_contacts import random_contacts

from torchcontact import (
    PARAMETERIZATIONS,
    ComplementarityFree,
    Constant,
    ContactNetwork,
    PerRow,
    Relative,
    StateNetwork,
    parameterization,
)

F64 = torch.float64
NC, NV, NQ, FACETS = 3, 5, 4, 4
ROWS = NC * FACETS

# Builders of every parameterization for NC contacts, FACETS facets and a state of size NQ.
KINDS = {
    "constant": lambda: Constant(2.0),
    "per_row": lambda: PerRow(ROWS, value=2.0),
    "contact_network": lambda: ContactNetwork(hidden=8, value=2.0),
    "state_network": lambda: StateNetwork(NQ, ROWS, hidden=8, value=2.0),
    "relative": lambda: Relative(0.5),
}


def evaluate(param, contacts, q):
    """The parameterization's per-row values; ``Relative`` scales a fixed stiffness."""
    stiffness = torch.linspace(1.0, 2.0, ROWS, dtype=contacts.phi.dtype)
    return param(contacts, FACETS, q, stiffness)


def inputs(batch=(), dtype=torch.float32):
    return random_contacts(NC, NV, batch, dtype=dtype), torch.randn(*batch, NQ, dtype=dtype)


def test_every_registered_name_is_covered():
    # the object-frame network has tests of its own (test_networks.py)
    assert set(KINDS) | {"object_contact_network"} == set(PARAMETERIZATIONS)


@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("batch", [(), (2,), (2, 3)])
def test_values_are_positive_and_broadcast_to_rows(kind, batch):
    c, q = inputs(batch)
    values = evaluate(KINDS[kind](), c, q)
    torch.broadcast_shapes(values.shape, (*batch, ROWS))
    assert bool((values > 0).all()) and torch.isfinite(values).all()
    expected = torch.tensor(2.0 if kind != "relative" else 0.75)
    torch.testing.assert_close(values.mean(), expected, rtol=0.05, atol=0)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_positive_after_big_negative_steps(kind):
    param = KINDS[kind]()
    c, q = inputs((4,))
    optimizer = torch.optim.Adam(param.parameters(), lr=1.0)
    for _ in range(30):
        optimizer.zero_grad()
        evaluate(param, c, q).mean().backward()
        optimizer.step()
    param.zero_grad()
    values = evaluate(param, c, q)
    assert bool((values > 0).all()) and torch.isfinite(values).all()
    assert values.max() < 1e-2, "the steps should have pushed the values far down"
    # Still learnable: the gradient has not vanished, so a later step can bring them back.
    values.sum().backward()
    grads = [p.grad for p in param.parameters()]
    assert any(bool((g != 0).any()) for g in grads)


@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_a_step_moves_values_toward_the_target(kind, direction):
    param = KINDS[kind]()
    c, q = inputs((4,))
    before = evaluate(param, c, q).detach()
    target = before * math.exp(direction)
    optimizer = torch.optim.Adam(param.parameters(), lr=0.05)
    for _ in range(3):
        optimizer.zero_grad()
        ((evaluate(param, c, q) - target) ** 2).mean().backward()
        optimizer.step()
    after = evaluate(param, c, q).detach()
    assert bool((direction * (after - before) > 0).all())


def test_per_row_rows_learn_independently():
    param = PerRow(ROWS, value=1.0)
    c, _ = inputs()
    target = torch.where(torch.arange(ROWS) % 2 == 0, 3.0, 0.3)
    optimizer = torch.optim.SGD(param.parameters(), lr=0.1)
    ((param(c, FACETS) - target) ** 2).sum().backward()
    optimizer.step()
    after = param(c, FACETS).detach()
    assert bool((after[::2] > 1.0).all()) and bool((after[1::2] < 1.0).all())


def test_contact_network_depends_on_contacts_and_repeats_per_facet():
    param = ContactNetwork(hidden=8)
    with torch.no_grad():
        param.net[-1].weight.mul_(100)  # make the features matter
    c, _ = inputs((2,))
    values = param(c, FACETS)
    assert values.shape == (2, ROWS)
    per_contact = values.unflatten(-1, (NC, FACETS))
    assert torch.equal(per_contact, per_contact[..., :1].expand_as(per_contact))
    assert per_contact[..., 0].unique().numel() == 2 * NC
    frameless = type(c)(c.phi, c.jac_normal, c.jac_tangent, c.mu, c.active)
    assert not torch.equal(param(frameless, FACETS), values)
    extreme = type(c)(c.phi.sign() * 1e3, c.jac_normal, c.jac_tangent, c.mu, c.active)
    assert bool((param(extreme, FACETS) > 0).all())


def _trained(kind):
    """A parameterization moved away from its initial values by one optimizer step."""
    param = KINDS[kind]()
    c, q = inputs((4,))
    optimizer = torch.optim.SGD(param.parameters(), lr=0.3)
    evaluate(param, c, q).square().mean().backward()
    optimizer.step()
    return param, c, q


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_state_dict_round_trip(kind):
    param, c, q = _trained(kind)
    torch.manual_seed(123)
    fresh = KINDS[kind]()
    assert not torch.equal(evaluate(fresh, c, q), evaluate(param, c, q))
    fresh.load_state_dict(param.state_dict())
    assert torch.equal(evaluate(fresh, c, q), evaluate(param, c, q))


@pytest.mark.parametrize("kind", ["constant", "per_row", "contact_network", "state_network"])
def test_model_state_dict_round_trip(kind):
    param, c, q = _trained(kind)
    model = ComplementarityFree(stiffness=param, damping=Relative(0.2), gamma=30.0)
    Q, b = torch.rand(NV) + 0.5, torch.randn(4, NV)
    torch.manual_seed(7)
    fresh = ComplementarityFree(stiffness=KINDS[kind](), damping=Relative(0.1), gamma=30.0)
    fresh.load_state_dict(model.state_dict())
    assert torch.equal(fresh(Q, b, c, 0.05, q), model(Q, b, c, 0.05, q))


def test_constant_exposes_its_value_as_learned():
    param = Constant(2.5)
    assert param.value == pytest.approx(2.5)
    with torch.no_grad():
        param.log_value.add_(torch.log(torch.tensor(2.0)))
    assert param.value == pytest.approx(5.0) and isinstance(param.value, float)


def test_fixed_constant_is_a_buffer():
    param = parameterization(3.0, learnable=False)
    assert isinstance(param, Constant) and list(param.parameters()) == []
    assert "log_value" in param.state_dict()
    assert list(Relative(0.1, learnable=False).parameters()) == []


@pytest.mark.parametrize("kind", ["constant", "per_row", "contact_network", "state_network"])
def test_float64_end_to_end(kind):
    model = ComplementarityFree(stiffness=KINDS[kind](), damping=Relative(0.1), gamma=20.0)
    c, q = inputs((3,))
    Q, b = torch.rand(NV) + 0.5, torch.randn(3, NV)
    v32 = model(Q, b, c, 0.05, q)
    model = model.to(F64)
    assert all(p.dtype == F64 for p in model.parameters())
    c64, q64 = c.to(F64), q.to(F64)
    assert model.stiffness(c64, FACETS, q64).dtype == F64
    v = model(Q.to(F64), b.to(F64), c64, 0.05, q64)
    assert v.dtype == F64
    torch.testing.assert_close(v.float(), v32, rtol=1e-4, atol=1e-5)
    v.square().sum().backward()
    grads = [p.grad for p in model.parameters()]
    assert all(g.dtype == F64 and torch.isfinite(g).all() for g in grads)
    assert any(bool((g != 0).any()) for g in grads)


def test_per_row_rows_mismatch():
    c, _ = inputs()
    with pytest.raises(ValueError, match="PerRow"):
        PerRow(ROWS + 1)(c, FACETS)
    with pytest.raises(ValueError, match="PerRow"):
        PerRow(ROWS)(c, 8)


def test_state_network_needs_q_and_matching_rows():
    c, q = inputs()
    model = ComplementarityFree(stiffness=StateNetwork(NQ, ROWS))
    with pytest.raises(ValueError, match="q is required"):
        model(torch.ones(NV), torch.randn(NV), c, 0.1)
    with pytest.raises(ValueError, match="rows"):
        StateNetwork(NQ, ROWS + 4)(c, FACETS, q)


def test_relative_needs_the_stiffness():
    c, _ = inputs()
    with pytest.raises(ValueError, match="stiffness"):
        Relative(0.1)(c, FACETS)
    with pytest.raises(ValueError, match="stiffness"):
        ComplementarityFree(stiffness=Relative(0.1))(torch.ones(NV), torch.randn(NV), c, 0.1)


BAD_NUMBERS = [0.0, -1.0, math.nan, math.inf, "1.0", None]


@pytest.mark.parametrize("value", BAD_NUMBERS)
def test_bad_constant_values(value):
    with pytest.raises(ValueError, match="value"):
        Constant(value)
    with pytest.raises(ValueError, match="value"):
        PerRow(ROWS, value=value)
    with pytest.raises(ValueError, match="ratio"):
        Relative(value)
    with pytest.raises(ValueError, match="distance_scale"):
        ContactNetwork(distance_scale=value)


@pytest.mark.parametrize("value", BAD_NUMBERS)
def test_bad_network_initial_values(value):
    with pytest.raises(ValueError, match="value"):
        ContactNetwork(value=value)
    with pytest.raises(ValueError, match="value"):
        StateNetwork(NQ, ROWS, value=value)


@pytest.mark.parametrize("size", [0, -2, 2.0, "3"])
def test_bad_sizes(size):
    with pytest.raises(ValueError, match="rows"):
        PerRow(size)
    with pytest.raises(ValueError, match="nq"):
        StateNetwork(size, ROWS)
    with pytest.raises(ValueError, match="rows"):
        StateNetwork(NQ, size)


def test_parameterization_factory():
    constant = parameterization(2.5)
    assert isinstance(constant, Constant)
    torch.testing.assert_close(constant(None, FACETS), torch.tensor(2.5))
    assert isinstance(parameterization(3), Constant)
    assert parameterization(constant) is constant
    for name, cls in PARAMETERIZATIONS.items():
        kwargs = {"rows": ROWS} if name == "per_row" else {}
        kwargs = {"nq": NQ, "rows": ROWS} if name == "state_network" else kwargs
        kwargs = {"facets": FACETS} if name == "object_contact_network" else kwargs
        assert type(parameterization(name, **kwargs)) is cls
    for bad in ("nope", "Constant", True, None, [1.0]):
        with pytest.raises(ValueError, match="per_row"):
            parameterization(bad)
    with pytest.raises(ValueError, match="spec"):
        parameterization(-2.0)
    with pytest.raises(ValueError, match="damping"):
        parameterization(-2.0, name="damping")


def test_relative_exposes_its_ratio_as_constant_does_its_value():
    ratio = Relative(0.25)
    assert ratio.value == pytest.approx(0.25) and isinstance(ratio.value, float)
    with torch.no_grad():
        ratio.log_ratio.add_(torch.log(torch.tensor(2.0)))
    assert ratio.value == pytest.approx(0.5)
