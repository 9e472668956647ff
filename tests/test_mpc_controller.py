"""The contact-implicit MPC: rollout, gradients, box, warm start and a closed-loop smoke run."""

import dataclasses

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchcontact import AnitescuQP
from torchcontact.environments import tasks
from torchcontact.functional import cf_velocity
from torchcontact.integrate import integrate
from torchcontact.mpc.controller import CONTACT_BUCKET, GAPS, ContactImplicitMPC
from torchcontact.mpc.fingertips import CONTROL_BOUND, LAYOUT, fingertip_positions, fingertips_mpc
from torchcontact.sim import FingertipsEnv

DT = torch.float64


@pytest.fixture(scope="module")
def env():
    settings_ = tasks.OBJECT_SETTINGS["cube"]
    return FingertipsEnv(
        "cube", object_friction=settings_.object_friction, contact_slots=settings_.contact_slots
    )


@pytest.fixture(scope="module")
def mpc():
    return fingertips_mpc("cube", max_iter=15)


@pytest.fixture(scope="module")
def propagated_mpc():
    return fingertips_mpc("cube", max_iter=15, gaps="propagated")


@pytest.fixture(scope="module")
def qp_mpc():
    """The same MPC through the relaxed QP (the paper's implicit-MPC baseline)."""
    return fingertips_mpc("cube", model="qp", max_iter=15)


def _touching_state(env):
    """The cube 0.5 mm into the ground with tip 0 pressed 1 mm into its +x face."""
    tips = np.array([0.039, 0.0, 0.03, 0.0, 0.2, 0.01, -0.2, 0.0, 0.01])
    env.reset(np.array([0, 0, 0.0295, 1, 0, 0, 0.0]), tips=tips)
    return torch.as_tensor(env.state()), env.contacts(DT)


TARGET = (torch.tensor([0.05, 0.02, 0.03], dtype=DT), torch.tensor([0.0, 0, 0, 1], dtype=DT))


@pytest.mark.parametrize("model", ["mpc", "qp_mpc"])
def test_rollout_equals_stepping_the_model(env, model, request):
    mpc = request.getfixturevalue(model)
    q, contacts = _touching_state(env)
    assert int(contacts.n_active()) == 5  # four ground corners and the tip
    controls = 0.004 * torch.randn(2, mpc.horizon, 9, dtype=DT)
    states = mpc.rollout(q, controls, mpc.frozen_rows(q, contacts))
    assert states.shape == (2, mpc.horizon + 1, 16)
    for b in range(2):
        state = q
        for t in range(mpc.horizon):
            Q, bias = mpc.system(controls[b, t])
            v = mpc.model(Q, bias, contacts, mpc.h, q)
            state = integrate(state, v, mpc.h, mpc.layout)
            torch.testing.assert_close(states[b, t + 1], state)


def test_propagated_gaps_follow_the_models_own_motion(env):
    """Each step sees φ̃ advanced along the frozen normal rows by the steps before it; the first
    step, and every step with frozen gaps, sees the detected distances."""
    frozen, propagated = fingertips_mpc("cube"), fingertips_mpc("cube", gaps="propagated")
    q, contacts = _touching_state(env)
    rows = propagated.frozen_rows(q, contacts)
    jac, phi, K, D, normal = rows
    torch.testing.assert_close(normal[::4], contacts.jac_normal * contacts.active.unsqueeze(-1))
    controls = 0.004 * torch.randn(2, propagated.horizon, 9, dtype=DT)
    states = propagated.rollout(q, controls, rows)
    Q, bias = propagated.system(controls)
    gap = phi.expand(2, -1)
    for t in range(propagated.horizon):
        v = cf_velocity(Q, bias[:, t], jac, gap, propagated.h, K, D, propagated.model.gamma)
        torch.testing.assert_close(
            states[:, t + 1], integrate(states[:, t], v, propagated.h, LAYOUT)
        )
        gap = gap + propagated.h * v @ normal.T
    first = frozen.rollout(q, controls, frozen.frozen_rows(q, contacts))
    torch.testing.assert_close(states[:, 1], first[:, 1])
    assert not torch.allclose(states[:, -1], first[:, -1])


def test_propagated_gaps_release_a_tip_the_plan_pulls_away(env):
    """Tip 0 pressed 1 mm into the cube, then pulled 5 mm away per step: frozen gaps keep
    pushing the cube every step, propagated ones stop once the modelled gap has opened."""
    q, contacts = _touching_state(env)
    controls = torch.zeros(1, 4, 9, dtype=DT)
    controls[..., 0] = 0.005  # +x: away from the cube's +x face
    pushes = {}
    for gaps in GAPS:
        mpc = fingertips_mpc("cube", gaps=gaps)
        states = mpc.rollout(q, controls, mpc.frozen_rows(q, contacts))
        pushes[gaps] = (states[0, 2:, 0] - states[0, 1:-1, 0]).abs().sum()
    assert float(pushes["propagated"]) < 0.1 * float(pushes["frozen"])


