"""The contact-implicit MPC: rollout, gradients, box, warm start and a closed-loop smoke run."""

import dataclasses
import math
import warnings

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchcontact import AnitescuQP, ComplementarityFree, RelaxedQP
from torchcontact.calibration import SystemCalibration
from torchcontact.environments import environment, tasks
from torchcontact.environments.costs import ManipulationCost
from torchcontact.environments.fingertips import CONTROL_BOUND
from torchcontact.environments.presets import GAPS, MPCSettings
from torchcontact.functional import cf_velocity
from torchcontact.integrate import difference, integrate, object_indices
from torchcontact.model import contact_model
from torchcontact.mpc import background, controller
from torchcontact.mpc.compile_notes import CompilingWarning
from torchcontact.mpc.controller import CONTACT_BUCKET, ContactImplicitMPC
from torchcontact.mpc.planners import LBFGS
from torchcontact.mpc.sources import MOVING
from torchcontact.relaxed_qp import paper_relaxation
from torchcontact.residual import ObjectResidual

DT = torch.float64
FROZEN_SETS = tuple(g for g in GAPS if g not in MOVING)
"""The sources that freeze the contacts detected at the real state."""
FINGERTIPS = environment("fingertips")


@pytest.fixture(scope="module")
def env():
    return FINGERTIPS.make_plant("cube")


def _mpc(plant, model=None, residual_plan="fixed", **options):
    """The fingertips' MPC of ``plant``, eager, with the paper's settings changed by ``options``
    (``model``: None for the paper's at the default K, or a name or model)."""
    solver = MPCSettings(compile=False, **options)
    return ContactImplicitMPC.from_env(
        FINGERTIPS, plant, model, settings=solver, residual_plan=residual_plan
    )


@pytest.fixture(scope="module")
def mpc(env):
    return _mpc(env, max_iter=15)


@pytest.fixture(scope="module")
def propagated_mpc(env):
    return _mpc(env, max_iter=15, gaps="propagated")


@pytest.fixture(scope="module")
def qp_mpc(env):
    """The same MPC through the relaxed QP (the paper's implicit-MPC baseline)."""
    return _mpc(env, "relaxed_qp", max_iter=15)


def _touching_state(env):
    """The cube 0.5 mm into the ground with tip 0 pressed 1 mm into its +x face."""
    tips = np.array([0.039, 0.0, 0.03, 0.0, 0.2, 0.01, -0.2, 0.0, 0.01])
    env.reset(np.array([0, 0, 0.0295, 1, 0, 0, 0.0]), tips=tips)
    return torch.as_tensor(env.state()), env.contacts(DT)


TARGET = (torch.tensor([0.05, 0.02, 0.03], dtype=DT), torch.tensor([0.0, 0, 0, 1], dtype=DT))


def test_the_environments_mpc_has_the_papers_fingertip_settings(env, mpc, qp_mpc):
    q, contacts = _touching_state(env)
    step = mpc.freeze(q, contacts)
    K = FINGERTIPS.default_stiffness
    assert K == 4.64
    torch.testing.assert_close(step.stiffness, torch.full_like(step.stiffness, K))
    torch.testing.assert_close(step.damping, 0.1 * step.stiffness)  # D = 0.1·K
    assert mpc.h == tasks.OBJECT_SETTINGS["cube"].model_step == 0.1
    assert (mpc.horizon, mpc.planner.max_iter, mpc.planner.memory) == (4, 15, 8)
    assert float(mpc.upper.max()) == -float(mpc.lower.min()) == CONTROL_BOUND
    # the paper's κ converted to this QP's scaling at the cube's h
    assert qp_mpc.model.relaxation == pytest.approx(paper_relaxation(qp_mpc.h))


@pytest.mark.parametrize("model", ["mpc", "qp_mpc"])
def test_rollout_equals_stepping_the_model(env, model, request):
    mpc = request.getfixturevalue(model)
    q, contacts = _touching_state(env)
    assert int(contacts.n_active()) == 5  # four ground corners and the tip
    controls = 0.004 * torch.randn(2, mpc.horizon, 9, dtype=DT)
    states = mpc.rollout(q, controls, mpc.freeze(q, contacts))
    assert states.shape == (2, mpc.horizon + 1, 16)
    for b in range(2):
        state = q
        for t in range(mpc.horizon):
            Q, bias = mpc.system(controls[b, t])
            v = mpc.model(Q, bias, contacts, mpc.h, q)
            state = integrate(state, v, mpc.h, mpc.layout)
            torch.testing.assert_close(states[b, t + 1], state)


