"""Receding-horizon contact-implicit MPC (the paper's Algorithm 1) over any contact model.

At each real state: detect contacts once and freeze the model's step over the horizon
(``model.freeze``); roll it out for T steps (optionally advancing φ̃ along the frozen normal
rows, ``gaps="propagated"``); let the planner minimize Σₜ c(qₜ, uₜ) + V(q_T) over u₀…u_{T−1}
in their box (gradients by ``torch.func``); apply u₀; warm-start the next solve from the
shifted plan. The contact model, the cost and the planner are each chosen by name or passed
in; :meth:`ContactImplicitMPC.from_env` builds the MPC of an environment's plant. A system that
carries the object's momentum (a fitted calibration's ``object_momentum``) is rolled out from
the object's displacement between the last two states planned from. A model with an object
residual (:class:`~torchcontact.residual.ObjectResidual`) plans with it as
:data:`RESIDUAL_PLANS` says.
"""

from __future__ import annotations

import functools
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import torch

from torchcontact.contacts import Contacts
from torchcontact.environments import costs
from torchcontact.environments.base import Environment
from torchcontact.environments.costs import Cost
from torchcontact.environments.presets import GAPS, MPCSettings
from torchcontact.integrate import JointLayout, difference, integrate
from torchcontact.model import ComplementarityFree, ContactModel, contact_model
from torchcontact.mpc import background, planners
from torchcontact.mpc.background import BackgroundCompile, graph_key
from torchcontact.mpc.compile_notes import (
    CompilingWarning,
    foreground_notice,
    quiet_known_inductor_warnings,
)
from torchcontact.mpc.models import default_model
from torchcontact.mpc.planners import LBFGS, Objective, Planner
from torchcontact.mpc.sources import (
    MOVING,
    ContactsAt,
    FrozenAlongPlan,
    anchor_states,
    live_reach,
    redetected,
)
from torchcontact.sim.dynamics import joint_layout
from torchcontact.sim.geometry import scene_geometry
from torchcontact.sim.plant import Plant
from torchcontact.systems import QuasiDynamic
from torchcontact.validation import check_finite, check_shape, checking_values, validate_args

Fingertips = Callable[[torch.Tensor], torch.Tensor]
"""Forward kinematics ``q (..., nq) ↦ fingertip positions (..., n_tips, 3)`` [m]."""

CONTACT_BUCKET = 4
"""Without a slot capacity (the MPC's ``contact_slots``), or for contacts that exceed it, the
MPC pads the detected contacts with inert slots to a multiple of this many: a compiled plan is
specialised to its number of rows, so scenes of nearby slot counts share one compiled graph
instead of compiling one each (a minute or more apiece). Padding rows are zero, so they change
no velocity."""

RESIDUAL_PLANS = ("fixed", "full")
"""How the MPC plans with a model's object residual. ``"fixed"``: the residual's correction
``δv`` is evaluated once per solve, along the warm start (the shifted last plan) from the
measured state, and added as a constant to the planned steps, so the plan's gradient is the
contact model's (a zero-order correction of the model's error, in distribution since the warm
start is what the MPC did). ``"full"``: the residual is evaluated, and differentiated, at every
planned state and control (on the Allegro its plans stalled: the planner steered the network
toward commands its data never held, docs/experiments.md)."""


@dataclass(frozen=True)
class Plan:
    """One MPC solve: the control to apply and how the solve went."""

    control: torch.Tensor  # (n_u,) u₀
    controls: torch.Tensor  # (T, n_u) the whole plan
    cost: float
    iterations: int
    evaluations: int
    solve_ms: float
    compiled: bool = False  # planned by the compiled graph (not eagerly while it compiles)


