"""Where the MPC's rollout takes its contacts from over the horizon.

The source is the solver setting ``gaps`` (:data:`~torchcontact.environments.presets.GAPS`).
``"frozen"`` and ``"propagated"`` freeze the contacts detected at the real state (the paper's
Algorithm 1); the two here move them with the plan:

- ``"redetect"``: before each solve the warm start (the last plan, shifted) is rolled out and
  the contacts are detected again at each state it predicts; step t of every planned rollout is
  the step frozen at its own detection, its distances moved to first order from that *anchor*
  state to the planned one (:meth:`FrozenAlongPlan.at`). Detection stays outside the gradient:
  a contact the warm start does not reach stays out of this solve, and enters the next.
- ``"live"``: the contacts are a differentiable function of the state (the torch contact
  geometry, :class:`~torchcontact.geometry.SceneGeometry`) evaluated at every planned state
  inside the objective, so the gradient sees contacts open, close and move.

Both need the complementarity-free model: a frozen QP step is solved before the rollout, at
one set of rows.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch

from torchcontact.contacts import Contacts
from torchcontact.frozen import FrozenComplementarityFree
from torchcontact.integrate import JointLayout, difference, integrate

MOVING = ("redetect", "live")
"""The sources whose contacts move with the plan (they need a contact function of q)."""


def live_reach(geometry, q: torch.Tensor, horizon: int, step: float) -> tuple[bool, ...]:
    """The live geometry's groups to evaluate over a solve from ``q (nq,)``: those whose
    bounding spheres lie within the margin plus twice the most the robot's shapes move in
    ``horizon`` steps of at most ``step`` per joint (``SceneGeometry.lever``; twice: both
    shapes of a pair may move, an object pushed no faster than what pushes it), and every
    plane (the cheapest, and where a falling object goes faster than any bound of the
    robot's). A pair left out enters a later solve once it comes within reach."""
    reach = geometry.margin + 2 * horizon * step * geometry.lever(q)
    near = geometry.within(q, reach)
    return tuple(n or g.kind_b == "plane" for n, g in zip(near, geometry.groups, strict=True))


ContactsAt = Callable[[torch.Tensor], Contacts]
"""Contacts at states ``q (..., nq)``: the plant's detector for ``"redetect"`` (called outside
any gradient), a differentiable torch function for ``"live"``."""


class FrozenAlongPlan(NamedTuple):
    """One frozen step per horizon step, each at the state the warm start predicted there.

    Attributes:
        steps: the steps frozen at each anchor, every tensor field with a leading ``(T,)``.
        anchors: ``(T, nq)`` the predicted states (``anchors[0]`` the real state).
    """

    steps: FrozenComplementarityFree
    anchors: torch.Tensor

    traceable = True
    """Plain tensor algebra, as the steps it holds."""

    def linearized(self, Q: torch.Tensor, b: torch.Tensor) -> FrozenAlongPlan:
        """Itself: the closed form needs no solve before it is differentiated."""
        return self

    def at(self, t: int, q: torch.Tensor, layout: JointLayout) -> FrozenComplementarityFree:
        """Step ``t``'s frozen step for the planned state ``q (..., nq)``: its distances
        ``φ̃ + Jⁿ·(q ⊖ anchor_t)``, the rows' first-order motion from the anchor to ``q``."""
        fields = self.steps._asdict()
        step = FrozenComplementarityFree(
            **{k: v[t] if isinstance(v, torch.Tensor) else v for k, v in fields.items()}
        )
        if t == 0:  # the real state is the anchor
            return step
        return step.advance_gaps(difference(self.anchors[t], q, step.h, layout))


def anchor_states(mpc, q: torch.Tensor, contacts: Contacts, controls: torch.Tensor):
    """``(T, nq)`` the states ``controls (T, n_u)`` (the warm start) lead to from ``q (nq,)``
    under ``mpc``'s step frozen at ``contacts``, gaps propagated (momentum and residual left
    out: the anchors are points to linearize about, not a prediction the plan is judged by)."""
    with torch.no_grad():
        step = mpc.freeze(q, contacts, compiled=False)
        Q, b = mpc.system(controls)
        states = [q]
        for t in range(mpc.horizon - 1):
            v = step.velocity(Q, b[t])
            states.append(integrate(states[-1], v, mpc.h, mpc.layout))
            step = step.advance_gaps(v)
        return torch.stack(states)


def redetected(contacts_at: ContactsAt, anchors: torch.Tensor, first: Contacts) -> Contacts:
    """``(T, nc)`` contacts: ``first`` (detected at the real state) then those detected at
    ``anchors[1:]``, all padded to the larger slot count."""
    later = contacts_at(anchors[1:]).to(dtype=first.phi.dtype, device=first.phi.device)
    slots = max(first.slots, later.slots)
    return Contacts.cat([first.padded(slots)[None], later.padded(slots)])