def _momentum_mpc(env, momentum=1.5, **options):
    """The fingertips' MPC with a model whose calibration carries the object's momentum."""
    calibration = SystemCalibration(9, ("object_momentum",)).double()
    with torch.no_grad():
        calibration.log_object_momentum.fill_(math.log(momentum))
    model = ComplementarityFree(FINGERTIPS.default_stiffness, calibration=calibration)
    return _mpc(env, model, **{"max_iter": 5, **options})


@pytest.mark.parametrize("gaps", FROZEN_SETS)
def test_a_momentum_rollout_chains_the_objects_displacement(env, gaps):
    mpc = _momentum_mpc(env, gaps=gaps)
    assert mpc.carries_momentum and float(mpc.system.object_momentum) == pytest.approx(1.5)
    q, contacts = _touching_state(env)
    step = mpc.freeze(q, contacts)
    controls = 0.004 * torch.randn(2, mpc.horizon, 9, dtype=DT)
    moved = torch.tensor([0.003, -0.002, 0.0, 0.0, 0.0, 0.05], dtype=DT)
    states = mpc.rollout(q, controls, step, moved)
    rows = mpc.system.object_dofs
    state, displacement = q.expand(2, -1), moved
    for t in range(mpc.horizon):
        v = step.velocity(*mpc.system(controls[:, t], object_displacement=displacement))
        state = integrate(state, v, mpc.h, mpc.layout)
        displacement = mpc.h * v[:, rows]
        torch.testing.assert_close(states[:, t + 1], state)
        if gaps == "propagated":
            step = step.advance_gaps(v)
    at_rest = mpc.rollout(q, controls, mpc.freeze(q, contacts))
    assert not torch.allclose(states[:, 1], at_rest[:, 1])


def test_a_relaxed_qp_refuses_a_system_carrying_momentum(env):
    """The QP's step is solved at all planned steps before the rollout, which momentum chains:
    refused when built, not failing inside the first plan."""
    mpc = _momentum_mpc(env)
    qp = RelaxedQP(paper_relaxation(mpc.h))
    with pytest.raises(ValueError, match="system carries the object's momentum.*RelaxedQP"):
        ContactImplicitMPC(mpc.system, qp, mpc.layout, mpc.fingertips, mpc.cost, -1e-3, 1e-3)


@pytest.mark.parametrize("gaps", FROZEN_SETS)
def test_a_residual_is_applied_at_every_planned_state(env, gaps):
    """A model with an object residual rolls each step out as the model's own forward at that
    state, the contacts frozen; a plan through it (``residual_plan="full"``) keeps its box."""
    model = _residual_model()
    mpc = _mpc(env, model, "full", max_iter=5, gaps=gaps)
    q, contacts = _touching_state(env)
    step = mpc.freeze(q, contacts)
    controls = 0.004 * torch.randn(2, mpc.horizon, 9, dtype=DT)
    states = mpc.rollout(q, controls, step)
    state = q.expand(2, -1)
    for t in range(mpc.horizon):
        Q, b = mpc.system(controls[:, t])
        v = model(Q, b, contacts.to(DT), mpc.h, q=state) if t == 0 or gaps == "frozen" else None
        if v is None:  # propagated gaps: the frozen step's advanced φ̃, then the residual
            v = model.residual(state, b, step.velocity(Q, b), mpc.h)
        state = integrate(state, v, mpc.h, mpc.layout)
        torch.testing.assert_close(states[:, t + 1], state)
        if gaps == "propagated":
            step = step.advance_gaps(v)
    plain = _mpc(env, max_iter=5, gaps=gaps)
    without = plain.rollout(q, controls, plain.freeze(q, contacts))
    assert not torch.allclose(states[:, 1], without[:, 1])
    plan = mpc.plan(q, contacts, *TARGET)
    assert bool((plan.controls.abs() <= CONTROL_BOUND + 1e-12).all())


def _residual_model(seed: int = 0) -> ComplementarityFree:
    """The fingertips' default paper model with a random (not zero) object residual."""
    model = contact_model("paper", stiffness=FINGERTIPS.default_stiffness).double()
    model.residual = ObjectResidual(
        *object_indices(FINGERTIPS.layout.joints), 16, 15, hidden=8
    ).double()
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in model.residual.parameters():
            parameter.copy_(0.3 * torch.randn(parameter.shape, generator=generator, dtype=DT))
    return model


