"""Planners by name: the registry and the L-BFGS planner on a box-constrained quadratic."""

import pytest
import torch

from torchcontact.mpc.planners import LBFGS, PLANNERS, Objective, planner, register_planner

F64 = torch.float64


def quadratic(x, centre):
    """``‖x − centre‖²`` per row and its gradient."""
    return (x - centre).square().sum(-1), 2 * (x - centre)


def test_lbfgs_by_name_finds_the_projected_minimum():
    solver = planner("lbfgs", max_iter=30, memory=5, compile=False)
    assert isinstance(solver, LBFGS)
    centre = torch.tensor([[0.5, -2.0, 0.1]], dtype=F64)
    box = (torch.full((1, 3), -1.0, dtype=F64), torch.full((1, 3), 1.0, dtype=F64))
    result = solver.plan(Objective(quadratic), torch.zeros(1, 3, dtype=F64), box, args=(centre,))
    torch.testing.assert_close(result.x, torch.tensor([[0.5, -1.0, 0.1]], dtype=F64))
    assert result.f.shape == (1,) and result.iterations >= 1 and result.evaluations >= 1


def _centre_from_offset(offset, scale):
    """A ``prepare``: the quadratic's centre from an offset and a scale."""
    return (scale * offset,)


@pytest.mark.parametrize("name", ["lbfgs", "hybrid"])
def test_planners_apply_the_objectives_prepare(name):
    """A planner that says it applies ``Objective.prepare`` plans as with the prepared
    arguments given directly; :meth:`Objective.prepared` returns them with an objective
    that prepares nothing."""
    solver = planner(name, max_iter=30, memory=5, compile=False)
    assert solver.applies_prepare
    offset, scale = torch.tensor([[0.25, -1.0, 0.05]], dtype=F64), torch.tensor(2.0, dtype=F64)
    box = (torch.full((1, 3), -1.0, dtype=F64), torch.full((1, 3), 1.0, dtype=F64))
    x0 = torch.zeros(1, 3, dtype=F64)
    objective = Objective(quadratic, prepare=_centre_from_offset)
    plain, args = objective.prepared((offset, scale))
    assert plain.prepare is None and plain.value_and_grad is quadratic
    torch.testing.assert_close(args[0], scale * offset)
    prepared = solver.plan(objective, x0, box, args=(offset, scale))
    direct = solver.plan(Objective(quadratic), x0, box, args=args)
    torch.testing.assert_close(prepared.x, direct.x, rtol=0, atol=0)
    torch.testing.assert_close(prepared.x, torch.tensor([[0.5, -1.0, 0.1]], dtype=F64))
    assert Objective(quadratic).prepared((offset,)) == (Objective(quadratic), (offset,))


def test_unknown_and_taken_planner_names_are_refused():
    with pytest.raises(ValueError, match="planner must be one of"):
        planner("newton")
    with pytest.raises(ValueError, match="name must be a new planner name"):
        register_planner("lbfgs", LBFGS)
    with pytest.raises(ValueError, match="planner 'not_callable' is not a valid planner"):
        register_planner("not_callable", 3)
    assert "not_callable" not in PLANNERS
