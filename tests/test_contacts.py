"""Contacts: padding, dtype moves, dual-cone rows and the split of row impulses."""

import dataclasses
import math

import pytest
import torch

from torchcontact import Contacts, facet_directions
from torchcontact.contacts import PAD_DISTANCE


def random_contacts(
    nc: int,
    nv: int,
    batch: tuple[int, ...] = (),
    dtype: torch.dtype = torch.float64,
    mu: float | None = None,
    inactive: int = 0,
    generator: torch.Generator | None = None,
) -> Contacts:
    """Random contacts with a frame; the last ``inactive`` slots are padding (non-zero Jacobians
    on purpose, so tests see that the rows are masked); ``mu=None`` draws μ in [0, 1)."""

    def draw(*shape, fn=torch.randn):
        return fn(*batch, *shape, dtype=dtype, generator=generator)

    active = torch.ones(*batch, nc, dtype=torch.bool)
    active[..., nc - inactive :] = False
    return Contacts(
        phi=0.05 * draw(nc),
        jac_normal=draw(nc, nv),
        jac_tangent=draw(nc, 2, nv),
        mu=draw(nc, fn=torch.rand) if mu is None else torch.full((*batch, nc), mu, dtype=dtype),
        active=active,
        frame=torch.linalg.qr(draw(nc, 3, 3)).Q,
        position=draw(nc, 3),
    )


def test_facet_directions_four_are_exact_axes():
    expected = torch.tensor([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]], dtype=torch.float64)
    assert torch.equal(facet_directions(4, torch.float64), expected)


def test_facet_directions_first_built_under_inference_mode_still_serve_autograd():
    from torchcontact.contacts import _facet_directions

    _facet_directions.cache_clear()
    with torch.inference_mode():
        facet_directions(5, torch.float64)  # cached here
    c = random_contacts(3, 4)
    jac_tangent = c.jac_tangent.clone().requires_grad_()
    rows, _, _ = dataclasses.replace(c, jac_tangent=jac_tangent).dual_rows(5)
    rows.sum().backward()  # saves the directions: an inference tensor would be refused
    assert torch.isfinite(jac_tangent.grad).all()


@pytest.mark.parametrize("facets", [3, 4, 8, 16])
def test_facet_directions_are_unit_and_evenly_spaced(facets):
    d = facet_directions(facets, torch.float64)
    assert d.shape == (facets, 2)
    torch.testing.assert_close(d.norm(dim=-1), torch.ones(facets, dtype=torch.float64))
    angles = torch.atan2(d[:, 1], d[:, 0]).remainder(2 * math.pi)
    expected = torch.arange(facets, dtype=torch.float64) * 2 * math.pi / facets
    torch.testing.assert_close(angles, expected)


@pytest.mark.parametrize("facets", [2, 0, -4, 4.0, "4", None])
def test_bad_facets_raise(facets):
    with pytest.raises(ValueError, match="facets"):
        facet_directions(facets)
    with pytest.raises(ValueError, match="facets"):
        random_contacts(2, 3).dual_rows(facets)


@pytest.mark.parametrize("batch", [(), (3,), (2, 3)])
@pytest.mark.parametrize("facets", [4, 8])
def test_dual_rows_shapes_and_contact_major_order(batch, facets):
    nc, nv = 5, 7
    c = random_contacts(nc, nv, batch, inactive=2)
    jac, phi, active = c.dual_rows(facets)
    assert jac.shape == (*batch, nc * facets, nv)
    assert phi.shape == active.shape == (*batch, nc * facets)
    assert active.dtype == torch.bool
    d = facet_directions(facets, torch.float64)
    for i in range(nc):
        for j in range(facets):
            row = i * facets + j
            expected = c.jac_normal[..., i, :] + c.mu[..., i, None] * (
                d[j, 0] * c.jac_tangent[..., i, 0, :] + d[j, 1] * c.jac_tangent[..., i, 1, :]
            )
            expected = expected * c.active[..., i, None]
            torch.testing.assert_close(jac[..., row, :], expected, rtol=1e-14, atol=1e-14)
            assert torch.equal(phi[..., row], c.phi[..., i])
            assert torch.equal(active[..., row], c.active[..., i])


