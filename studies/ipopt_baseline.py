"""The paper's MPC solved the paper's way, CasADi + IPOPT: the speed baseline of our L-BFGS.

The paper's reference code states its MPC as a multiple-shooting NLP and solves it with IPOPT
(through CasADi, at most 50 to 500 iterations by example, warm-started from the previous
solution). Our speed targets are relative to that implementation on the same machine, so
``benchmarks/ipopt_speed.py`` times :class:`IpoptMPC` beside our :class:`ContactImplicitMPC`
on the same states in one run. The problem is our MPC's, read from the controller it is built
on: the complementarity-free step with J̃, φ̃, K, D frozen over the horizon (as the paper's
Algorithm 1, :meth:`ContactImplicitMPC.freeze`), the same cost terms and weights, the same
control box. As in the paper's code:

- decision variables ``w = (u₀, q₁, u₁, q₂, …, u_{T−1}, q_T)``, constraints ``q_{t+1} =
  f(q_t, u_t)``, optionally the tips' heights bounded (the reference's first guess is all
  zeros; ours holds the current state, since zero quaternions make the grasp term's rotation
  NaN);
- the object's quaternion moves by the first-order update ``q + ½h·G(q)ᵀω`` (ω in the body
  frame), not renormalised; our rollout rotates it exactly (:func:`torchcontact.integrate`),
  so the two optima differ slightly;
- IPOPT with its defaults (MUMPS), a cap on its iterations, given the previous primal and
  dual solution as its start.

The robot is the environment's (``mpc.fingertips.robot``, a
:class:`~torchcontact.sim.robot.Robot`): point fingertips (no kinematics) are coordinates of
q; a kinematic chain's tips come from its MJCF through
:func:`~studies.casadi_kinematics.casadi_fingertips`, as the paper's code writes its hands'
forward kinematics in CasADi.

Two ways in:

- :class:`IpoptMPC` wraps a controller and solves its problem at the states it is given,
  warm-started from its own previous solution: the benchmark's replays of the states our
  closed loop visited.
- :class:`IpoptPlanner` is a :class:`~torchcontact.mpc.planners.Planner`, so that an MPC plans
  every step through IPOPT: ``ContactImplicitMPC.from_env(env, plant,
  planner=IpoptPlanner())`` or, after :func:`register_ipopt`, ``planner="ipopt"``. A planner
  exists before the MPC it serves (``from_env`` takes it ready-made, and builds a named one
  from ``max_iter``, ``memory`` and ``compile`` alone), so the planner holds IPOPT's options
  only and reads the problem at plan time: the system, layout, fingertips, cost, h and horizon
  from the MPC whose objective it is handed (that objective is the MPC's own bound method;
  ``IpoptPlanner(mpc=...)`` names the MPC instead), the frozen step, state and target from
  the MPC's ``args``, and the control box from ``box``. It builds one :class:`IpoptMPC` per
  (MPC, number of frozen rows), since the MPC pads the contact slots to a bucket size that can
  change from step to step.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from studies.casadi_kinematics import casadi_fingertips
from torchcontact.contacts import Contacts
from torchcontact.environments.base import RobotTips
from torchcontact.frozen import FrozenComplementarityFree, FrozenRelaxedQP
from torchcontact.model import ComplementarityFree, RelaxedQP
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.planners import PLANNERS, Objective, PlannerResult, register_planner
from torchcontact.sim.robot import Robot
from torchcontact.validation import check_shape

REFERENCE_MAX_ITER = 50
"""IPOPT's iteration cap in the paper's reference code."""

FORMULATIONS = ("lean", "reference")
"""How :class:`IpoptMPC` writes the NLP: ``"lean"``, our statement (Q⁻¹b first, diagonal
scalings, an overflow-safe softplus, only the tips' heights bounded); ``"reference"``, as the
paper's code writes it (dense Q⁻¹ and the products (J̃Q⁻¹)b and (Q⁻¹J̃ᵀ)λ, log(1 + exp(γx))/γ,
and every state variable boxed, see :data:`REFERENCE_BOUND`). Same problem and optimum; the
expression graphs IPOPT evaluates differ in size, and finite bounds on all states add
barrier terms."""

REFERENCE_BOUND = 1e7
"""The reference's box on the states it does not otherwise bound (finite, so IPOPT keeps it)."""