@pytest.mark.parametrize("gaps", FROZEN_SETS)
def test_a_fixed_residual_plans_with_its_corrections_along_the_warm_start(env, gaps):
    """``residual_plan="fixed"``: along the warm start the plan's states are the residual's
    own; elsewhere its corrections are constants, so the plan's gradient is the contact
    model's; each solve evaluates them along its own warm start."""
    model = _residual_model()
    mpc = _mpc(env, model, max_iter=5, gaps=gaps)
    assert mpc.residual_plan == "fixed" and mpc.fixes_residual
    q, contacts = _touching_state(env)
    step = mpc.freeze(q, contacts)
    warm = 0.003 * torch.randn(mpc.horizon, 9, dtype=DT)
    corrections = mpc.residual_corrections(q, warm, step)
    assert corrections.shape == (mpc.horizon, 15)
    assert bool((corrections[:, 6:] == 0).all()) and bool(corrections[:, :6].abs().gt(0).any())
    with torch.no_grad():
        full = mpc.rollout(q, warm[None], step)
    torch.testing.assert_close(mpc.rollout(q, warm[None], step, None, corrections), full)
    controls = 0.004 * torch.randn(2, mpc.horizon, 9, dtype=DT, requires_grad=True)
    cost = mpc.objective(controls, q, step, *TARGET, corrections).sum()
    (grad,) = torch.autograd.grad(cost, controls)
    plain = _mpc(env, max_iter=5, gaps=gaps)
    plain_step = plain.freeze(q, contacts)
    shifted = plain.rollout(q, controls, plain_step, None, corrections)
    torch.testing.assert_close(mpc.rollout(q, controls, step, None, corrections), shifted)
    (plain_grad,) = torch.autograd.grad(
        plain.cost(*_pose_and_tips(plain, shifted), controls, *TARGET).sum(), controls
    )
    torch.testing.assert_close(grad, plain_grad)
    for _ in range(2):  # the first solve from zero, the second from the shifted plan
        expected = mpc.residual_corrections(q, mpc._warm.reshape(mpc.horizon, -1), step)
        plan = mpc.plan(q, contacts, *TARGET)
        with torch.no_grad():
            planned = mpc.objective(plan.controls[None], q, step, *TARGET, expected)
        assert float(planned[0]) == pytest.approx(plan.cost, rel=1e-9)
        assert bool((plan.controls.abs() <= CONTROL_BOUND + 1e-12).all())


def _pose_and_tips(mpc, states):
    """The object's position and quaternion and the fingertips of ``states``, as the cost
    takes them."""
    pose = mpc.layout.object_pose(states)
    return pose[..., :3], pose[..., 3:], mpc.fingertips(states)


def test_the_residual_plan_is_checked(env):
    with pytest.raises(ValueError, match="residual_plan must be one of"):
        _mpc(env, residual_plan="exact")
    q, contacts = _touching_state(env)
    mpc = _mpc(env, max_iter=5)
    assert not mpc.fixes_residual
    with pytest.raises(ValueError, match="needs a model with a residual"):
        mpc.residual_corrections(q, torch.zeros(mpc.horizon, 9, dtype=DT), mpc.freeze(q, contacts))


def test_the_mpc_plans_from_the_objects_last_displacement(env):
    """The first plan of an episode sees the object at rest; the next one the displacement
    between the two states it planned from; reset forgets it."""
    mpc = _momentum_mpc(env)
    q, contacts = _touching_state(env)
    moved_q = q.clone()
    moved_q[:2] += torch.tensor([0.002, -0.001], dtype=DT)
    assert torch.equal(mpc.displacement(q, q), torch.zeros(6, dtype=DT))  # exactly at rest
    torch.testing.assert_close(
        mpc.displacement(q, moved_q),
        difference(q, moved_q, 1.0, mpc.layout)[mpc.system.object_dofs],
    )
    for start, previous in ((q, q), (moved_q, q)):
        plan = mpc.plan(start, contacts, *TARGET)
        with torch.no_grad():
            frozen = mpc.freeze(start, contacts)
            cost = mpc.objective(plan.controls[None], start, frozen, *TARGET, previous)
            moved = mpc.displacement(previous, start)
            states = mpc.rollout(start, plan.controls[None], frozen, moved)
        assert float(cost[0]) == pytest.approx(plan.cost, rel=1e-9)
        assert not torch.equal(states, mpc.rollout(start, plan.controls[None], frozen, moved + 1))
    mpc.reset()
    plan = mpc.plan(moved_q, contacts, *TARGET)
    with torch.no_grad():
        cost = mpc.objective(plan.controls[None], moved_q, mpc.freeze(moved_q, contacts), *TARGET)
    assert float(cost[0]) == pytest.approx(plan.cost, rel=1e-9)


