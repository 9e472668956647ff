"""The MPC's contact sources that move with its plan: ``redetect`` and ``live``."""

import numpy as np
import pytest
import torch

from torchcontact import RelaxedQP
from torchcontact.environments import environment
from torchcontact.environments.fingertips import CONTROL_BOUND
from torchcontact.environments.presets import MPCSettings
from torchcontact.integrate import integrate
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.sources import FrozenAlongPlan, anchor_states, redetected
from torchcontact.relaxed_qp import paper_relaxation

DT = torch.float64
FINGERTIPS = environment("fingertips")
TARGET = (torch.tensor([0.05, 0.02, 0.03], dtype=DT), torch.tensor([0.0, 0, 0, 1], dtype=DT))


@pytest.fixture(scope="module")
def plant():
    return FINGERTIPS.make_plant("cube")


def _mpc(plant, gaps: str, **options) -> ContactImplicitMPC:
    settings = MPCSettings(compile=False, gaps=gaps, **{"max_iter": 5, **options})
    return ContactImplicitMPC.from_env(FINGERTIPS, plant, settings=settings)


def _state(plant, gap: float):
    """The cube resting 0.5 mm into the ground, tip 0 ``gap`` [m] off its +x face (the tips
    are spheres of 1 cm on a 6 cm cube), the other tips far."""
    tips = np.array([0.04 + gap, 0.0, 0.03, 0.0, 0.2, 0.01, -0.2, 0.0, 0.01])
    plant.reset(np.array([0, 0, 0.0295, 1, 0, 0, 0.0]), tips=tips)
    return torch.as_tensor(plant.state()), plant.contacts(DT)


def _push(horizon: int) -> torch.Tensor:
    """Tip 0 driven 4 mm a step towards the cube (−x)."""
    controls = torch.zeros(1, horizon, 9, dtype=DT)
    controls[..., 0] = -0.004
    return controls


def _along_plan(mpc, q, contacts, controls):
    """The redetected frozen steps along ``controls (T, n_u)`` as the warm start."""
    anchors = anchor_states(mpc, q, contacts, controls)
    steps = mpc.freeze(anchors, redetected(mpc.contacts_at, anchors, contacts))
    return FrozenAlongPlan(steps, anchors)


def test_a_contact_that_is_not_in_the_frozen_set_pushes_in_the_moving_sources(plant):
    """Tip 0 starts 3 mm off the cube, outside detection: the frozen rows have no row for it,
    so the planned cube never moves; re-detected along the warm start, or live, the tip's
    contact appears once it reaches the face and the planned cube is pushed."""
    q, contacts = _state(plant, 0.003)
    assert int(contacts.n_active()) == 4  # the ground only
    controls = _push(4)
    moved = {}
    for gaps in ("propagated", "redetect", "live"):
        mpc = _mpc(plant, gaps)
        step = mpc.freeze(q, contacts)
        if gaps == "redetect":
            step = _along_plan(mpc, q, contacts, controls[0])
        states = mpc.rollout(q, controls, step)
        moved[gaps] = float(q[0] - states[0, -1, 0])  # the cube's −x motion [m]
    assert abs(moved["propagated"]) < 1e-6
    assert moved["redetect"] > 2e-3 and moved["live"] > 2e-3


def test_redetected_steps_are_the_detections_at_their_anchors_moved_to_first_order(plant):
    mpc = _mpc(plant, "redetect")
    q, contacts = _state(plant, -0.001)
    controls = _push(mpc.horizon)[0]
    along = _along_plan(mpc, q, contacts, controls)
    assert along.anchors.shape == (mpc.horizon, mpc.layout.nq)
    torch.testing.assert_close(along.anchors[0], q)
    for t in range(mpc.horizon):
        at_anchor = mpc.freeze(along.anchors[t], mpc.contacts_at(along.anchors[t]).to(DT))
        step = along.at(t, along.anchors[t], mpc.layout)
        torch.testing.assert_close(step.phi[: at_anchor.phi.shape[0]], at_anchor.phi)
    # the cube lifted 0.2 mm off its anchor: the ground rows' φ̃ grow by 0.2 mm
    lifted = along.anchors[2].clone()
    lifted[2] += 2e-4
    step, anchor = along.at(2, lifted, mpc.layout), along.at(2, along.anchors[2], mpc.layout)
    ground = mpc.contacts_at(along.anchors[2]).static
    rows = torch.nonzero(ground).flatten()
    change = (step.phi - anchor.phi).reshape(-1, 4)[rows]  # 4 facet rows a contact
    torch.testing.assert_close(change, torch.full_like(change, 2e-4))


