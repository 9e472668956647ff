"""Named MPC settings on the measured speed–accuracy front: ``fast``, ``balanced``, ``accurate``.

A preset fixes the solver's settings, not the task's: L-BFGS iterations and memory, the
horizon T, the dtype and whether the objective is compiled. Presets are per environment, as
the measured fronts differ: a 2-step horizon was the fastest and most successful setting on the
three swept TriFinger objects and the worst fingertip one. The values come from the MPC-level
sweep of ``python benchmarks/tradeoff.py`` (:mod:`torchcontact.mpc.tradeoff`, 10 trials per
pair), which reruns every setting below and reports whether each preset is on its
environment's front; README "Choosing settings" shows the figures. Allegro was not swept: it
takes TriFinger's presets except ``balanced``, the paper's settings in float32.

``balanced`` is the default of ``torchcontact run`` and of :func:`preset_options`::

    mpc = hand_mpc("trifinger", **preset_options("trifinger", "fast"))
    torchcontact run trifinger --preset fast
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch

GAPS = ("frozen", "propagated")
"""How the MPC's model treats the contact distances φ̃ over the horizon, by name.

``"frozen"``: the paper's Algorithm 1, every step of the rollout sees the distances detected at
the real state. ``"propagated"``: J̃ stays frozen, but each step's distance follows the motion
the model itself predicts, to first order along the frozen normal rows,
``φ_{t+1} = φ_t + h Jⁿ v_t``: a tip the plan moves off the object stops pushing it later in the
horizon, and one it presses in pushes harder (complementarity-free model only)."""


@dataclass(frozen=True)
class MPCSettings:
    """The solver settings of a :class:`~torchcontact.mpc.controller.ContactImplicitMPC`.

    Attributes:
        max_iter: L-BFGS line-search rounds per control step (fewer when it converges first).
        memory: L-BFGS (s, y) pairs kept.
        horizon: T, model steps planned ahead.
        dtype: ``"float32"`` or ``"float64"``, of the solve.
        compile: ``torch.compile`` the objective and optimizer steps (else eager).
        gaps: ``"frozen"`` (the paper's) or ``"propagated"`` contact distances over the
            horizon, see :data:`GAPS`.
    """

    max_iter: int = 30
    memory: int = 8
    horizon: int = 4
    dtype: str = "float64"
    compile: bool = True
    gaps: str = "frozen"

    def __post_init__(self):
        for name in ("max_iter", "memory", "horizon"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.gaps not in GAPS:
            raise ValueError(f"gaps must be one of {GAPS}, got {self.gaps!r}")

    def options(self) -> dict:
        """Keyword arguments of the MPC factories (``dtype`` as a torch dtype)."""
        return {**asdict(self), "dtype": getattr(torch, self.dtype)}

    @property
    def label(self) -> str:
        """Short description: ``it30 m8 T4 f64 compiled``."""
        mode = "compiled" if self.compile else "eager"
        label = f"it{self.max_iter} m{self.memory} T{self.horizon} f{self.dtype[-2:]} {mode}"
        return label if self.gaps == "frozen" else f"{label}, {self.gaps} gaps"


PAPER = MPCSettings()
"""The settings every environment ran with before the sweep: 30 iterations, memory 8, T = 4
(the paper's horizon), float64, compiled."""

_TRIFINGER = {
    "fast": MPCSettings(horizon=2),
    "balanced": MPCSettings(max_iter=15, dtype="float32"),
    "accurate": MPCSettings(horizon=6),
}

PRESETS: dict[str, dict[str, MPCSettings]] = {
    "fingertips": {
        "fast": MPCSettings(max_iter=5),
        "balanced": MPCSettings(max_iter=20, dtype="float32", gaps="propagated"),
        "accurate": MPCSettings(memory=16),
    },
    "trifinger": _TRIFINGER,
    "allegro": {**_TRIFINGER, "balanced": MPCSettings(dtype="float32")},
}
"""Presets by environment and name (module docstring: where the values come from). TriFinger's
``fast`` (T = 2) was the fastest and most successful setting on the three swept objects, but
over 8 of the 17 objects it lost 2.5 points of success to T = 4, so ``balanced`` keeps the
paper's T = 4. Its cap of 15 iterations comes from full 17-object sweeps with the objects
colliding as their hulls. Session 9, float64: 5, 8, 10, 15 and 30 iterations reached 96.8,
97.6, 97.1, 97.4 and 97.4 % success (within three trials of each other), 8 and more at
12.1, 13.0–13.6, 14.5 and 13.4 ms median (the median step takes 8 iterations under any cap
of 8 or more). In float32 with the learned K(q), 8 (session 13), 10 and 15 (session 14)
reached 96.8, 96.5 and 97.4 % at 3.3, 2.9 and 2.9 ms median (the median step again 8
iterations; 10 and 15 ran side by side, one process each). So 15: the one cap at or above the
paper's 97 % in both, at no cost in the median step;
``accurate`` (T = 6) had the smallest final angle error, at 3× the solve time. The fingertips'
``balanced`` caps L-BFGS at 20 iterations since their default K became the stiffer 4.64, which
needs more of them: over the nine pairs × 20 trials 15, 20 and 30 iterations gave 81.7, 86.1
and 84.4 % success at 8.8, 10.7 and 13.9 ms median (docs/journal.md, fingertips). Since session
10 it plans with propagated gaps: 96.1 % of the nine pairs × 20 against 87.8 % frozen, at a
12.9 ms median (the in-air cube and foam brick 100 % against 75 and 65 %). The TriFinger's
stays frozen: propagated, its first 157 trials lost 3 successes to the frozen sweep's. Since
session 13 both hands' ``balanced`` solve in float32 (the Allegro's otherwise the paper's
settings): full 17-object sweeps gave the TriFinger (8 iterations then) 96.8 % against 96.5 %
in float64 at a 3.3 ms median, the Allegro 87.9 % against 89.1 % (4 trials of 340) at 4.1 ms
against 7.0 ms (docs/journal.md, TriFinger and Allegro)."""

NAMES = ("fast", "balanced", "accurate")
DEFAULT_PRESET = "balanced"


def preset(env: str, name: str = DEFAULT_PRESET) -> MPCSettings:
    """The settings of preset ``name`` (one of :data:`NAMES`) for environment ``env``."""
    if env not in PRESETS:
        raise ValueError(f"env must be one of {tuple(PRESETS)}, got {env!r}")
    if name not in NAMES:
        raise ValueError(f"preset must be one of {NAMES}, got {name!r}")
    return PRESETS[env][name]


def preset_options(env: str, name: str = DEFAULT_PRESET) -> dict:
    """:meth:`MPCSettings.options` of :func:`preset`: ``hand_mpc(hand, **...)``."""
    return preset(env, name).options()
