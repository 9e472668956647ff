"""What a user may set of an environment's cost: its terms.

Each field is the one home of its setting: ``torchcontact run`` generates its option from it
(:mod:`torchcontact.cli.options`), a trial's configuration holds it resolved
(:meth:`CostOptions.resolved`), and the environment's ``cost(plant, options)`` takes it. None
keeps the environment's own value (:attr:`~torchcontact.environments.base.Environment
.cost_defaults`). A field's metadata gives its ``off`` value (the paper's cost), the term it
``needs`` to mean anything, and how a run's header ``tells`` it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from torchcontact.validation import is_finite_number


@dataclass(frozen=True)
class CostOptions:
    """The environment's cost terms (hands), None for the environment's own."""

    hold_first: int | None = field(
        default=None,
        metadata={
            "help": "(hands) the contacts that must hold an object that tips before it slides "
            "before the plan moves it (0: no hold); default the environment's",
            "off": 0,
            "tells": "objects that tip held by {} contacts before they move",
        },
    )
    hold_approach: float | None = field(
        default=None,
        metadata={
            "help": "(hands, with a hold) the weight of the cost's contact term, relative to "
            "its own, until the object is held: it draws the tips to the object (1: the "
            "paper's throughout); default the environment's",
            "off": 1.0,
            "needs": "hold_first",
            "tells": "approached at {:g}× the contact term",
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

    @classmethod
    def off(cls) -> CostOptions:
        """Every term at its ``off`` value: the paper's cost, as a value for each term."""
        return cls(**{term.name: term.metadata["off"] for term in fields(cls)})

    def resolved(self, env, cost: str | None = None) -> CostOptions:
        """Every term given a value: the one set here, else the environment ``env``'s
        (``env.cost_defaults``), else off; a term whose ``needs`` is off is off.

        ``ValueError`` naming a term set on (not its ``off``) that cannot apply: one
        ``env``'s cost does not have (None in its defaults), any term with another cost
        than the environment's (``cost``, a registered cost's name), one whose ``needs`` is
        off."""
        values, offs = {}, CostOptions.off()
        for term in fields(self):
            off, needs = getattr(offs, term.name), term.metadata.get("needs")
            given, default = getattr(self, term.name), getattr(env.cost_defaults, term.name)
            needed = needs is None or values[needs] != getattr(offs, needs)
            if given is not None and given != off:
                if cost is not None:
                    raise ValueError(
                        f"{term.name} is a term of the environment's cost, not {cost!r}"
                    )
                if default is None:
                    raise ValueError(f"{term.name}: the {env.name} cost has no such term")
                if not needed:
                    raise ValueError(f"{term.name}: it applies with {needs} only; set {needs}")
            elif given is None:
                given = off if cost is not None or default is None or not needed else default
            values[term.name] = given
        return CostOptions(**values)

    def describe(self) -> str:
        """The terms on (not off), in words, for a run's header ("" with none)."""
        told = [
            term.metadata["tells"].format(getattr(self, term.name))
            for term in fields(self)
            if getattr(self, term.name) not in (None, term.metadata["off"])
        ]
        return ", ".join(told)