def test_propagated_gaps_are_for_the_complementarity_free_model():
    with pytest.raises(ValueError, match="gaps"):
        fingertips_mpc("cube", model="qp", gaps="propagated")
    with pytest.raises(ValueError, match="gaps"):
        fingertips_mpc("cube", gaps="updated")


@pytest.mark.parametrize("model", ["mpc", "propagated_mpc", "qp_mpc"])
def test_value_and_grad_matches_the_autograd_tape_and_finite_differences(env, model, request):
    mpc = request.getfixturevalue(model)
    q, contacts = _touching_state(env)
    rows = mpc.frozen_rows(q, contacts)
    controls = (0.004 * torch.randn(3, mpc.horizon, 9, dtype=DT)).requires_grad_(True)
    cost, grad = mpc.value_and_grad(controls.detach(), q, rows, *TARGET)
    taped = mpc.objective(controls, q, rows, *TARGET)  # the QP solved inside the tape
    (taped_grad,) = torch.autograd.grad(taped.sum(), controls)
    torch.testing.assert_close(cost, taped.detach())
    torch.testing.assert_close(grad, taped_grad)
    direction = torch.randn_like(controls)
    eps = 1e-7
    plus = mpc.objective(controls.detach() + eps * direction, q, rows, *TARGET)
    minus = mpc.objective(controls.detach() - eps * direction, q, rows, *TARGET)
    torch.testing.assert_close(
        (plus - minus) / (2 * eps), (grad * direction).sum((-1, -2)), rtol=1e-5, atol=1e-7
    )


def test_qp_plan_stays_in_its_box_and_lowers_the_cost_from_the_warm_start(env, qp_mpc):
    q, contacts = _touching_state(env)
    qp_mpc.reset()
    rows = qp_mpc.frozen_rows(q, contacts)
    warm, _ = qp_mpc.value_and_grad(torch.zeros(1, qp_mpc.horizon, 9, dtype=DT), q, rows, *TARGET)
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
    states = qp_mpc.rollout(q, still, qp_mpc.frozen_rows(q, contacts))
    assert float((states[0, 1:, 2] - states[0, :-1, 2]).abs().max()) < 1e-3


def test_the_mpc_refuses_models_it_cannot_differentiate(mpc):
    with pytest.raises(ValueError, match="model"):
        ContactImplicitMPC(
            mpc.system, AnitescuQP(), LAYOUT, fingertip_positions, mpc.cost, -1e-3, 1e-3
        )
    with pytest.raises(ValueError, match="model"):
        fingertips_mpc("cube", model="osqp")


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
@pytest.mark.parametrize("gaps", GAPS)
def test_compiled_plan_matches_the_eager_plan(env, gaps):
    """Compiled, the objective is traced into the L-BFGS rounds (several per compiled call):
    the same plans as eager, plan after warm-started plan."""
    q, contacts = _touching_state(env)
    options = {"horizon": 2, "max_iter": 8, "gaps": gaps}
    eager = fingertips_mpc("cube", **options)
    compiled = fingertips_mpc("cube", compile=True, **options)
    for _ in range(3):
        expected, plan = eager.plan(q, contacts, *TARGET), compiled.plan(q, contacts, *TARGET)
        torch.testing.assert_close(plan.controls, expected.controls, rtol=0, atol=1e-10)
        assert plan.iterations == expected.iterations and plan.iterations > 0


def test_padding_slots_do_not_change_the_plan(env):
    """The plan pads contacts to a multiple of CONTACT_BUCKET slots; more padding changes
    nothing but rounding."""
    q, contacts = _touching_state(env)
    mpc = fingertips_mpc("cube", horizon=2, max_iter=8)
    plan = mpc.plan(q, contacts, *TARGET)
    mpc.reset()
    padded = mpc.plan(q, contacts.padded(contacts.slots + CONTACT_BUCKET + 1), *TARGET)
    torch.testing.assert_close(padded.controls, plan.controls, rtol=0, atol=1e-12)
    assert padded.iterations == plan.iterations


def test_closed_loop_moves_the_cube_toward_its_target(env, mpc):
    """120 MPC steps of cube rotation (seed 1): the pose error shrinks in position and angle."""
    initial, target = tasks.sample("rotation", "cube", 1)
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
        fingertips_mpc("cube", horizon=0)
    q, contacts = _touching_state(env)
    with pytest.raises(ValueError, match="q"):
        mpc.plan(q[:10], contacts, torch.zeros(3, dtype=DT), torch.tensor([1.0, 0, 0, 0]))


def test_planned_tip_heights_are_bounded_as_in_the_papers_fingertip_mpc():
    """z ≥ 0 for every object, z ≤ 0.1 m for the stick: the penalty is weight × excess² summed
    over the planned states q₁…q_T (not q₀, which the plan cannot change)."""
    assert fingertips_mpc("stick").cost.tip_height is None  # off by default
    assert fingertips_mpc("stick", bound_tips=True).cost.tip_height == (0.0, 0.1)
    cost = fingertips_mpc("cube", bound_tips=True).cost
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