QP_REFUSAL = "the IPOPT baseline states the complementarity-free model, not qp"


@dataclass(frozen=True)
class IpoptPlan:
    """One IPOPT solve: the control to apply and how the solve went."""

    control: np.ndarray  # (n_u,) u₀
    controls: np.ndarray  # (T, n_u)
    cost: float
    iterations: int
    status: str  # IPOPT's return status, e.g. "Solve_Succeeded", "Maximum_Iterations_Exceeded"
    solve_ms: float  # wall time of the solve, the frozen rows' extraction included


def _softplus(x, gamma: float):
    """log(1 + exp(γx))/γ without overflow: max(x, 0) + log1p(exp(−γ|x|))/γ."""
    import casadi as cs

    return cs.fmax(x, 0) + cs.log1p(cs.exp(-gamma * cs.fabs(x))) / gamma


def _body_rate_matrix(quat):
    """G(q) (3, 4) with q̇ = ½ G(q)ᵀ ω for the body-frame angular velocity ω."""
    import casadi as cs

    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    return cs.vertcat(
        cs.horzcat(-x, w, z, -y),
        cs.horzcat(-y, -z, w, x),
        cs.horzcat(-z, y, -x, w),
    )


def _rotation(quat):
    """R(q/‖q‖) (3, 3, CasADi) of a quaternion (w, x, y, z), as the torch cost's."""
    import casadi as cs

    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    s = 2 / cs.sumsqr(quat)
    return cs.vertcat(
        cs.horzcat(1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)),
        cs.horzcat(s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)),
        cs.horzcat(s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)),
    )