def test_four_facet_rows_are_normal_plus_minus_mu_tangents():
    c = random_contacts(3, 4)
    jac, _, _ = c.dual_rows(4)
    mu = c.mu[:, None]
    n, t1, t2 = c.jac_normal, c.jac_tangent[:, 0], c.jac_tangent[:, 1]
    expected = torch.stack([n + mu * t1, n + mu * t2, n - mu * t1, n - mu * t2], dim=1)
    torch.testing.assert_close(jac, expected.flatten(0, 1), rtol=1e-15, atol=1e-15)


def test_padding_rows_are_zero_and_inactive():
    c = random_contacts(4, 5, (2,), inactive=2)
    jac, phi, active = c.dual_rows(4)
    assert torch.count_nonzero(jac[..., 8:, :]) == 0
    assert torch.count_nonzero(jac[..., :8, :]) == 2 * 8 * 5
    assert not active[..., 8:].any() and active[..., :8].all()
    assert torch.equal(phi, c.phi.repeat_interleave(4, dim=-1))


@pytest.mark.parametrize("batch", [(), (2, 3)])
def test_padded_contacts_append_inert_slots(batch):
    c = random_contacts(4, 5, batch, inactive=1)
    padded = c.padded(7)
    assert padded.slots == 7 and padded.batch_shape == c.batch_shape and c.padded(4) is c
    for name in ("phi", "jac_normal", "jac_tangent", "mu", "active", "frame", "position"):
        kept = getattr(padded, name).narrow(len(batch), 0, 4)  # the slot dimension
        torch.testing.assert_close(kept, getattr(c, name), rtol=0, atol=0)
    assert padded.n_active().equal(c.n_active())
    assert torch.all(padded.phi[..., 4:] == PAD_DISTANCE)
    jac, phi, active = padded.dual_rows(4)
    assert torch.count_nonzero(jac[..., 16:, :]) == 0 and not active[..., 16:].any()
    torch.testing.assert_close(jac[..., :16, :], c.dual_rows(4)[0], rtol=0, atol=0)
    empty = Contacts.empty(3, 5, batch, c.phi.dtype)
    for name in ("phi", "jac_normal", "jac_tangent", "mu", "active"):
        added = getattr(padded, name).narrow(len(batch), 4, 3)
        assert added.dtype == getattr(c, name).dtype and torch.equal(added, getattr(empty, name))
    for name in ("frame", "position"):
        assert not getattr(padded, name).narrow(len(batch), 4, 3).any()
    with pytest.raises(ValueError, match="slots must be an integer ≥ the 4 slots"):
        c.padded(3)


def test_empty_contacts():
    c = Contacts.empty(3, 6, batch=(2, 5), dtype=torch.float64)
    assert c.slots == 3 and c.nv == 6 and c.batch_shape == (2, 5)
    assert c.phi.dtype == torch.float64 and c.active.dtype == torch.bool
    assert torch.equal(c.n_active(), torch.zeros(2, 5, dtype=torch.long))
    assert torch.all(c.phi == PAD_DISTANCE)
    jac, phi, active = c.dual_rows(4)
    assert jac.shape == (2, 5, 12, 6) and torch.count_nonzero(jac) == 0
    assert not active.any()
    none = Contacts.empty(0, 6)
    jac, phi, active = none.dual_rows(8)
    assert jac.shape == (0, 6) and phi.shape == active.shape == (0,)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_to_dtype_keeps_active_bool(dtype):
    c = random_contacts(3, 4, (2,), inactive=1).to(dtype)
    for name in ("phi", "jac_normal", "jac_tangent", "mu", "frame", "position"):
        assert getattr(c, name).dtype == dtype
    assert c.active.dtype == torch.bool
    assert torch.equal(c.n_active(), torch.tensor([2, 2]))
    assert c.to(dtype) is c and c.to("cpu") is c  # nothing to move: no copy, as Tensor.to
    moved = Contacts.empty(2, 3).to("cpu", torch.float64)
    assert moved.frame is None and moved.position is None and moved.phi.dtype == torch.float64
    assert moved.active.dtype == torch.bool


