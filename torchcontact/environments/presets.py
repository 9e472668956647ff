"""Solver settings of the MPC and the names of the presets on the measured speed–accuracy front.

A preset fixes the solver's settings, not the task's: planner iterations and memory, the
horizon T, the dtype, compilation and how gaps evolve over the horizon. Each environment holds
its own presets (``env.presets``), as the measured fronts differ; ``python
benchmarks/tradeoff.py --level mpc`` (:mod:`studies.mpc_tradeoff`) reruns the sweep they come
from. ``balanced`` is the default of ``torchcontact run`` and of
:meth:`~torchcontact.mpc.controller.ContactImplicitMPC.from_env`::

    mpc = ContactImplicitMPC.from_env(env, plant, settings="fast")
    torchcontact run trifinger --preset fast
"""

from __future__ import annotations

from dataclasses import dataclass, field

GAPS = ("frozen", "propagated", "redetect", "live")
"""Where the MPC's rollout takes its contacts from over the horizon, by name.

``"frozen"``: the paper's Algorithm 1, every step of the rollout sees the contacts detected at
the real state. ``"propagated"``: J̃ stays frozen, but each step's distance follows the motion
the model itself predicts, to first order along the frozen normal rows,
``φ_{t+1} = φ_t + h Jⁿ v_t``: a tip the plan moves off the object stops pushing it later in the
horizon, and one it presses in pushes harder. ``"redetect"``: MuJoCo detects again at each
state the warm start predicts, one frozen set per step. ``"live"``: the torch contact geometry
at every planned state, inside the gradient (:mod:`~torchcontact.mpc.sources`). All but
``"frozen"`` need the complementarity-free model."""


SETTING_LIMITS = {"max_iter": 100_000, "memory": 1_000, "horizon": 1_000}
"""The largest value each count of :class:`MPCSettings` takes: far beyond any plan that runs in
a control step (the paper's are 30, 8 and 4), and small enough that a mistyped value is
refused at once rather than allocating a rollout for minutes."""


@dataclass(frozen=True)
class MPCSettings:
    """The solver settings of a :class:`~torchcontact.mpc.controller.ContactImplicitMPC`.

    Attributes:
        max_iter: L-BFGS line-search rounds per control step (fewer when it converges first).
        memory: L-BFGS (s, y) pairs kept.
        horizon: T, model steps planned ahead.
        dtype: ``"float32"`` or ``"float64"``, of the solve.
        compile: ``torch.compile`` the objective and optimizer steps (else eager).
        gaps: where the rollout's contacts come from over the horizon, one of :data:`GAPS`
            (``"frozen"``: the paper's).
    """

    max_iter: int = field(default=30, metadata={"help": "planner iterations per control step"})
    memory: int = field(default=8, metadata={"help": "L-BFGS memory, (s, y) pairs kept"})
    horizon: int = field(default=4, metadata={"help": "T, model steps planned ahead"})
    dtype: str = field(
        default="float64",
        metadata={"help": "the solve's floating-point type", "choices": ("float32", "float64")},
    )
    compile: bool = field(
        default=True, metadata={"help": "plan eagerly, without torch.compile (slower)"}
    )
    gaps: str = field(
        default="frozen",
        metadata={
            "help": "where the plan's contacts come from over the horizon: frozen (the "
            "paper's Algorithm 1), propagated along the frozen normal rows, redetect (MuJoCo "
            "at the warm start's predicted states) or live (the torch geometry at every "
            "planned state); all but frozen for the paper model only",
            "choices": GAPS,
        },
    )

    def __post_init__(self):
        for name, most in SETTING_LIMITS.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= most:
                raise ValueError(f"{name} must be an integer from 1 to {most:,}, got {value!r}")
        if not isinstance(self.compile, bool):
            raise ValueError(f"compile must be True or False, got {self.compile!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.gaps not in GAPS:
            raise ValueError(f"gaps must be one of {GAPS}, got {self.gaps!r}")

    @property
    def label(self) -> str:
        """Short description: ``it30 m8 T4 f64 compiled``."""
        mode = "compiled" if self.compile else "eager"
        label = f"it{self.max_iter} m{self.memory} T{self.horizon} f{self.dtype[-2:]} {mode}"
        return label if self.gaps == "frozen" else f"{label}, {self.gaps} gaps"


PAPER = MPCSettings()
"""The paper's settings: 30 iterations, memory 8, T = 4, float64 (compiled, frozen gaps)."""

NAMES = ("fast", "balanced", "accurate")
DEFAULT_PRESET = "balanced"
