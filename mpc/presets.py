"""Named MPC settings on the measured speed–accuracy front: ``fast``, ``balanced``, ``accurate``.

A preset fixes the solver's settings, not the task's: L-BFGS iterations and memory, the
horizon T, the dtype and whether the objective is compiled. The values come from the MPC-level
sweep of ``python benchmarks/tradeoff.py`` (:mod:`torchcontact.mpc.tradeoff`), which reruns
every setting below and marks the presets on its Pareto plots; README "Choosing settings"
shows the figures. ``balanced`` is the default of ``torchcontact run`` and of
:func:`preset_options`.

    mpc = hand_mpc("trifinger", **preset_options("fast"))
    torchcontact run trifinger --preset fast
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch


@dataclass(frozen=True)
class MPCSettings:
    """The solver settings of a :class:`~torchcontact.mpc.controller.ContactImplicitMPC`.

    Attributes:
        max_iter: L-BFGS line-search rounds per control step (fewer when it converges first).
        memory: L-BFGS (s, y) pairs kept.
        horizon: T, model steps planned ahead.
        dtype: ``"float32"`` or ``"float64"``, of the solve.
        compile: ``torch.compile`` the objective and optimizer steps (else eager).
    """

    max_iter: int = 30
    memory: int = 8
    horizon: int = 4
    dtype: str = "float64"
    compile: bool = True

    def __post_init__(self):
        for name in ("max_iter", "memory", "horizon"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")

    def options(self) -> dict:
        """Keyword arguments of the MPC factories (``dtype`` as a torch dtype)."""
        return {**asdict(self), "dtype": getattr(torch, self.dtype)}

    @property
    def label(self) -> str:
        """Short description: ``it30 m8 T4 f64 compiled``."""
        mode = "compiled" if self.compile else "eager"
        return f"it{self.max_iter} m{self.memory} T{self.horizon} f{self.dtype[-2:]} {mode}"


PRESETS: dict[str, MPCSettings] = {
    "fast": MPCSettings(max_iter=10, memory=8, horizon=4, dtype="float32"),
    "balanced": MPCSettings(),
    "accurate": MPCSettings(max_iter=50, memory=8, horizon=4),
}
"""The named presets; see the module docstring for where their values come from."""

DEFAULT_PRESET = "balanced"


def preset(name: str) -> MPCSettings:
    """The settings of preset ``name`` (one of :data:`PRESETS`)."""
    if name not in PRESETS:
        raise ValueError(f"preset must be one of {tuple(PRESETS)}, got {name!r}")
    return PRESETS[name]


def preset_options(name: str = DEFAULT_PRESET) -> dict:
    """:meth:`MPCSettings.options` of preset ``name``: ``fingertips_mpc(obj, **...)``."""
    return preset(name).options()