@pytest.mark.parametrize("facets", [4, 8])
def test_impulses_split_rows_into_normal_and_friction(facets):
    c = random_contacts(3, 4, (2,))
    beta = torch.rand(2, 3 * facets, dtype=torch.float64)
    normal, friction = c.impulses(beta, facets)
    assert normal.shape == (2, 3) and friction.shape == (2, 3, 2)
    per_contact = beta.unflatten(-1, (3, facets))
    torch.testing.assert_close(normal, per_contact.sum(-1))
    d = facet_directions(facets, torch.float64)
    expected = c.mu[..., None] * (per_contact[..., None] * d).sum(-2)
    torch.testing.assert_close(friction, expected)
    assert bool((friction.norm(dim=-1) <= c.mu * normal * (1 + 1e-12)).all())


def test_equal_row_impulses_give_pure_normal_impulse():
    c = random_contacts(2, 3, mu=0.7)
    normal, friction = c.impulses(torch.full((8,), 0.25, dtype=torch.float64), 4)
    torch.testing.assert_close(normal, torch.ones(2, dtype=torch.float64))
    torch.testing.assert_close(friction, torch.zeros(2, 2, dtype=torch.float64))


def _fields(c: Contacts) -> dict:
    return {name: getattr(c, name) for name in ("phi", "jac_normal", "jac_tangent", "mu", "active")}


def test_negative_mu_raises():
    fields = _fields(random_contacts(3, 4))
    fields["mu"] = torch.tensor([0.5, -0.1, 0.2], dtype=torch.float64)
    with pytest.raises(ValueError, match="mu"):
        Contacts(**fields)