def _check_options(max_iter, tip_height, formulation: str) -> None:
    """Refuse bad solver options, naming the argument."""
    if formulation not in FORMULATIONS:
        raise ValueError(f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
    if not isinstance(max_iter, int) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    if tip_height is not None and not tip_height[0] < tip_height[1]:
        raise ValueError(f"tip_height must be (low, high) with low < high, got {tip_height}")


def is_chain(mpc: ContactImplicitMPC) -> bool:
    """Whether the MPC's robot is a kinematic chain (a hand, tips by forward kinematics of its
    MJCF) rather than point fingertips (tips are coordinates of q); ``ValueError`` for any
    other robot or layout.

    The robot is ``mpc.fingertips.robot``, the :class:`~torchcontact.sim.robot.Robot` of an
    environment's :meth:`~torchcontact.environments.base.Environment.fingertips`. Point
    fingertips need the layout ``free`` then three slides per tip; a chain, ``free`` then its
    hinge and slide joints.
    """
    tips = mpc.fingertips
    robot = tips.robot if isinstance(tips, RobotTips) else None
    joints = mpc.layout.joints
    if isinstance(robot, Robot) and joints[0] == "free" and mpc.layout.nq == 7 + robot.n_joints:
        if robot.kinematics is None and joints[1:] == ("slide",) * (3 * robot.n_tips):
            return False
        if robot.kinematics is not None and set(joints[1:]) <= {"hinge", "slide"}:
            return True
    raise ValueError(
        "the IPOPT baseline supports an environment's point fingertips and kinematic hands only"
    )


def _check(mpc: ContactImplicitMPC, n_rows, max_iter, tip_height, formulation: str) -> bool:
    """Refuse what the baseline cannot state, naming the argument; True for a hand's MPC."""
    _check_options(max_iter, tip_height, formulation)
    if isinstance(mpc.model, RelaxedQP):
        raise ValueError(QP_REFUSAL)
    if not isinstance(mpc.model, ComplementarityFree) or mpc.model.gamma is None:
        raise ValueError(
            "the IPOPT baseline states the complementarity-free model with a softplus γ, "
            f"got {mpc.model!r}"
        )
    if mpc.gaps != "frozen":
        raise ValueError(f"the IPOPT baseline plans with frozen gaps, got gaps={mpc.gaps!r}")
    hold = getattr(mpc.cost, "hold", None)
    if hold is not None and float(hold.applies):
        raise ValueError(
            "the IPOPT baseline states the paper's cost terms, not the hold term: build "
            "the MPC with env.cost(plant, CostOptions(hold_first=0))"
        )
    hand = is_chain(mpc)
    if hand and tip_height is not None:
        raise ValueError("tip_height bounds the fingertips' coordinates; give None for hands")
    if not isinstance(n_rows, int) or n_rows < 1:
        raise ValueError(f"n_rows must be a positive integer, got {n_rows!r}")
    return hand


def _step_function(mpc: ContactImplicitMPC, formulation: str, jac, phi, K, D):
    """``step(q, u) ↦ q⁺`` (CasADi) of the CF model with the frozen rows ``jac (n_rows, nv)``,
    ``phi, K, D (n_rows,)``, written the lean way or the reference's way; the quaternion moves
    by the first-order update ``q + ½h·G(q)ᵀω``."""
    import casadi as cs

    h, gamma = mpc.h, mpc.model.gamma
    metric = mpc.system.metric().double().numpy()
    object_force = mpc.system.object_force.double().numpy()
    stiffness = mpc.system.robot_stiffness.double().numpy()

    def lean_velocity(u):
        b = cs.vertcat(cs.DM(object_force), cs.DM(stiffness) * u)
        free = b / cs.DM(metric)  # Q⁻¹b
        gap_change = cs.mtimes(jac, free)
        lam = _softplus(-K * (gap_change + phi) - D * gap_change / h, gamma)
        return (free + cs.mtimes(jac.T, lam) / cs.DM(metric)) / h

    def reference_velocity(u):  # the same v, written as the paper's code writes it
        inverse = cs.DM(np.linalg.inv(np.diag(metric)))
        b = cs.vertcat(cs.DM(object_force), cs.mtimes(cs.DM(np.diag(stiffness)), u))
        pressure = -K * (cs.mtimes(cs.mtimes(jac, inverse), b) + phi)
        pressure = pressure - D * cs.mtimes(cs.mtimes(jac, inverse), b) / h
        lam = cs.log(1 + cs.exp(gamma * pressure)) / gamma
        return cs.mtimes(inverse, b) / h + cs.mtimes(cs.mtimes(inverse, jac.T), lam) / h

    velocity = lean_velocity if formulation == "lean" else reference_velocity

    def step(q, u):
        v = velocity(u)
        quat = q[3:7] + 0.5 * h * cs.mtimes(_body_rate_matrix(q[3:7]).T, v[3:6])
        return cs.vertcat(q[0:3] + h * v[0:3], quat, q[7:] + h * v[6:])

    return step


def _tips_function(mpc: ContactImplicitMPC, hand: bool):
    """``tips(q) ↦ [p_i (3,)]``: the fingertips' positions (CasADi): coordinates of q for point
    fingertips, CasADi forward kinematics of the MJCF for a hand."""
    robot = mpc.fingertips.robot
    if not hand:
        return lambda q: [q[7 + 3 * i : 10 + 3 * i] for i in range(robot.n_tips)]
    kinematics = robot.kinematics
    forward = casadi_fingertips(kinematics.mjcf, kinematics.tips)

    def tips(q):
        points = forward(q[7:])
        return [points[i, :].T for i in range(len(kinematics.tips))]

    return tips


def _cost_functions(cost, tips, target_q):
    """``path_cost(q, u)`` (contact, grasp and control terms, on q₀…q_{T−1}) and
    ``state_cost(q)`` (tilt and tip-height terms, on q₁…q_T) of the MPC's cost, in CasADi."""
    import casadi as cs

    def path_cost(q, u):
        offsets = [tip - q[0:3] for tip in tips(q)]
        total = cost.contact * sum(cs.sumsqr(o) for o in offsets)
        if cost.grasp:
            directions = sum(o / cs.sqrt(cs.fmax(cs.sumsqr(o), 1e-12)) for o in offsets)
            total += cost.grasp * cs.sumsqr(cs.mtimes(_rotation(q[3:7]).T, directions))
        return total + cost.control * cs.sumsqr(u)

    def state_cost(q):
        total = 0
        if cost.tilt_weight:
            up, target_up = _rotation(q[3:7])[:, 2], _rotation(target_q)[:, 2]
            total += cost.tilt_weight * (1 - cs.dot(up, target_up))
        if cost.tip_height is not None:
            low, high = cost.tip_height
            for tip in tips(q):
                excess = cs.fmax(low - tip[2], 0) ** 2 + cs.fmax(tip[2] - high, 0) ** 2
                total += cost.tip_height_weight * excess
        return total

    return path_cost, state_cost


def _state_bounds(lower, upper, nq: int, formulation: str, hand: bool, tip_height):
    """``(lower, upper)`` bounds ``(T·(n_u + nq),)`` on the decision variables, in their order
    ``(u₀, q₁, …)``: the control box ``lower, upper (T, n_u)``, and the states' boxes
    (:class:`IpoptMPC`)."""
    unbounded = np.inf if formulation == "lean" else REFERENCE_BOUND
    state_low, state_high = np.full(nq, -unbounded), np.full(nq, unbounded)
    if formulation == "reference" and hand:
        state_low[:3], state_high[:3] = (-0.99, -0.99, 0.0), (0.99, 0.99, 0.99)
    elif formulation == "reference":
        state_low[7:], state_high[7:] = -100.0, 100.0
        state_low[9::3] = 0.0
    if tip_height is not None:
        low, high = tip_height
        state_low[9::3] = low  # the tips' z: q[9], q[12], q[15]
        state_high[9::3] = min(high, state_high[9])
    low = np.concatenate([np.concatenate([lo, state_low]) for lo in lower])
    high = np.concatenate([np.concatenate([hi, state_high]) for hi in upper])
    return low, high


def _nlp(mpc: ContactImplicitMPC, n_rows: int, max_iter: int, formulation: str, hand: bool):
    """IPOPT on the MPC's multiple-shooting NLP, ``solver``, and its model step as a
    ``casadi.Function`` ``step (q, u, rows) ↦ q⁺`` (:attr:`IpoptMPC.step_function`)."""
    import casadi as cs

    nq, nv, n_u, T = mpc.layout.nq, mpc.layout.nv, mpc.system.n_robot, mpc.horizon
    cost = mpc.cost
    q0 = cs.SX.sym("q0", nq)
    target_p, target_q = cs.SX.sym("target_p", 3), cs.SX.sym("target_q", 4)
    phi, K, D = (cs.SX.sym(name, n_rows) for name in ("phi", "K", "D"))
    jac = cs.SX.sym("jac", n_rows, nv)
    step = _step_function(mpc, formulation, jac, phi, K, D)
    path_cost, state_cost = _cost_functions(cost, _tips_function(mpc, hand), target_q)

    w, g, objective, q = [], [], 0, q0
    for _ in range(T):
        u = cs.SX.sym(f"u{len(w)}", n_u)
        objective += path_cost(q, u)
        predicted = step(q, u)
        q = cs.SX.sym(f"q{len(w)}", nq)
        w += [u, q]
        g.append(predicted - q)
        objective += state_cost(q)
    final = cost.position * cs.sumsqr(q[0:3] - target_p)
    final += cost.orientation * (1 - cs.dot(q[3:7], target_q) ** 2)
    objective += cost.final * final

    rows = cs.vertcat(phi, cs.vec(jac), K, D)
    params = cs.vertcat(q0, target_p, target_q, rows)
    nlp = {"x": cs.vertcat(*w), "f": objective, "g": cs.vertcat(*g), "p": params}
    options = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "print_time": 0,
        "ipopt.max_iter": max_iter,
    }
    solver = cs.nlpsol("mpc", "ipopt", nlp, options)
    q, u = cs.SX.sym("q", nq), cs.SX.sym("u", n_u)
    return solver, cs.Function("step", [q, u, rows], [step(q, u)])


