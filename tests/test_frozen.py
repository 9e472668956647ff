"""Frozen model steps: the MPC's view of a contact model, equal to the model's own step."""

import pytest
import torch
from test_model import pushed_sphere

from torchcontact import AnitescuQP, ComplementarityFree, Relative, RelaxedQP
from torchcontact.frozen import FrozenComplementarityFree, FrozenRelaxedQP

F64 = torch.float64


@pytest.mark.parametrize("damping", [None, Relative(0.1)])
def test_a_frozen_complementarity_free_step_is_the_models_step(damping):
    Q, b, contacts = pushed_sphere()
    model = ComplementarityFree(stiffness=3.0, damping=damping, gamma=100.0).to(F64)
    frozen = model.freeze(contacts, 0.1)
    assert isinstance(frozen, FrozenComplementarityFree) and frozen.traceable
    assert frozen.linearized(Q, b) is frozen
    torch.testing.assert_close(frozen.velocity(Q, b), model(Q, b, contacts, 0.1), rtol=0, atol=0)
    # batched controls share the frozen rows
    Q2, b2 = Q.expand(5, -1), b.expand(5, -1) * torch.linspace(0, 2, 5, dtype=F64)[:, None]
    v = frozen.velocity(Q2, b2)
    for i in range(5):
        torch.testing.assert_close(v[i], model(Q, b2[i], contacts, 0.1))


def test_advancing_gaps_moves_phi_along_the_normal_rows_only():
    Q, b, contacts = pushed_sphere()
    model = ComplementarityFree(stiffness=1.0, gamma=None).to(F64)
    frozen = model.freeze(contacts, 0.1)
    v = torch.tensor([0.01, 0.0, -0.02, 0.03], dtype=F64)
    moved = frozen.advance_gaps(v)
    expected = contacts.phi + 0.1 * contacts.jac_normal @ v
    torch.testing.assert_close(moved.phi, expected.repeat_interleave(4))
    assert moved.jac is frozen.jac and moved.stiffness is frozen.stiffness


def test_a_frozen_relaxed_qp_solves_before_it_differentiates():
    Q, b, contacts = pushed_sphere()
    model = RelaxedQP().to(F64)
    frozen = model.freeze(contacts, 0.1)
    assert isinstance(frozen, FrozenRelaxedQP) and not frozen.traceable
    linearized = frozen.linearized(Q, b)
    assert linearized.solution is not None
    torch.testing.assert_close(linearized.velocity(Q, b), model(Q, b, contacts, 0.1))
    with pytest.raises(ValueError, match="propagated"):
        frozen.advance_gaps(torch.zeros(4, dtype=F64))


def test_the_osqp_model_cannot_be_frozen():
    _, _, contacts = pushed_sphere()
    with pytest.raises(ValueError, match="AnitescuQP cannot be frozen"):
        AnitescuQP().freeze(contacts, 0.1)