def test_an_episodes_first_plan_passes_a_copy_of_its_state_as_the_previous_one(env):
    """Not the state itself: a compiled graph is specialised to which inputs alias, and one
    graph serves an episode's first plan and the later ones."""
    mpc = _momentum_mpc(env)
    q, _ = _touching_state(env)
    (previous,) = mpc._previous(q)
    assert torch.equal(previous, q) and previous is not q
    later = q + 0.001
    (previous,) = mpc._previous(later)
    assert previous is q
    mpc.reset()
    assert mpc._previous(later)[0] is not later


def test_propagated_gaps_follow_the_models_own_motion(env):
    """Each step sees φ̃ advanced along the frozen normal rows by the steps before it; the first
    step, and every step with frozen gaps, sees the detected distances."""
    frozen, propagated = _mpc(env), _mpc(env, gaps="propagated")
    q, contacts = _touching_state(env)
    step = propagated.freeze(q, contacts)
    normal = step.normal
    torch.testing.assert_close(normal[::4], contacts.jac_normal * contacts.active.unsqueeze(-1))
    controls = 0.004 * torch.randn(2, propagated.horizon, 9, dtype=DT)
    states = propagated.rollout(q, controls, step)
    Q, bias = propagated.system(controls)
    gap = step.phi.expand(2, -1)
    for t in range(propagated.horizon):
        v = cf_velocity(
            Q, bias[:, t], step.jac, gap, propagated.h, step.stiffness, step.damping, step.gamma
        )
        torch.testing.assert_close(
            states[:, t + 1], integrate(states[:, t], v, propagated.h, FINGERTIPS.layout)
        )
        torch.testing.assert_close(step.advance_gaps(v).phi, step.phi + propagated.h * v @ normal.T)
        gap = gap + propagated.h * v @ normal.T
    first = frozen.rollout(q, controls, frozen.freeze(q, contacts))
    torch.testing.assert_close(states[:, 1], first[:, 1])
    assert not torch.allclose(states[:, -1], first[:, -1])


def test_propagated_gaps_release_a_tip_the_plan_pulls_away(env):
    """Tip 0 pressed 1 mm into the cube, then pulled 5 mm away per step: frozen gaps keep
    pushing the cube every step, propagated ones stop once the modelled gap has opened."""
    q, contacts = _touching_state(env)
    controls = torch.zeros(1, 4, 9, dtype=DT)
    controls[..., 0] = 0.005  # +x: away from the cube's +x face
    pushes = {}
    for gaps in FROZEN_SETS:
        mpc = _mpc(env, gaps=gaps)
        states = mpc.rollout(q, controls, mpc.freeze(q, contacts))
        pushes[gaps] = (states[0, 2:, 0] - states[0, 1:-1, 0]).abs().sum()
    assert float(pushes["propagated"]) < 0.1 * float(pushes["frozen"])


def test_propagated_gaps_are_for_the_complementarity_free_model(env, mpc):
    q, contacts = _touching_state(env)
    qp = _mpc(env, "relaxed_qp", max_iter=2, gaps="propagated")
    with pytest.raises(ValueError, match="gaps"):
        qp.plan(q, contacts, *TARGET)
    with pytest.raises(ValueError, match="gaps"):
        ContactImplicitMPC(
            mpc.system,
            mpc.model,
            mpc.layout,
            mpc.fingertips,
            mpc.cost,
            -1e-3,
            1e-3,
            gaps="updated",
        )
    with pytest.raises(ValueError, match="gaps"):
        MPCSettings(gaps="updated")