@pytest.mark.parametrize("name", ["phi", "jac_normal", "jac_tangent"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_geometry_raises(name, bad):
    fields = _fields(random_contacts(3, 4))
    fields[name] = fields[name].clone()
    fields[name].view(-1)[1] = bad
    with pytest.raises(ValueError, match=name):
        Contacts(**fields)


@pytest.mark.parametrize(
    "name, shape",
    [
        ("jac_normal", (4, 4)),
        ("jac_tangent", (3, 3, 4)),
        ("jac_tangent", (3, 2, 5)),
        ("mu", (4,)),
        ("active", (2,)),
        ("frame", (3, 3)),
        ("position", (3, 2)),
    ],
)
def test_mismatched_shapes_raise(name, shape):
    fields = _fields(random_contacts(3, 4))
    dtype = torch.bool if name == "active" else torch.float64
    fields[name] = torch.zeros(shape, dtype=dtype)
    with pytest.raises(ValueError, match=name):
        Contacts(**fields)


def test_active_must_be_bool():
    fields = _fields(random_contacts(3, 4))
    fields["active"] = torch.ones(3)
    with pytest.raises(TypeError, match="active"):
        Contacts(**fields)


FIELDS = ("phi", "jac_normal", "jac_tangent", "mu", "active", "frame", "position")


def _assert_fields(actual: Contacts, expected: dict) -> None:
    for name in FIELDS:
        assert torch.equal(getattr(actual, name), expected[name]), name


@pytest.mark.parametrize(
    "index",
    [
        1,
        -1,
        slice(1, 3),
        (0, 2),
        (slice(None), 1),
        torch.tensor([2, 0, 2]),
        torch.tensor([[True, False, True, True]] * 3),
        [0, 2],
        (Ellipsis, 3),
        (Ellipsis,),
        (None, 1),
    ],
)
def test_indexing_selects_on_the_batch_dimensions(index):
    c = random_contacts(2, 5, batch=(3, 4))
    actual = c[index]
    batch_index = index if isinstance(index, tuple) else (index,)
    batch_index = tuple(torch.tensor(i) if isinstance(i, list) else i for i in batch_index)
    expected_batch = torch.empty(3, 4)[batch_index].shape
    assert actual.batch_shape == expected_batch
    if Ellipsis in batch_index:  # ... covers the batch dimensions only, not a field's own
        at = batch_index.index(Ellipsis)
        batch_index = (
            batch_index[:at] + (slice(None),) * (3 - len(batch_index)) + batch_index[at + 1 :]
        )
    _assert_fields(actual, {name: getattr(c, name)[batch_index] for name in FIELDS})
    assert (actual.slots, actual.nv) == (2, 5)


def test_indexing_matches_per_row_contacts_and_keeps_missing_fields():
    c = random_contacts(3, 4, batch=(5,))
    bare = Contacts(**_fields(c))
    rows = bare[torch.tensor([4, 1])]
    assert rows.frame is None and rows.position is None
    for k, i in enumerate((4, 1)):
        assert torch.equal(rows[k].dual_rows(4)[0], c[i].dual_rows(4)[0])


@pytest.mark.parametrize(
    "batch, index",
    [
        ((), 0),
        ((5,), (0, 1)),
        ((5,), (Ellipsis, 0, 0)),
        ((5,), (Ellipsis, 0, Ellipsis)),
        ((5,), torch.ones(5, 3, dtype=torch.bool)),
    ],
)
def test_indexing_beyond_the_batch_dimensions_raises(batch, index):
    c = random_contacts(3, 4, batch=batch)
    with pytest.raises(IndexError, match=f"index must address only the {len(batch)} batch"):
        c[index]


def test_stack_and_cat_join_along_batch_dimensions():
    items = [random_contacts(3, 4, batch=(2,)) for _ in range(3)]
    for dim, at in ((0, 0), (1, 1), (-1, 1), (-2, 0)):
        stacked = Contacts.stack(items, dim=dim)
        assert stacked.batch_shape == ((3, 2) if at == 0 else (2, 3))
        _assert_fields(
            stacked, {n: torch.stack([getattr(c, n) for c in items], at) for n in FIELDS}
        )
    joined = Contacts.cat([items[0], items[1][:1]])
    assert joined.batch_shape == (3,)
    _assert_fields(
        joined, {n: torch.cat([getattr(items[0], n), getattr(items[1], n)[:1]]) for n in FIELDS}
    )
    grid = Contacts.stack(items, dim=1)
    assert Contacts.cat([grid, grid], dim=-1).batch_shape == (2, 6)
    scalar = Contacts.stack([random_contacts(2, 4), random_contacts(2, 4)])
    assert scalar.batch_shape == (2,)
    _assert_fields(Contacts.stack(list(scalar)), {n: getattr(scalar, n) for n in FIELDS})


def test_stack_and_cat_reject_mismatched_items():
    a = random_contacts(3, 4, batch=(2,))
    with pytest.raises(ValueError, match="items must share slots and nv"):
        Contacts.stack([a, random_contacts(2, 4, batch=(2,))])
    with pytest.raises(ValueError, match="items must share slots and nv"):
        Contacts.cat([a, random_contacts(3, 5, batch=(2,))])
    with pytest.raises(ValueError, match="items must all carry frame"):
        Contacts.cat([a, Contacts(**_fields(a))])
    with pytest.raises(ValueError, match="items must share a batch shape"):
        Contacts.stack([a, a[:1]])
    with pytest.raises(ValueError, match="items must share the batch shape but for dim"):
        Contacts.cat([Contacts.stack([a, a]), a])
    with pytest.raises(ValueError, match="items must have a batch dimension"):
        Contacts.cat([a[0], a[1]])
    with pytest.raises(ValueError, match="items must be a non-empty sequence"):
        Contacts.stack([])
    with pytest.raises(ValueError, match=r"dim must be an integer in \[-2, 1\]"):
        Contacts.stack([a, a], dim=2)
    with pytest.raises(ValueError, match="dim must be an integer"):
        Contacts.cat([a, a], dim=1)


def test_contacts_are_a_pytree():
    from torch.utils import _pytree as pytree

    c = random_contacts(3, 4, batch=(2,))
    leaves, spec = pytree.tree_flatten(c)
    assert len(leaves) == 7
    doubled = pytree.tree_unflatten([2 * x for x in leaves], spec)
    assert isinstance(doubled, Contacts) and torch.equal(doubled.phi, 2 * c.phi)
    bare_leaves, _ = pytree.tree_flatten(Contacts(**_fields(c)))
    assert len(bare_leaves) == 5  # absent frame and position are no leaves
    assert pytree.tree_flatten_with_path(c)[0][0][0] == (pytree.GetAttrKey("phi"),)


def test_vmap_over_contacts_matches_the_batched_velocity():
    """``torch.func.vmap`` maps a function of one step's contacts over a batch of them."""
    from torchcontact import cf_velocity, validate_args

    contacts = random_contacts(3, 6, batch=(5,), inactive=1)
    Q = torch.rand(6, dtype=torch.float64) + 1.0
    b = torch.randn(5, 6, dtype=torch.float64)

    def velocity(c: Contacts, b: torch.Tensor) -> torch.Tensor:
        jac, phi, _ = c.dual_rows(4)
        return cf_velocity(Q, b, jac, phi, 0.1, 200.0)

    with validate_args(False):  # value checks read tensors, which vmap cannot
        mapped = torch.func.vmap(velocity)(contacts, b)
    torch.testing.assert_close(mapped, velocity(contacts, b), rtol=1e-12, atol=1e-12)
    assert mapped.shape == (5, 6)
    bare = Contacts(**_fields(contacts))  # without frame and position
    with validate_args(False):
        torch.testing.assert_close(torch.func.vmap(velocity)(bare, b), mapped, rtol=0, atol=0)


def test_contacts_move_to_meta_and_give_meta_rows():
    """Meta tensors have shapes but no values: the value checks skip themselves."""
    contacts = random_contacts(3, 6, batch=(2,), inactive=1).to("meta")
    assert contacts.phi.is_meta and contacts.active.is_meta
    assert contacts.active.dtype == torch.bool
    jac, phi, active = contacts.dual_rows(4)
    assert jac.is_meta and jac.shape == (2, 12, 6) and phi.shape == active.shape == (2, 12)
    meta = Contacts(**{k: v.to("meta") for k, v in _fields(random_contacts(2, 4)).items()})
    assert meta.slots == 2


def test_compiling_the_rows_and_the_step_warns_of_no_cache(monkeypatch, caplog, recwarn):
    """Dynamo warns when it traces a ``functools.lru_cache``d function: the directions are
    computed afresh while compiling, to the same values."""
    import logging

    import torch._dynamo.utils

    from torchcontact import cf_velocity
    from torchcontact.contacts import _directions

    monkeypatch.setattr(torch._dynamo.utils, "warn_once_cache", set())  # warn as if first
    torch._dynamo.reset()
    contacts = random_contacts(3, 6, batch=(5,), inactive=1)
    Q = torch.rand(6, dtype=torch.float64) + 1.0
    b = torch.randn(5, 6, dtype=torch.float64)

    def velocity(c: Contacts, b: torch.Tensor) -> torch.Tensor:
        jac, phi, _ = c.dual_rows(4)
        return cf_velocity(Q, b, jac, phi, 0.1, 200.0)

    with caplog.at_level(logging.WARNING):
        compiled = torch.compile(velocity, backend="eager", fullgraph=True)(contacts, b)
    torch._dynamo.reset()
    messages = [str(w.message) for w in recwarn] + [r.getMessage() for r in caplog.records]
    assert not [m for m in messages if "lru_cache" in m], messages
    torch.testing.assert_close(compiled, velocity(contacts, b), rtol=0, atol=0)
    for facets in (3, 4, 8):
        fresh = _directions(facets, torch.float64, torch.device("cpu"))
        assert torch.equal(fresh, facet_directions(facets, torch.float64))


def test_static_must_be_a_bool_tensor_of_the_slots_shape():
    fields = dict(
        phi=torch.zeros(2),
        jac_normal=torch.zeros(2, 3),
        jac_tangent=torch.zeros(2, 2, 3),
        mu=torch.zeros(2),
        active=torch.ones(2, dtype=torch.bool),
    )
    with pytest.raises(TypeError, match="static must be a bool tensor"):
        Contacts(**fields, static=torch.zeros(2))
    with pytest.raises(ValueError, match="static"):
        Contacts(**fields, static=torch.zeros(3, dtype=torch.bool))
    with pytest.raises(ValueError, match="all carry static"):
        Contacts.stack([Contacts(**fields), Contacts(**fields, static=torch.ones(2, dtype=bool))])