class ContactImplicitMPC:
    """MPC over a quasi-dynamic system whose contacts are frozen over the horizon.

    Args:
        system: the quasi-dynamic system (Q, b(u)); one carrying the object's momentum
            (``object_momentum``) needs the complementarity-free model.
        model: a contact model that can be frozen (:meth:`ContactModel.freeze`), e.g.
            ``contact_model("paper", stiffness=0.5)`` or ``contact_model("relaxed_qp")``.
        layout: the joint layout of q (block ``object`` a free joint, then the robot).
        fingertips: forward kinematics of the fingertips, see :data:`Fingertips`.
        cost: the cost, see :class:`~torchcontact.environments.costs.Cost`.
        u_lower, u_upper: ``(n_u,)`` or floats, the control box.
        horizon: T steps; h: the model's time step [s].
        planner: a :class:`~torchcontact.mpc.planners.Planner`; default L-BFGS with the
            paper's 30 iterations and memory 8, compiled as ``compile``.
        compile: compile the objective (traced into the planner where the planner and the
            model allow; the first call compiles, cached on disk after that).
        dtype: of the solve.
        gaps: where the rollout's contacts come from over the horizon, one of
            :data:`~torchcontact.environments.presets.GAPS` (:mod:`~torchcontact.mpc.sources`).
        contacts_at: contacts at any states ``q (..., nq)``, for the sources that move with
            the plan: the plant's detector for ``"redetect"``, a differentiable torch function
            (:class:`~torchcontact.geometry.SceneGeometry`) for ``"live"``; unused otherwise.
        background_compile: with ``compile``, compile each new graph in a child process
            and plan eagerly until it is ready, instead of waiting for it; a graph this
            machine has compiled before is loaded at once (see
            :mod:`~torchcontact.mpc.background`). Needs a planner with an ``eager()`` method
            (L-BFGS has one); :attr:`Plan.compiled` tells which steps the graph planned.
        residual_plan: one of :data:`RESIDUAL_PLANS`, how a model's object residual enters
            the plan (no effect on a model without one).
        contact_slots: the slot capacity: every solve's contacts are padded with inert slots
            (zero rows) to this many, so that one compiled graph serves every object whose
            detection fits (``from_env`` takes the plant's
            :attr:`~torchcontact.sim.plant.Plant.contact_capacity`); contacts with more slots
            are padded to their multiple of :data:`CONTACT_BUCKET` instead, a graph of their
            own, with a warning the first time. None: every solve to its multiple of
            :data:`CONTACT_BUCKET`.
    """

    def __init__(
        self,
        system: QuasiDynamic,
        model: ContactModel,
        layout: JointLayout,
        fingertips: Fingertips,
        cost: Cost,
        u_lower,
        u_upper,
        horizon: int = 4,
        h: float = 0.1,
        planner: Planner | None = None,
        compile: bool = False,
        dtype: torch.dtype = torch.float64,
        gaps: str = "frozen",
        background_compile: bool = False,
        residual_plan: str = "fixed",
        contacts_at: ContactsAt | None = None,
        contact_slots: int | None = None,
    ):
        if contact_slots is not None and (
            isinstance(contact_slots, bool)
            or not isinstance(contact_slots, int)
            or contact_slots < 1
        ):
            raise ValueError(
                f"contact_slots must be a positive integer or None, got {contact_slots!r}"
            )
        if residual_plan not in RESIDUAL_PLANS:
            raise ValueError(
                f"residual_plan must be one of {RESIDUAL_PLANS}, got {residual_plan!r}"
            )
        if not isinstance(horizon, int) or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if not h > 0:
            raise ValueError(f"h must be positive, got {h!r}")
        if not isinstance(model, ContactModel):
            raise ValueError(f"model must be a ContactModel, got {type(model).__name__}")
        if gaps not in GAPS:
            raise ValueError(f"gaps must be one of {GAPS}, got {gaps!r}")
        if gaps in MOVING and contacts_at is None:
            raise ValueError(f"gaps={gaps!r} needs contacts_at, the contacts at any state q")
        if gaps in MOVING and not isinstance(model, ComplementarityFree):
            raise ValueError(
                f"gaps={gaps!r} needs the complementarity-free model (a QP step is solved "
                f"at one set of rows), got a {type(model).__name__}"
            )
        self.contacts_at = contacts_at
        self.system = system.to(dtype)
        self.model = model.to(dtype)
        if self.carries_momentum and not isinstance(model, ComplementarityFree):
            # a solved step (the relaxed QP) is linearized at all T planned steps at once,
            # before the rollout; carried momentum makes each step's b depend on the last
            raise ValueError(
                "system carries the object's momentum, which only the complementarity-free "
                f"model can plan with; got a {type(model).__name__}: use a system without "
                "object_momentum (a calibration without it)"
            )
        self.layout, self.fingertips, self.cost = layout, fingertips, cost
        self.horizon, self.h, self.dtype, self.gaps = horizon, float(h), dtype, gaps
        self.residual_plan, self.contact_slots = residual_plan, contact_slots
        self._overflowed: set[int] = set()  # slot counts above contact_slots, warned about once
        self.planner = LBFGS(compile=compile) if planner is None else planner
        n_u = system.n_robot
        self.lower = torch.as_tensor(u_lower, dtype=dtype).expand(horizon, n_u).reshape(1, -1)
        self.upper = torch.as_tensor(u_upper, dtype=dtype).expand(horizon, n_u).reshape(1, -1)
        if bool((self.lower > self.upper).any()):
            raise ValueError("u_lower must not exceed u_upper")
        self.compiled = compile
        self._reach = _Reach()
        self._differentiate, self._objective, self._freeze, self._live = self._compiled()
        self._warm = torch.zeros(1, horizon * n_u, dtype=dtype)
        self._last_q: torch.Tensor | None = None  # the state of the previous plan, for momentum
        self._object_rows = torch.tensor(system.object_dofs)
        background = compile and background_compile and hasattr(self.planner, "eager")
        self._background = BackgroundCompile() if background else None
        self._eager_planner = self.planner.eager() if background else None
        self._graph_keys: dict[tuple[int, int], str] = {}  # by (slots, nv): hashing is slow

    @classmethod
    def from_env(
        cls,
        env: Environment,
        plant: Plant,
        model: ContactModel | str | None = None,
        planner: Planner | str | None = None,
        settings: MPCSettings | str | None = None,
        cost: Cost | str | None = None,
        background_compile: bool = False,
        residual_plan: str = "fixed",
    ) -> ContactImplicitMPC:
        """The MPC of ``env``'s ``plant``: its system (the plant's object mass), layout,
        fingertips, cost, control box and h.

        ``model``: a contact model, a name of :data:`~torchcontact.model.MODELS` built with
        its defaults (the relaxed QP's κ is then the paper's at h = 0.1 s: for another h,
        pass ``RelaxedQP(paper_relaxation(h))``), or None for the model ``torchcontact run``
        plans with (:func:`~torchcontact.mpc.models.default_model`: the environment's shipped
        model where it ships one, the TriFinger's, otherwise the paper's at
        ``env.default_stiffness``); a model holding a fitted
        :class:`~torchcontact.calibration.SystemCalibration` plans with the system it
        calibrates;
        ``planner``: a planner or a name of :data:`~torchcontact.mpc.planners.PLANNERS`,
        built with the settings' iterations, memory and compilation (None: ``env.planner``);
        ``settings``: solver settings or a preset name (default the environment's default
        preset); ``cost``: a cost or a registered name (None: ``env.cost(plant)``). With all
        four None, the MPC is the one ``torchcontact run`` builds for ``env``'s defaults;
        ``background_compile``, ``residual_plan``: as in the constructor; ``contact_slots``
        is the plant's :attr:`~torchcontact.sim.plant.Plant.contact_capacity`, the same for
        every object of the environment, so their plans share one compiled graph.
        """
        _check_from_env(env, plant, model, planner, settings, cost, background_compile)
        if settings is None or isinstance(settings, str):
            settings = env.preset() if settings is None else env.preset(settings)
        if model is None:
            model = default_model(env)
        elif isinstance(model, str):
            model = _named("model", model, contact_model)
        if planner is None:
            planner = env.planner
        if isinstance(planner, str):
            options = {"max_iter": settings.max_iter, "memory": settings.memory}
            planner = planners.planner(planner, compile=settings.compile, **options)
        if cost is None:
            cost = env.cost(plant)
        elif isinstance(cost, str):
            cost = costs.cost(cost)
        bound = env.control_bound(plant)
        dtype = getattr(torch, settings.dtype)
        system = env.system(plant)
        calibration = getattr(model, "calibration", None)
        if calibration is not None:
            system = calibration.apply(system)
        contacts_at = None
        if settings.gaps == "redetect":
            contacts_at = plant.detector
        elif settings.gaps == "live":
            contacts_at = scene_geometry(plant.detector, dtype=dtype)
        return cls(
            system,
            model,
            env.layout,
            env.fingertips(dtype),
            cost,
            -bound,
            bound,
            horizon=settings.horizon,
            h=env.h(plant),
            planner=planner,
            compile=settings.compile,
            dtype=dtype,
            gaps=settings.gaps,
            background_compile=background_compile,
            residual_plan=residual_plan,
            contacts_at=contacts_at,
            contact_slots=getattr(plant, "contact_capacity", None),
        )

    def reset(self) -> None:
        """Forget the warm start and the last state (call between episodes)."""
        self._warm.zero_()
        self._last_q = None

    def __getstate__(self) -> dict:
        """Pickled (for a background compile) without its compiled callables and child."""
        state = self.__dict__.copy()
        state.update(
            _differentiate=None, _objective=None, _freeze=None, _live=None, _background=None
        )
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._differentiate, self._objective, self._freeze, self._live = self._compiled()

    def _compiled(self) -> tuple[Callable, Callable, Callable | None, Callable | None]:
        """:meth:`differentiate`, :meth:`objective`, the closed form's freeze and the live
        contacts, through ``torch.compile`` when the MPC compiles (the objective alone serves
        sampling planners, which need no gradient; a freeze is plain tensor algebra for the
        closed form only, whose K(q), D(q) networks and dual rows took 0.4 ms of a TriFinger
        solve eagerly).

        With ``"live"`` contacts the geometry is a graph of its own, compiled once and called
        at every planned state from the objective's graph (through a graph break), and the
        gradient is a tape over the two: traced inline, the geometry's forward and backward at
        each state of four unrolled L-BFGS rounds made a graph that did not finish compiling in
        50 minutes (docs/experiments.md, "The MPC's contact sources")."""
        live = self.contacts_at if self.gaps == "live" else None
        if live is not None and not self.compiled:
            live = functools.partial(_contacts_through, live, self._reach)
        if not self.compiled:
            return self.taped, self.objective, None, live
        freeze = None
        if isinstance(self.model, ComplementarityFree):
            freeze = torch.compile(self.model.freeze, dynamic=False, fullgraph=True)
        objective = torch.compile(self.objective, dynamic=False)
        if live is not None:
            config = torch._dynamo.config  # a graph per vertex bucket and batch shape
            config.recompile_limit = max(config.recompile_limit, LIVE_GRAPHS)
            live = torch.compile(live, dynamic=False)
            live = functools.partial(_contacts_through, live, self._reach)
            return functools.partial(_taped, objective), objective, freeze, live
        return torch.compile(self.differentiate, dynamic=False), objective, freeze, None

    @property
    def compiling(self) -> bool:
        """Whether a background compile (``background_compile``) is running."""
        return self._background is not None and self._background.compiling

    def wait_for_compile(self) -> None:
        """Block until a background compile (``background_compile``) has finished; Ctrl-C
        stops it (its graph is compiled again when next needed) and raises
        ``KeyboardInterrupt``."""
        if self._background is not None:
            try:
                self._background.wait()
            except KeyboardInterrupt:
                self._background.cancel()
                raise

    @property
    def compile_pid(self) -> int | None:
        """The process id of the running background compile, or None."""
        return None if self._background is None else self._background.pid

    @property
    def compile_log(self):
        """The file the background compile writes its output to (None without one)."""
        return None if self._background is None else self._background.log

    @property
    def compile_elapsed(self) -> float:
        """Seconds the running background compile has taken so far (0 without one)."""
        return 0.0 if self._background is None else self._background.elapsed

    def freeze(self, q: torch.Tensor, contacts: Contacts, compiled: bool | None = None):
        """The model's step frozen at the contacts detected at ``q (nq,)``; its inner
        iterations compiled as ``compiled`` (default: as the MPC)."""
        compiled = self.compiled if compiled is None else compiled
        options = {"without_residual": True} if self.residual is not None else {}
        if compiled and self._freeze is not None:
            return self._freeze(contacts, self.h, q, **options)
        return self.model.freeze(contacts, self.h, q, compile=compiled, **options)

    @property
    def residual(self):
        """The model's :class:`~torchcontact.residual.ObjectResidual`, which :meth:`rollout`
        applies at each planned state, or None."""
        return getattr(self.model, "residual", None)

    @property
    def carries_momentum(self) -> bool:
        """Whether the system carries the object's momentum from step to step."""
        return getattr(self.system, "object_momentum", None) is not None

    @property
    def fixes_residual(self) -> bool:
        """Whether the model has a residual that plans enter as a constant (``"fixed"``)."""
        return self.residual is not None and self.residual_plan == "fixed"

    def rollout(self, q0, controls, frozen, moved=None, corrections=None) -> torch.Tensor:
        """States ``(..., T+1, nq)`` from ``q0 (nq,)`` under ``controls (..., T, n_u)``.

        The step ``frozen`` (:meth:`freeze`) stays frozen over the horizon, as does Q: so with
        frozen gaps each step's velocity depends on its own control only and all T are
        computed at once; propagated gaps chain the steps through φ̃, and a system carrying
        momentum through the object's displacement, ``moved (n_o,)`` [m, rad] before q0.
        ``corrections (T, nv)`` [m/s, rad/s] are added to the steps' velocities (a fixed
        residual, :meth:`residual_corrections`); without them a model's residual is applied
        at each planned state.
        """
        chained = self.carries_momentum or self.gaps in MOVING
        if chained or (self.residual is not None and corrections is None):
            return self._chained_rollout(q0, controls, frozen, moved, corrections)[0]
        Q, b = self.system(controls)
        states = [q0.expand(*controls.shape[:-2], -1)]
        if self.gaps == "propagated":
            for t in range(self.horizon):
                v = _corrected(frozen.velocity(Q, b[..., t, :]), corrections, t)
                states.append(integrate(states[-1], v, self.h, self.layout))
                frozen = frozen.advance_gaps(v)
            return torch.stack(states, dim=-2)
        v = frozen.velocity(Q, b)
        if corrections is not None:
            v = v + corrections
        for t in range(self.horizon):
            states.append(integrate(states[-1], v[..., t, :], self.h, self.layout))
        return torch.stack(states, dim=-2)

    def _chained_rollout(self, q0, controls, frozen, moved, corrections=None):
        """:meth:`rollout` step by step, for a system carrying momentum (the steps chained
        through the object's displacement) or a model with a residual (applied at each
        planned state unless ``corrections`` are given), and φ̃ with propagated gaps. Returns
        the states and the residual's corrections ``(..., T, nv)`` it applied (None without).
        The contacts that move with the plan (:data:`~torchcontact.mpc.sources.MOVING`) are
        rolled out here too, each step's frozen step from :meth:`_step`."""
        states, applied = [q0.expand(*controls.shape[:-2], -1)], []
        for t in range(self.horizon):
            options = {"object_displacement": moved} if self.carries_momentum else {}
            Q, b = self.system(controls[..., t, :], **options)
            v = self._step(frozen, t, states[-1]).velocity(Q, b)
            if corrections is not None:
                v = _corrected(v, corrections, t)
            elif self.residual is not None:
                corrected = self.residual(states[-1], b, v, self.h)
                applied.append(corrected - v)
                v = corrected
            states.append(integrate(states[-1], v, self.h, self.layout))
            moved = self.h * v[..., self._object_rows]
            if self.gaps == "propagated":
                frozen = frozen.advance_gaps(v)
        applied = torch.stack(applied, dim=-2) if applied else None
        return torch.stack(states, dim=-2), applied

    def _step(self, frozen, t: int, q: torch.Tensor):
        """The frozen step of horizon step ``t`` at the planned states ``q (..., nq)``: the
        one frozen at the real state, or the source's (:mod:`~torchcontact.mpc.sources`)."""
        if isinstance(frozen, FrozenAlongPlan):
            return frozen.at(t, q, self.layout)
        if self.gaps == "live" and t > 0:  # the freeze traced into the objective, if compiled
            return self.freeze(q, self._live(q), compiled=False)
        return frozen

    def residual_corrections(self, q0, controls, frozen, previous=None) -> torch.Tensor:
        """The residual's corrections ``(T, nv)`` [m/s, rad/s] along ``controls (T, n_u)``
        from ``q0 (nq,)`` (``frozen`` and ``previous`` as in :meth:`objective`), without
        gradient: the constants a ``"fixed"`` residual plan adds to its steps."""
        if self.residual is None:
            raise ValueError("residual_corrections needs a model with a residual")
        with torch.no_grad():
            frozen = frozen.linearized(*self.system(controls))
            moved = None if previous is None else self.displacement(previous, q0)
            return self._chained_rollout(q0, controls, frozen, moved)[1]

    def objective(self, controls, q0, frozen, target_p, target_quat, *extras):
        """Cost ``(...)`` of ``controls (..., T, n_u)`` (arguments as :meth:`rollout`).
        ``extras``, each optional, told apart by their shapes: ``previous (nq,)``, the state
        planned from before ``q0`` when the system carries momentum (the object's
        displacement to ``q0`` is worked out here, inside the traced graph, rather than
        eagerly before each solve; none: at rest), and the residual's ``corrections (T, nv)``
        when it is fixed (:attr:`fixes_residual`; none: the residual applied in full)."""
        previous = next((extra for extra in extras if extra.dim() == 1), None)
        corrections = next((extra for extra in extras if extra.dim() == 2), None)
        moved = None if previous is None else self.displacement(previous, q0)
        states = self.rollout(q0, controls, frozen, moved, corrections)
        pose = self.layout.object_pose(states)
        tips = self.fingertips(states)
        return self.cost(pose[..., :3], pose[..., 3:], tips, controls, target_p, target_quat)

    def value_and_grad(
        self, controls, q0, frozen, target_p, target_quat, *extras, compiled: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Cost ``(B,)`` and its gradient ``(B, T, n_u)`` for ``controls (B, T, n_u)``.

        The frozen step is first linearized at these controls outside the gradient transform
        (the relaxed QP solves there; the closed form needs nothing).
        """
        frozen = frozen.linearized(*self.system(controls))
        differentiate = self._differentiate if compiled else self.taped
        return differentiate(controls, q0, frozen, target_p, target_quat, *extras)

    def value(
        self, controls, q0, frozen, target_p, target_quat, *extras, compiled: bool = True
    ) -> torch.Tensor:
        """Cost ``(B,)`` of ``controls (B, T, n_u)`` without its gradient (for sampling), the
        frozen step linearized as in :meth:`value_and_grad`."""
        frozen = frozen.linearized(*self.system(controls))
        objective = self._objective if compiled else self.objective
        return objective(controls, q0, frozen, target_p, target_quat, *extras)

    def differentiate(self, controls, *args) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`value_and_grad` of :meth:`objective` by ``torch.func.grad``.

        ``torch.func.grad`` rather than a recorded tape: one traced graph for value and
        gradient, which ``torch.compile`` fuses into a faster graph than a compiled tape.
        """

        def total(c):
            cost = self.objective(c, *args)
            return cost.sum(), cost  # rows are independent: ∇ of the sum is each row's ∇

        grad, cost = torch.func.grad(total, has_aux=True)(controls)
        return cost, grad

    def taped(self, controls, *args) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`differentiate` by a recorded tape (``torch.autograd``), the eager
        gradient: on these small tensors ``torch.func.grad``'s transforms cost more than its
        ops when not compiled (1.7–1.9× a fingertips, TriFinger or Allegro objective's value and
        gradient, docs/experiments.md, "Speed"); the same values up to rounding."""
        return _taped(self.objective, controls, *args)

    def _flat_value_and_grad(
        self, x: torch.Tensor, *args, compiled: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`value_and_grad` of flat controls ``x (N, T·n_u)``; grad ``(N, T·n_u)``."""
        controls = x.unflatten(-1, (self.horizon, -1))
        f, grad = self.value_and_grad(controls, *args, compiled=compiled)
        return f, grad.flatten(-2)

    def _flat_eager_value_and_grad(self, x: torch.Tensor, *args):
        """:meth:`_flat_value_and_grad` never compiled; a bound method of the MPC, as planners
        such as the IPOPT baseline expect of an objective."""
        return self._flat_value_and_grad(x, *args, compiled=False)

    def _flat_value(self, x: torch.Tensor, *args, compiled: bool = True) -> torch.Tensor:
        """:meth:`value` of flat controls ``x (N, T·n_u)``."""
        return self.value(x.unflatten(-1, (self.horizon, -1)), *args, compiled=compiled)

    def _flat_eager_value(self, x: torch.Tensor, *args) -> torch.Tensor:
        """:meth:`_flat_value` never compiled."""
        return self._flat_value(x, *args, compiled=False)

    def _flat_differentiate(self, x: torch.Tensor, *args) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`differentiate` of flat controls ``x (N, T·n_u)``, for a traced planner."""
        f, grad = self.differentiate(x.unflatten(-1, (self.horizon, -1)), *args)
        return f, grad.flatten(-2)

    def plan(
        self, q: torch.Tensor, contacts: Contacts, target_p: torch.Tensor, target_quat: torch.Tensor
    ) -> Plan:
        """Solve the MPC problem at state ``q (nq,)`` with the contacts detected there, toward
        ``target_p (3,)`` [m], ``target_quat (4,)``."""
        check_shape("q", q, f"({self.layout.nq},)", q.shape == (self.layout.nq,))
        check_finite("q", q)
        check_shape("target_p", target_p, "(3,)", target_p.shape == (3,))
        check_shape("target_quat", target_quat, "(4,)", target_quat.shape == (4,))
        check_finite("target_p", target_p)
        check_finite("target_quat", target_quat)
        if not isinstance(contacts, Contacts):
            raise TypeError(f"contacts must be Contacts, got {type(contacts).__name__}")
        if checking_values(target_quat) and not bool(target_quat.detach().norm() > 0):
            raise ValueError("target_quat must be a non-zero quaternion, got a zero quaternion")
        start = time.perf_counter()
        # inputs checked above (contacts when built): what plan derives from them is not
        # checked again (each value check is a host sync inside a solve of a few ms)
        with validate_args(False):
            return self._plan(q, contacts, target_p, target_quat, start)

    def _plan(self, q, contacts, target_p, target_quat, start: float) -> Plan:
        """:meth:`plan` after its checks; ``start``: its ``time.perf_counter()``."""
        q, contacts = q.to(self.dtype), contacts.to(self.dtype)
        observe = getattr(self.cost, "observe", None)
        if observe is not None:  # a cost that depends on the contacts at the plan's start
            observe(contacts)
        target_p, target_quat = target_p.to(self.dtype), target_quat.to(self.dtype)
        targets = (target_p, target_quat) + self._previous(q)
        if self.gaps == "redetect":  # the solve's state: the (T, nq) anchors, the real one first
            q = anchor_states(self, q, contacts, self._warm.reshape(self.horizon, -1))
            contacts = redetected(self.contacts_at, q, contacts)
        if self.gaps == "live" and hasattr(self.contacts_at, "within"):  # the broad phase
            step = max(float(self.upper.abs().max()), float(self.lower.abs().max()))
            self._reach.groups = live_reach(self.contacts_at, q, self.horizon, step)
        contacts = contacts.padded(self.padded_slots(contacts.slots))
        if self.fixes_residual:  # the warm start, whose corrections _frozen_args works out
            targets += (self._warm.reshape(self.horizon, -1).clone(),)
        inputs = (q, contacts, targets, self._warm.clone())
        compiled, compiling = self.compiled, None
        if self._background is not None:
            warmup = functools.partial(self._solve, *inputs, compiled=True)  # for the child
            compiled = self._background.ready(self._graph_key(contacts), warmup)
        elif compiled:
            compiling = self._announce_compile(contacts)
        result = self._solve(*inputs, compiled=compiled)
        if compiling is not None:
            background.mark(compiling)
        controls = result.x.reshape(self.horizon, self.system.n_robot)
        self._warm = torch.cat([controls[1:], controls[-1:]]).reshape(1, -1)
        return Plan(
            control=controls[0].clone(),
            controls=controls,
            cost=float(result.f[0]),
            iterations=result.iterations,
            evaluations=result.evaluations,
            solve_ms=1e3 * (time.perf_counter() - start),
            compiled=compiled,
        )

    def warm_up(
        self, q: torch.Tensor, contacts: Contacts, target_p: torch.Tensor, target_quat: torch.Tensor
    ) -> bool:
        """Compile, in the foreground, the graph that :meth:`plan` with these arguments runs,
        into this machine's cache (loaded at once where the cache holds it), and mark it, so
        that later runs plan compiled from their first step. The MPC is left as it was (its
        warm start, its last state, its background compile). Returns whether the graph was
        compiled (False: it was in the cache). Needs a compiled MPC."""
        if not self.compiled:
            raise ValueError("warm_up needs a compiled MPC (settings with compile=True)")
        key = self._graph_key(contacts.to(self.dtype).padded(self.padded_slots(contacts.slots)))
        cached = background.marked(key)
        kept = (self._background, self._eager_planner, self._warm.clone(), self._last_q)
        self._background = self._eager_planner = None
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", CompilingWarning)  # compiling is the point
                self.plan(q, contacts, target_p, target_quat)
        finally:
            self._background, self._eager_planner, self._warm, self._last_q = kept
        background.mark(key)
        return not cached

    def _announce_compile(self, contacts: Contacts) -> str | None:
        """Before a foreground compiled solve at ``contacts``: the first time this process
        meets its graph, quiet Inductor's known-harmless messages and, where this machine's
        cache lacks the graph, warn (:class:`~torchcontact.mpc.compile_notes.CompilingWarning`)
        that this ``plan()`` compiles it. Returns the graph's key to mark once compiled, or
        None."""
        key = self._graph_key(contacts)
        if key in _GRAPHS_MET:
            return None
        _GRAPHS_MET.add(key)
        quiet_known_inductor_warnings()
        if background.marked(key):
            return None
        description = (
            f"{type(self.cost).__name__}, T = {self.horizon}, {contacts.slots} contact slots, "
            f"{str(self.dtype).removeprefix('torch.')}"
        )
        warnings.warn(CompilingWarning(foreground_notice(description)), stacklevel=4)
        return key

    def padded_slots(self, slots: int) -> int:
        """The slot count a solve pads contacts of ``slots`` slots to: :attr:`contact_slots`
        where they fit (one compiled graph for every object), else the multiple of
        :data:`CONTACT_BUCKET` that holds them (a warning the first time for each count)."""
        if self.contact_slots is not None and slots <= self.contact_slots:
            return self.contact_slots
        bucket = -(-slots // CONTACT_BUCKET) * CONTACT_BUCKET
        if self.contact_slots is not None and slots not in self._overflowed:
            self._overflowed.add(slots)
            warnings.warn(
                f"{slots} contact slots exceed the MPC's capacity of {self.contact_slots}: these "
                f"plans are padded to {bucket} slots, a compiled graph of their own",
                stacklevel=3,
            )
        return bucket

    def displacement(self, previous: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """The object's displacement ``(..., n_o)`` [m, rad] from ``previous`` to ``q`` (both
        ``(..., nq)``): its velocity rows of :func:`difference` over a unit step."""
        return difference(previous, q, 1.0, self.layout)[..., self._object_rows]

    def _previous(self, q: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``(previous,)``, the state the last plan started from (a copy of ``q`` at an
        episode's first: no displacement), when the system carries momentum; else ``()``. A
        copy, not ``q`` itself: a compiled graph is specialised to which of its inputs alias,
        so ``q`` twice would compile a second graph for each episode's first plan, and every
        later call would check the guards of both."""
        last, self._last_q = self._last_q, q
        if not self.carries_momentum:
            return ()
        return (q.clone() if last is None else last,)

    def _solve(self, q, contacts, targets, warm, compiled: bool):
        """The planner's result from the warm start ``warm (1, T·n_u)``, compiled or eager;
        ``targets``: the target position and quaternion, then the objective's ``extras`` (with
        a fixed residual, the warm start ``(T, n_u)`` in place of its corrections)."""
        eager = self._eager_planner if self._eager_planner is not None else self.planner
        planner = self.planner if compiled else eager
        box = (self.lower, self.upper)
        live = self.gaps == "live"  # its geometry is called through a graph break
        applies_prepare = getattr(planner, "applies_prepare", False) and not live
        if compiled and self._freeze is not None and applies_prepare:
            # the closed form's freeze is traced into the planner's first compiled call
            objective = Objective(
                self._flat_value_and_grad, self._flat_differentiate, self._flat_value,
                prepare=self._frozen_args,
            )  # fmt: skip
            with validate_args(False):
                return planner.plan(objective, warm, box, args=(q, contacts, *targets))
        args = self._frozen_args(q, contacts, *targets, compiled=compiled)
        if compiled:
            traceable = self._flat_differentiate if args[1].traceable and not live else None
            objective = Objective(self._flat_value_and_grad, traceable, self._flat_value)
        else:
            objective = Objective(self._flat_eager_value_and_grad, value=self._flat_eager_value)
        with validate_args(False):
            return planner.plan(objective, warm, box, args=args)

    def _frozen_args(self, q, contacts, *targets, compiled: bool | None = None) -> tuple:
        """The objective's arguments ``(q, frozen, *extras)`` from ``(q, contacts,
        *targets)`` (an :attr:`Objective.prepare`, traced into a compiled planner's first
        call): the model's step frozen at ``contacts`` (compiled as ``compiled``, default as
        the MPC), and with a fixed residual its corrections along the warm start that ends
        ``targets``."""
        with torch.no_grad():
            frozen = self.freeze(q, contacts, compiled)
            if q.dim() == 2:  # "redetect": a step frozen at each of the (T, nq) anchors
                frozen, q = FrozenAlongPlan(frozen, q), q[0]
            if not self.fixes_residual:
                return (q, frozen, *targets)
            *targets, warm = targets
            corrections = self.residual_corrections(q, warm, frozen, *targets[2:])
            return (q, frozen, *targets, corrections)

    def _graph_key(self, contacts: Contacts) -> str:
        """What the compiled graph of a solve at ``contacts`` is specialised to (all but the
        contacts' shape fixed with the MPC, so computed once per shape)."""
        shape = (contacts.slots, contacts.nv)
        if shape not in self._graph_keys:
            self._graph_keys[shape] = graph_key(
                self.model, self.cost, self.fingertips, self.layout, self.planner, self.system,
                self.horizon, self.h, self.dtype, self.gaps, *shape, self.lower, self.upper,
                *(("residual_plan", self.residual_plan) if self.residual is not None else ()),
            )  # fmt: skip
        return self._graph_keys[shape]