def test_a_live_rollout_is_the_model_at_the_geometrys_contacts_of_each_state(plant):
    mpc = _mpc(plant, "live")
    q, contacts = _state(plant, -0.001)
    controls = 0.004 * torch.randn(
        2, mpc.horizon, 9, dtype=DT, generator=torch.Generator().manual_seed(0)
    )
    states = mpc.rollout(q, controls, mpc.freeze(q, contacts))
    state = q.expand(2, -1)
    for t in range(mpc.horizon):
        Q, b = mpc.system(controls[:, t])
        at = contacts if t == 0 else mpc.contacts_at(state)
        v = mpc.model(Q, b, at, mpc.h, q=state) if t else mpc.freeze(q, contacts).velocity(Q, b)
        state = integrate(state, v, mpc.h, mpc.layout)
        torch.testing.assert_close(states[:, t + 1], state)


def test_the_live_gradient_reaches_the_controls_through_the_geometry(plant):
    mpc = _mpc(plant, "live", horizon=2)
    q, contacts = _state(plant, -0.001)
    step = mpc.freeze(q, contacts)

    def final_cube(controls):
        return mpc.rollout(q, controls[None], step)[0, -1, :3]

    controls = 0.002 * torch.ones(mpc.horizon, 9, dtype=DT)
    controls[:, 0] = -0.003
    controls.requires_grad_(True)
    assert torch.autograd.gradcheck(final_cube, (controls,), eps=1e-7, atol=1e-6)
    (live,) = torch.autograd.grad(final_cube(controls)[0], controls)
    propagated = _mpc(plant, "propagated", horizon=2)
    cube = propagated.rollout(q, controls[None], propagated.freeze(q, contacts))[0, -1, 0]
    (frozen,) = torch.autograd.grad(cube, controls)
    assert not torch.allclose(live, frozen)


@pytest.mark.parametrize("gaps", ["redetect", "live"])
def test_a_plan_with_moving_contacts_keeps_its_box_and_pushes(plant, gaps):
    mpc = _mpc(plant, gaps)
    q, contacts = _state(plant, -0.001)
    for _ in range(2):  # the second solve re-detects along the first plan
        plan = mpc.plan(q, contacts, *TARGET)
        assert plan.controls.shape == (mpc.horizon, 9) and np.isfinite(plan.cost)
        assert bool((plan.controls.abs() <= CONTROL_BOUND + 1e-12).all())


def test_moving_sources_refuse_a_qp_and_need_a_contact_function(plant):
    mpc = _mpc(plant, "propagated")
    qp = RelaxedQP(paper_relaxation(mpc.h))
    args = (mpc.system, qp, mpc.layout, mpc.fingertips, mpc.cost, -1e-3, 1e-3)
    with pytest.raises(ValueError, match="gaps='live' needs the complementarity-free model"):
        ContactImplicitMPC(*args, gaps="live", contacts_at=mpc.contacts_at or (lambda q: None))
    args = (mpc.system, mpc.model, *args[2:])
    with pytest.raises(ValueError, match="gaps='redetect' needs contacts_at"):
        ContactImplicitMPC(*args, gaps="redetect")


def test_live_solves_leave_out_the_pairs_out_of_the_horizons_reach():
    """At the TriFinger's start the finger bases lie ≥ 20 cm from the cube, beyond what three
    steps of its control box move (about 5 cm): a live solve evaluates every group but
    theirs, the ground always."""
    trifinger = environment("trifinger")
    plant = trifinger.make_plant("cube")
    settings = MPCSettings(compile=False, gaps="live", max_iter=2, horizon=3)
    mpc = ContactImplicitMPC.from_env(trifinger, plant, settings=settings)
    kinds = [(g.kind_a, g.kind_b) for g in mpc.contacts_at.groups]
    plan = mpc.plan(torch.as_tensor(plant.state()), plant.contacts(DT), *TARGET)
    assert np.isfinite(plan.cost)
    left_out = [kind for kind, kept in zip(kinds, mpc._reach.groups, strict=True) if not kept]
    assert left_out == [("polytope", "polytope")]