class IpoptMPC:
    """The MPC problem of ``mpc`` (fingertips or a hand) as a multiple-shooting NLP solved by IPOPT.

    Args:
        mpc: the controller whose model, system, cost, box, horizon and h are solved; its
            frozen rows come from :meth:`ContactImplicitMPC.freeze` (the complementarity-free
            model with frozen gaps only).
        n_rows: rows of J̃ (contact slots × facets) the NLP is built for.
        max_iter: IPOPT's iteration cap (the reference's hands: 50; its fingertips: 100 for
            the foam brick, 500 for the cube).
        tip_height: ``(low, high)`` [m] bounds on the planned tips' heights, as the reference's
            fingertip MPCs bound their states (z ≥ 0, and ≤ 0.1 m for the foam brick and the
            stick); None leaves the states unbounded (fingertips only).
        formulation: one of :data:`FORMULATIONS`. ``"reference"`` also boxes every state as
            the reference does: fingertips' x, y within ±100 m and heights within
            ``tip_height`` (else [0, 100] m), hands' object within ±0.99 m and above z = 0,
            the rest within ±:data:`REFERENCE_BOUND`.
    """

    def __init__(
        self,
        mpc: ContactImplicitMPC,
        n_rows: int,
        max_iter: int = REFERENCE_MAX_ITER,
        tip_height: tuple[float, float] | None = None,
        formulation: str = "lean",
    ):
        self._hand = _check(mpc, n_rows, max_iter, tip_height, formulation)
        self.mpc, self.n_rows = mpc, n_rows
        self._formulation, self._tip_height = formulation, tip_height
        self.solver, self.step_function = _nlp(mpc, n_rows, max_iter, formulation, self._hand)
        """``step_function (q (nq,), u (n_u,), rows) ↦ q⁺``: the NLP's model step; ``rows``
        are the parameter vector's entries after the target (:meth:`parameters`)."""
        self._shape, self._nq = (mpc.horizon, mpc.system.n_robot), mpc.layout.nq
        self._lbx, self._ubx = self.bounds(mpc.lower, mpc.upper)
        self.reset()

    def reset(self) -> None:
        """Forget the previous solution: the next solve starts from zero controls with every
        state at the current one (the reference's all-zero start would put zero quaternions
        into the grasp term's rotation)."""
        self._guess = None

    def bounds(self, lower, upper) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``(T·(n_u + nq),)`` on the decision variables for the control box ``lower,
        upper`` (``T·n_u`` values each, in the MPC's order), with the states' boxes."""
        lower = torch.as_tensor(lower).double().reshape(self._shape).numpy()
        upper = torch.as_tensor(upper).double().reshape(self._shape).numpy()
        return _state_bounds(
            lower, upper, self._nq, self._formulation, self._hand, self._tip_height
        )

    def parameters(self, q, contacts: Contacts, target_p, target_quat) -> np.ndarray:
        """The NLP's parameter vector at state ``q (nq,)``: q₀, the target and the frozen rows."""
        q = torch.as_tensor(q, dtype=torch.float64)
        check_shape("q", q, f"({self._nq},)", q.shape == (self._nq,))
        with torch.no_grad():
            frozen = self.mpc.freeze(q.to(self.mpc.dtype), contacts.to(self.mpc.dtype))
        return self.frozen_parameters(q, frozen, target_p, target_quat)

    def frozen_parameters(self, q, frozen, target_p, target_quat) -> np.ndarray:
        """:meth:`parameters` from the MPC's frozen step ``frozen`` (a
        :class:`~torchcontact.frozen.FrozenComplementarityFree` of :attr:`n_rows` rows)."""
        if isinstance(frozen, FrozenRelaxedQP):
            raise ValueError(QP_REFUSAL)
        if not isinstance(frozen, FrozenComplementarityFree):
            raise ValueError(f"frozen must be complementarity-free, got {type(frozen).__name__}")
        phi = frozen.phi
        if phi.shape[-1] != self.n_rows:
            raise ValueError(f"contacts must give {self.n_rows} rows, got {phi.shape[-1]}")
        K = frozen.stiffness.expand(phi.shape)
        D = torch.zeros_like(phi) if frozen.damping is None else frozen.damping.expand(phi.shape)
        pieces = [
            torch.as_tensor(q),
            torch.as_tensor(target_p),
            torch.as_tensor(target_quat),
            phi,
            frozen.jac.mT.reshape(-1),  # CasADi's vec() stacks columns
            K,
            D,
        ]
        return torch.cat([x.detach().double().reshape(-1) for x in pieces]).numpy()

    def rollout(self, params: np.ndarray, controls) -> np.ndarray:
        """The decision variables ``(T·(n_u + nq),)`` of ``controls`` (``T·n_u`` values) with
        the states the NLP's model steps to from ``params``' q₀: a start on its constraints."""
        controls = torch.as_tensor(controls).double().reshape(self._shape).numpy()
        q, rows = params[: self._nq], params[self._nq + 7 :]
        pieces = []
        for u in controls:
            q = np.asarray(self.step_function(q, u, rows)).ravel()
            pieces += [u, q]
        return np.concatenate(pieces)

    def solve(self, params: np.ndarray, guess: dict, lbx=None, ubx=None) -> tuple[dict, dict]:
        """One IPOPT solve from ``guess`` (``x0`` and optionally ``lam_x0``, ``lam_g0``) in
        ``lbx ≤ w ≤ ubx`` (default the MPC's box): its solution (NumPy arrays ``x``, ``f``,
        ``lam_x``, ``lam_g``) and IPOPT's stats."""
        lbx = self._lbx if lbx is None else lbx
        ubx = self._ubx if ubx is None else ubx
        solution = self.solver(**guess, lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0, p=params)
        solution = {key: value.full().ravel() for key, value in solution.items()}
        return solution, self.solver.stats()

    def plan(self, q, contacts: Contacts, target_p, target_quat) -> IpoptPlan:
        """Solve at state ``q (nq,)`` from the previous solution; returns u₀ and the stats."""
        start = time.perf_counter()
        params = self.parameters(q, contacts, target_p, target_quat)
        T, n_u = self._shape
        if self._guess is None:
            held = np.concatenate([np.zeros(n_u), params[: self._nq]])
            n_w, n_g = self._lbx.shape[0], T * self._nq
            self._guess = {"x0": np.tile(held, T), "lam_x0": np.zeros(n_w), "lam_g0": np.zeros(n_g)}
        solution, stats = self.solve(params, self._guess)
        solve_ms = 1e3 * (time.perf_counter() - start)
        x = solution["x"]
        self._guess = {"x0": x, "lam_x0": solution["lam_x"], "lam_g0": solution["lam_g"]}
        controls = x.reshape(T, n_u + self._nq)[:, :n_u]
        return IpoptPlan(
            control=controls[0].copy(),
            controls=controls,
            cost=float(solution["f"][0]),
            iterations=int(stats["iter_count"]),
            status=str(stats["return_status"]),
            solve_ms=solve_ms,
        )


class IpoptPlanner:
    """A :class:`~torchcontact.mpc.planners.Planner` that solves the MPC's problem by IPOPT,
    as the NLP of :class:`IpoptMPC`.

    ``plan(objective, x0, box, args)`` takes the MPC's ``args = (q, frozen, target_p,
    target_quat)``, ``frozen`` the step it froze (:meth:`ContactImplicitMPC.freeze`). Each row of
    ``x0 (B, T·n_u)`` is one solve, started from those controls with the states the NLP's
    model steps to under them (a start on its constraints; no multipliers), within the row of
    ``box``. It returns the controls in ``x0``'s dtype, ``f`` the NLP's own objective (its
    quaternion moves to first order, so ``f`` is within about 1e-3 of the MPC's cost of the
    same controls), ``iterations`` IPOPT's and ``evaluations`` its objective evaluations,
    each summed over the rows; :attr:`status` keeps IPOPT's return status of the last solve.

    ``objective`` is never evaluated: it names the MPC whose problem is solved (its
    ``value_and_grad`` is that MPC's bound method), unless ``mpc`` is given. One
    :class:`IpoptMPC` is built per (MPC, number of frozen rows) and kept.

    Args:
        mpc: the controller whose problem is solved; None: the MPC that calls :meth:`plan`.
        max_iter, tip_height, formulation: as :class:`IpoptMPC`.
    """

    def __init__(
        self,
        mpc: ContactImplicitMPC | None = None,
        max_iter: int = REFERENCE_MAX_ITER,
        tip_height: tuple[float, float] | None = None,
        formulation: str = "lean",
    ):
        _check_options(max_iter, tip_height, formulation)
        if mpc is not None and not isinstance(mpc, ContactImplicitMPC):
            raise ValueError(f"mpc must be a ContactImplicitMPC or None, got {type(mpc).__name__}")
        self.mpc, self.max_iter = mpc, max_iter
        self.tip_height, self.formulation = tip_height, formulation
        self.status: str | None = None
        self._problem: ContactImplicitMPC | None = None
        self._baselines: dict[int, IpoptMPC] = {}

    def baseline(self, mpc: ContactImplicitMPC, n_rows: int) -> IpoptMPC:
        """The :class:`IpoptMPC` of ``mpc`` for ``n_rows`` frozen rows (built once)."""
        if self._problem is not mpc:
            self._problem, self._baselines = mpc, {}
        if n_rows not in self._baselines:
            self._baselines[n_rows] = IpoptMPC(
                mpc, n_rows, self.max_iter, self.tip_height, self.formulation
            )
        return self._baselines[n_rows]

    def _solved_mpc(self, objective: Objective) -> ContactImplicitMPC:
        """:attr:`mpc`, else the MPC whose bound method ``objective`` is."""
        mpc = self.mpc
        if mpc is None:
            mpc = getattr(getattr(objective, "value_and_grad", None), "__self__", None)
        if not isinstance(mpc, ContactImplicitMPC):
            raise ValueError(
                "objective must be a ContactImplicitMPC's (its value_and_grad a bound method of "
                "the MPC); to plan another objective, give IpoptPlanner(mpc=...)"
            )
        return mpc

    def plan(self, objective: Objective, x0, box, args: tuple = ()) -> PlannerResult:
        if len(args) != 4:
            raise ValueError(
                f"args must be the MPC's (q, frozen, target_p, target_quat), got {args}"
            )
        q, frozen, target_p, target_quat = args
        mpc = self._solved_mpc(objective)
        baseline = self.baseline(mpc, frozen.phi.shape[-1])
        params = baseline.frozen_parameters(q, frozen, target_p, target_quat)
        lower, upper = (torch.as_tensor(bound).expand(x0.shape) for bound in box)
        n_u = mpc.system.n_robot
        xs, fs, iterations, evaluations = [], [], 0, 0
        for start, low, high in zip(x0, lower, upper, strict=True):
            lbx, ubx = baseline.bounds(low, high)
            guess = {"x0": baseline.rollout(params, start)}
            solution, stats = baseline.solve(params, guess, lbx, ubx)
            xs.append(solution["x"].reshape(mpc.horizon, -1)[:, :n_u].reshape(-1))
            fs.append(float(solution["f"][0]))
            iterations += int(stats["iter_count"])
            evaluations += int(stats["n_call_nlp_f"])
            self.status = str(stats["return_status"])
        x = torch.as_tensor(np.stack(xs), dtype=x0.dtype, device=x0.device)
        f = torch.as_tensor(fs, dtype=x0.dtype, device=x0.device)
        return PlannerResult(x, f, iterations, evaluations)


def _ipopt(
    max_iter: int = REFERENCE_MAX_ITER, memory: int | None = None, compile: bool = False, **options
) -> IpoptPlanner:
    """``planner("ipopt", max_iter=..., memory=..., compile=...)``: an :class:`IpoptPlanner`
    capped at ``max_iter`` IPOPT iterations; L-BFGS's ``memory`` and ``compile`` do not apply
    and are ignored; other ``options`` go to :class:`IpoptPlanner`."""
    return IpoptPlanner(max_iter=max_iter, **options)


def register_ipopt() -> None:
    """Register :class:`IpoptPlanner` as planner ``"ipopt"`` (then
    ``ContactImplicitMPC.from_env(env, plant, planner="ipopt")`` plans through IPOPT, capped
    at the settings' ``max_iter`` iterations; its settings must freeze the gaps); a second
    call does nothing."""
    if PLANNERS.get("ipopt") is not _ipopt:
        register_planner("ipopt", _ipopt)