_GRAPHS_MET: set[str] = set()
"""Keys of the compiled graphs this process has planned with in the foreground (compiled or
loaded): the compiled callables are shared by every MPC of the process."""


LIVE_GRAPHS = 64
"""The most graphs of the live geometry one process keeps (Dynamo's recompile limit, 8 by
default, after which it would run eagerly): one per polytope vertex bucket
(:func:`~torchcontact.geometry.scene.vertex_bucket`), batch shape and dtype."""


class _Reach:
    """The live geometry's groups within reach of the current solve (``SceneGeometry.
    within``; None: all), set before each solve and read behind the graph break, so that the
    objective's graph does not depend on them."""

    groups: tuple[bool, ...] | None = None


@torch.compiler.disable
def _contacts_through(geometry: Callable, reach: _Reach, q: torch.Tensor) -> Contacts:
    """``geometry(q)`` behind a graph break: the compiled objective calls the compiled
    geometry as a graph of its own (one function for every MPC, so that no objective graph is
    specialised to one MPC's geometry), over the groups within reach (a graph per set)."""
    return geometry(q) if reach.groups is None else geometry(q, reach.groups)


def _taped(objective: Callable, controls: torch.Tensor, *args) -> tuple[torch.Tensor, torch.Tensor]:
    """Cost ``(B,)`` of ``objective(controls, *args)`` and its gradient by a recorded tape."""
    with torch.enable_grad():
        controls = controls.detach().requires_grad_(True)
        cost = objective(controls, *args)
        (grad,) = torch.autograd.grad(cost.sum(), controls)
    return cost.detach(), grad


