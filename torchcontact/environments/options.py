"""What a user may set of an environment's cost: its terms.

Each field is the one home of its setting: ``torchcontact run`` generates its option from it
(:mod:`torchcontact.cli.options`), a trial's configuration holds it
(:class:`~torchcontact.mpc.trials.TrialConfig`) and the environment's ``cost(plant, options)``
takes it. None keeps the environment's own value.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from torchcontact.validation import is_finite_number


@dataclass(frozen=True)
class CostOptions:
    """The environment's cost terms (hands), None for the environment's own."""

    hold_first: int | None = field(
        default=None,
        metadata={
            "help": "(hands) the contacts that must hold an object that tips before it slides "
            "before the plan moves it (0: no hold); default the environment's"
        },
    )
    hold_approach: float | None = field(
        default=None,
        metadata={
            "help": "(hands, with a hold) the weight of the cost's contact term, relative to "
            "its own, until the object is held: it draws the tips to the object (1: the "
            "paper's throughout); default the environment's"
        },
    )

    def __post_init__(self):
        hold = self.hold_first
        if hold is not None and (isinstance(hold, bool) or not isinstance(hold, int) or hold < 0):
            raise ValueError(f"hold_first must be a number of contacts >= 0, got {hold!r}")
        approach = self.hold_approach
        if approach is not None and not (is_finite_number(approach) and approach > 0):
            raise ValueError(f"hold_approach must be a weight > 0, got {approach!r}")

    @property
    def is_default(self) -> bool:
        """Whether nothing is set."""
        return self == CostOptions()