@pytest.mark.parametrize("model", ["mpc", "propagated_mpc", "qp_mpc"])
def test_value_and_grad_matches_the_autograd_tape_and_finite_differences(env, model, request):
    mpc = request.getfixturevalue(model)
    q, contacts = _touching_state(env)
    frozen = mpc.freeze(q, contacts)
    controls = (0.004 * torch.randn(3, mpc.horizon, 9, dtype=DT)).requires_grad_(True)
    cost, grad = mpc.value_and_grad(controls.detach(), q, frozen, *TARGET)
    taped = mpc.objective(controls, q, frozen, *TARGET)  # the QP solved inside the tape
    (taped_grad,) = torch.autograd.grad(taped.sum(), controls)
    torch.testing.assert_close(cost, taped.detach())
    torch.testing.assert_close(grad, taped_grad)
    direction = torch.randn_like(controls)
    eps = 1e-7
    plus = mpc.objective(controls.detach() + eps * direction, q, frozen, *TARGET)
    minus = mpc.objective(controls.detach() - eps * direction, q, frozen, *TARGET)
    torch.testing.assert_close(
        (plus - minus) / (2 * eps), (grad * direction).sum((-1, -2)), rtol=1e-5, atol=1e-7
    )


@pytest.mark.parametrize("model", ["mpc", "qp_mpc"])
def test_the_value_alone_equals_value_and_grads_value(env, model, request):
    """Sampling planners ask for the cost alone: the same numbers, the QP linearized alike."""
    mpc = request.getfixturevalue(model)
    q, contacts = _touching_state(env)
    frozen = mpc.freeze(q, contacts)
    controls = 0.004 * torch.randn(5, mpc.horizon, 9, dtype=DT)
    cost, _ = mpc.value_and_grad(controls, q, frozen, *TARGET)
    torch.testing.assert_close(mpc.value(controls, q, frozen, *TARGET), cost)


def test_qp_plan_stays_in_its_box_and_lowers_the_cost_from_the_warm_start(env, qp_mpc):
    q, contacts = _touching_state(env)
    qp_mpc.reset()
    frozen = qp_mpc.freeze(q, contacts)
    still = torch.zeros(1, qp_mpc.horizon, 9, dtype=DT)
    warm, _ = qp_mpc.value_and_grad(still, q, frozen, *TARGET)
    plan = qp_mpc.plan(q, contacts, *TARGET)
    assert bool((plan.controls.abs() <= CONTROL_BOUND).all())
    assert plan.cost < 0.99 * float(warm[0])
    assert plan.iterations > 0 and np.isfinite(plan.cost)


def test_qp_mpc_keeps_a_resting_cube_within_a_millimetre_per_step(env, qp_mpc):
    """The paper's κ converted to this QP's scaling: unconverted, 5e-4 N·m lifts the cube."""
    env.reset(np.array([0, 0, 0.0299, 1, 0, 0, 0.0]))
    q, contacts = torch.as_tensor(env.state()), env.contacts(DT)
    assert int(contacts.n_active()) == 4
    still = torch.zeros(1, qp_mpc.horizon, 9, dtype=DT)
    states = qp_mpc.rollout(q, still, qp_mpc.freeze(q, contacts))
    assert float((states[0, 1:, 2] - states[0, :-1, 2]).abs().max()) < 1e-3


def test_the_mpc_refuses_models_it_cannot_differentiate(env, mpc):
    q, contacts = _touching_state(env)
    osqp = ContactImplicitMPC(
        mpc.system, AnitescuQP(), mpc.layout, mpc.fingertips, mpc.cost, -1e-3, 1e-3
    )
    with pytest.raises(ValueError, match="cannot be frozen"):  # OSQP has no gradient
        osqp.plan(q, contacts, *TARGET)
    with pytest.raises(ValueError, match="model must be a ContactModel"):
        ContactImplicitMPC(
            mpc.system, torch.nn.Identity(), mpc.layout, mpc.fingertips, mpc.cost, -1e-3, 1e-3
        )
    with pytest.raises(ValueError, match="must be one of"):
        _mpc(env, "osqp")


@settings(max_examples=12, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    task=st.sampled_from(["rotation", "flip", "in-air"]),
    push=st.floats(-0.03, 0.03),
)
def test_planned_controls_never_leave_their_box(env, mpc, seed, task, push):
    initial, target = tasks.sample(task, "cube", seed)
    tips = np.array([0.03 + 0.01 + push, 0, 0.03, 0, 0.2, 0.01, -0.2, 0, 0.01])
    env.reset(initial, target, tips=tips)
    mpc.reset()
    for _ in range(2):
        plan = mpc.plan(
            torch.as_tensor(env.state()),
            env.contacts(DT),
            torch.as_tensor(target[:3]),
            torch.as_tensor(target[3:]),
        )
        assert plan.controls.shape == (mpc.horizon, 9)
        assert bool((plan.controls.abs() <= CONTROL_BOUND).all())
        assert np.isfinite(plan.cost)