def _corrected(v: torch.Tensor, corrections: torch.Tensor | None, t: int) -> torch.Tensor:
    """Velocity ``v (..., nv)`` of step ``t`` plus its fixed correction, if any."""
    return v if corrections is None else v + corrections[t]


def _named(argument: str, name: str, build: Callable):
    """``build(name)``, its unknown-name error naming ``argument`` instead of ``name``."""
    try:
        return build(name)
    except ValueError as error:
        raise ValueError(f"{argument}: {error}".replace(": name must", " must", 1)) from None


def _check_from_env(env, plant, model, planner, settings, cost, background_compile) -> None:
    """``TypeError`` naming the argument of :meth:`ContactImplicitMPC.from_env` of the wrong
    kind; ``ValueError`` for a plant that is not ``env``'s (its joints differ)."""
    if not isinstance(env, Environment):
        raise TypeError(f"env must be an Environment, got {type(env).__name__}")
    if not isinstance(plant, Plant):
        raise TypeError(f"plant must be a Plant (env.make_plant(...)), got {type(plant).__name__}")
    joints = joint_layout(plant.model).joints
    if joints != env.layout.joints:
        raise ValueError(
            f"plant must be a plant of {env.name} (joints {', '.join(env.layout.joints)}), got "
            f"one with joints {', '.join(joints)}"
        )
    kinds = (
        ("model", model, (ContactModel, str), "a ContactModel, a model's name or None"),
        ("settings", settings, (MPCSettings, str), "MPCSettings, a preset's name or None"),
    )
    for name, value, accepted, expected in kinds:
        if value is not None and not isinstance(value, accepted):
            raise TypeError(f"{name} must be {expected}, got {type(value).__name__}")
    if planner is not None and not (isinstance(planner, str) or hasattr(planner, "plan")):
        raise TypeError(f"planner must be a Planner, a planner's name or None, got {planner!r}")
    if cost is not None and not (isinstance(cost, str) or callable(cost)):
        raise TypeError(f"cost must be a Cost (a callable), a cost's name or None, got {cost!r}")
    if not isinstance(background_compile, bool):
        raise TypeError(f"background_compile must be True or False, got {background_compile!r}")