def test_warm_start_is_the_shifted_plan(env, mpc):
    q, contacts = _touching_state(env)
    mpc.reset()
    target = (torch.tensor([0.05, 0.0, 0.03], dtype=DT), torch.tensor([1.0, 0, 0, 0], dtype=DT))
    plan = mpc.plan(q, contacts, *target)
    shifted = torch.cat([plan.controls[1:], plan.controls[-1:]]).reshape(1, -1)
    torch.testing.assert_close(mpc._warm, shifted)
    mpc.reset()
    assert not mpc._warm.any()


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
@pytest.mark.parametrize("gaps", FROZEN_SETS)
def test_compiled_plan_matches_the_eager_plan(env, gaps):
    """Compiled, the objective is traced into the L-BFGS rounds (several per compiled call)
    and the start into a call of its own, with the closed form's freeze traced into the start
    (an ``Objective.prepare``): the same freeze bit for bit, and the same plans as eager,
    plan after warm-started plan."""
    q, contacts = _touching_state(env)
    options = {"horizon": 2, "max_iter": 8, "gaps": gaps}
    eager = _mpc(env, **options)
    compiled = ContactImplicitMPC.from_env(
        FINGERTIPS, env, settings=MPCSettings(compile=True, **options)
    )
    assert compiled.compiled and compiled.planner.compile
    for a, b in zip(compiled.freeze(q, contacts), eager.freeze(q, contacts), strict=True):
        assert a == b if not torch.is_tensor(a) else torch.equal(a, b)
    for _ in range(3):
        expected, plan = eager.plan(q, contacts, *TARGET), compiled.plan(q, contacts, *TARGET)
        torch.testing.assert_close(plan.controls, expected.controls, rtol=0, atol=1e-10)
        assert plan.iterations == expected.iterations and plan.iterations > 0


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_a_plan_that_compiles_says_so_once_and_marks_its_graph(env, tmp_path, monkeypatch):
    """A Python user's first compiled ``plan()`` of a graph this machine's cache lacks warns
    that it compiles and how to skip it; it then marks the graph, so neither a later plan nor
    another process (a fresh record of the graphs met) warns again (the graph of the test
    above, cached)."""
    monkeypatch.setattr(background, "_marks", lambda: tmp_path)
    monkeypatch.setattr(controller, "_GRAPHS_MET", set())
    q, contacts = _touching_state(env)
    settings = MPCSettings(compile=True, horizon=2, max_iter=8, gaps="frozen")
    mpc = ContactImplicitMPC.from_env(FINGERTIPS, env, settings=settings)
    with pytest.warns(CompilingWarning, match="compile=False") as caught:
        mpc.plan(q, contacts, *TARGET)
    assert "12 contact slots" in str(caught[0].message) and len(caught) == 1
    assert caught[0].filename == __file__  # points at the caller's plan()
    assert len(list(tmp_path.iterdir())) == 1
    monkeypatch.setattr(controller, "_GRAPHS_MET", set())
    again = ContactImplicitMPC.from_env(FINGERTIPS, env, settings=settings)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CompilingWarning)
        mpc.plan(q, contacts, *TARGET)
        again.plan(q, contacts, *TARGET)


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_warming_up_compiles_and_marks_the_graph_and_leaves_the_mpc_as_it_was(
    env, tmp_path, monkeypatch
):
    """``warm_up`` compiles (here: loads, the graph of the tests above) and marks the graph a
    plan would run, says whether the cache lacked it, and changes no warm start."""
    monkeypatch.setattr(background, "_marks", lambda: tmp_path)
    q, contacts = _touching_state(env)
    settings = MPCSettings(compile=True, horizon=2, max_iter=8, gaps="frozen")
    mpc = ContactImplicitMPC.from_env(FINGERTIPS, env, settings=settings, background_compile=True)
    assert mpc.warm_up(q, contacts, *TARGET) and not mpc.compiling
    assert not mpc._warm.any() and mpc._last_q is None
    assert not mpc.warm_up(q, contacts, *TARGET)  # marked now
    assert mpc.plan(q, contacts, *TARGET).compiled  # from its first plan
    with pytest.raises(ValueError, match="compile=True"):
        _mpc(env, horizon=2, max_iter=8, gaps="frozen").warm_up(q, contacts, *TARGET)


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_a_compiled_plan_works_out_a_fixed_residual_as_eager(env):
    """The fixed residual's corrections are traced with the freeze into the compiled start:
    the same plans as eager, plan after warm-started plan."""
    q, contacts = _touching_state(env)
    options = {"horizon": 2, "max_iter": 8}
    eager = _mpc(env, _residual_model(), **options)
    compiled = ContactImplicitMPC.from_env(
        FINGERTIPS, env, _residual_model(), settings=MPCSettings(compile=True, **options)
    )
    assert compiled.fixes_residual
    for _ in range(3):
        expected, plan = eager.plan(q, contacts, *TARGET), compiled.plan(q, contacts, *TARGET)
        torch.testing.assert_close(plan.controls, expected.controls, rtol=0, atol=1e-10)
        assert plan.iterations == expected.iterations and plan.iterations > 0


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_a_traced_objective_works_out_the_objects_displacement_as_eager(env):
    """With momentum the objective takes the previous plan's state and works the object's
    displacement out itself, which the MPC traces into its compiled graphs."""
    mpc = _momentum_mpc(env, horizon=2)
    q, contacts = _touching_state(env)
    previous = q.clone()
    previous[:2] -= torch.tensor([0.002, -0.001], dtype=DT)
    frozen = mpc.freeze(q, contacts)
    controls = 0.003 * torch.randn(3, 2, 9, dtype=DT, generator=torch.Generator().manual_seed(0))
    traced = torch.compile(mpc.objective, dynamic=False, fullgraph=True)
    cost = traced(controls, q, frozen, *TARGET, previous)
    torch.testing.assert_close(cost, mpc.objective(controls, q, frozen, *TARGET, previous))
    at_rest = mpc.objective(controls, q, frozen, *TARGET, q)
    assert not torch.allclose(cost, at_rest)  # the displacement changes the plan's cost


@pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")  # torch's own
def test_a_background_compile_plans_eagerly_until_its_graph_is_ready(env, tmp_path, monkeypatch):
    """With ``background_compile`` the first plan is the eager MPC's, bit for bit, while a
    child compiles the graph (the settings of the test above: its graph is in the cache); once
    the child is done, plans are the compiled graph's, and the graph is marked as compiled."""
    monkeypatch.setattr(background, "_marks", lambda: tmp_path)
    q, contacts = _touching_state(env)
    settings = MPCSettings(horizon=2, max_iter=8, gaps="frozen")
    eager = _mpc(env, horizon=2, max_iter=8, gaps="frozen")
    mpc = ContactImplicitMPC.from_env(FINGERTIPS, env, settings=settings, background_compile=True)
    first, expected = mpc.plan(q, contacts, *TARGET), eager.plan(q, contacts, *TARGET)
    assert not first.compiled and mpc.compiling
    assert torch.equal(first.controls, expected.controls)
    mpc.wait_for_compile()
    assert not mpc.compiling and [p.name for p in tmp_path.iterdir() if not p.suffix] == [
        mpc._graph_key(contacts.padded(mpc.padded_slots(contacts.slots)))
    ]
    second, expected = mpc.plan(q, contacts, *TARGET), eager.plan(q, contacts, *TARGET)
    assert second.compiled
    torch.testing.assert_close(second.controls, expected.controls, rtol=0, atol=1e-10)


def test_a_planner_passed_in_is_the_one_that_plans(env):
    """``from_env`` builds L-BFGS from the settings unless given a planner."""
    q, contacts = _touching_state(env)
    few = LBFGS(max_iter=2)
    mpc = ContactImplicitMPC.from_env(
        FINGERTIPS, env, planner=few, settings=MPCSettings(max_iter=30, compile=False)
    )
    assert mpc.planner is few
    assert 0 < mpc.plan(q, contacts, *TARGET).iterations <= 2


def test_padding_slots_do_not_change_the_plan(env):
    """The plan pads contacts to a multiple of CONTACT_BUCKET slots; more padding changes
    nothing but rounding."""
    q, contacts = _touching_state(env)
    mpc = _mpc(env, horizon=2, max_iter=8)
    plan = mpc.plan(q, contacts, *TARGET)
    mpc.reset()
    padded = mpc.plan(q, contacts.padded(contacts.slots + CONTACT_BUCKET + 1), *TARGET)
    torch.testing.assert_close(padded.controls, plan.controls, rtol=0, atol=1e-12)
    assert padded.iterations == plan.iterations


def test_closed_loop_moves_the_cube_toward_its_target(env, mpc):
    """120 MPC steps of cube rotation (seed 1): the pose error shrinks in position and angle."""
    initial, target = FINGERTIPS.sample(env, "rotation", 1)
    env.reset(initial, target)
    mpc.reset()
    start_pos = tasks.position_error(initial[:3], target[:3])
    start_angle = tasks.angle_error(initial[3:], target[3:])
    for _ in range(120):
        plan = mpc.plan(
            torch.as_tensor(env.state()),
            env.contacts(DT),
            torch.as_tensor(target[:3]),
            torch.as_tensor(target[3:]),
        )
        env.step(plan.control.numpy())
    final = env.state()
    assert tasks.position_error(final[:3], target[:3]) < 0.5 * start_pos
    assert tasks.angle_error(final[3:7], target[3:]) < start_angle


def test_bad_arguments_name_themselves(env, mpc):
    with pytest.raises(ValueError, match="horizon"):
        ContactImplicitMPC(
            mpc.system, mpc.model, mpc.layout, mpc.fingertips, mpc.cost, -1e-3, 1e-3, horizon=0
        )
    with pytest.raises(ValueError, match="horizon"):
        _mpc(env, horizon=0)
    q, contacts = _touching_state(env)
    with pytest.raises(ValueError, match="q"):
        mpc.plan(q[:10], contacts, torch.zeros(3, dtype=DT), torch.tensor([1.0, 0, 0, 0]))


def _bounded_tips_cost(obj: str) -> ManipulationCost:
    """The paper's fingertip state bounds as a cost: tip heights in [0, ``tip_height_max``]."""
    high = tasks.OBJECT_SETTINGS[obj].tip_height_max
    return ManipulationCost(tip_height=(0.0, math.inf if high is None else high))


def test_planned_tip_heights_are_bounded_as_in_the_papers_fingertip_mpc(env):
    """z ≥ 0 for every object, z ≤ 0.1 m for the stick: the penalty is weight × excess² summed
    over the planned states q₁…q_T (not q₀, which the plan cannot change)."""
    stick = FINGERTIPS.make_plant("stick")
    assert FINGERTIPS.cost(stick).tip_height is None  # off by default
    assert _bounded_tips_cost("stick").tip_height == (0.0, 0.1)
    cost = _bounded_tips_cost("cube")
    assert cost.tip_height == (0.0, float("inf"))
    free = dataclasses.replace(cost, tip_height=None)
    T = 4
    positions = torch.zeros(T + 1, 3, dtype=DT)
    quats = torch.tensor([1.0, 0, 0, 0], dtype=DT).expand(T + 1, 4)
    tips = torch.full((T + 1, 3, 3), 0.02, dtype=DT)
    tips[0, 0, 2] = -0.05  # the current state: not penalised
    tips[2, 1, 2] = -0.003  # a planned tip 3 mm below the floor
    args = (positions, quats, tips, torch.zeros(T, 9, dtype=DT), positions[0], quats[0])
    extra = cost(*args) - free(*args)
    torch.testing.assert_close(extra, torch.tensor(cost.tip_height_weight * 0.003**2, dtype=DT))


def test_an_mpc_built_with_the_tip_bounds_charges_a_plan_through_the_floor(env, mpc):
    """The bounded cost passed to the constructor: a plan that lowers tip 1 (resting 1 cm up)
    5 mm a step costs weight × Σ (planned depth below the floor)² more than without."""
    bounded = ContactImplicitMPC(
        FINGERTIPS.system(env),
        contact_model("paper", stiffness=FINGERTIPS.default_stiffness),
        FINGERTIPS.layout,
        FINGERTIPS.fingertips(),
        _bounded_tips_cost("cube"),
        -CONTROL_BOUND,
        CONTROL_BOUND,
        h=FINGERTIPS.h(env),
    )
    q, contacts = _touching_state(env)
    down = torch.zeros(1, bounded.horizon, 9, dtype=DT)
    down[..., 5] = -CONTROL_BOUND
    frozen = bounded.freeze(q, contacts)
    extra = bounded.objective(down, q, frozen, *TARGET) - mpc.objective(down, q, frozen, *TARGET)
    z = bounded.fingertips(bounded.rollout(q, down, frozen))[0, 1:, :, 2]
    assert float(z.min()) < -1e-3  # the plan does take tip 1 below the floor
    expected = bounded.cost.tip_height_weight * z.clamp(max=0).square().sum()
    torch.testing.assert_close(extra[0], expected)
