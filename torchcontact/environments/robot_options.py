"""What a user may set of a user robot's environment where its MJCF does not say it.

Each field is the one home of its setting, as :mod:`torchcontact.environments.options`' are:
``torchcontact run custom`` generates its option from it and a trial's configuration holds it.
None keeps what the robot's file and reach give
(:func:`~torchcontact.environments.custom.from_mjcf`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from torchcontact.environments.custom import PoseTask
from torchcontact.validation import is_finite_number


def _pair(help: str) -> dict:
    return {"help": help, "metavar": "LOW,HIGH"}


@dataclass(frozen=True)
class RobotOptions:
    """A user robot's environment (run custom), None for what its MJCF and reach give."""

    initial_joints: tuple[float, ...] | None = field(
        default=None,
        metadata={
            "help": "the joints at the start of every trial [rad or m], one per joint; "
            "default the file's first keyframe, else its joints' reference positions",
            "metavar": "Q1,Q2,...",
        },
    )
    control_bound: float | None = field(
        default=None,
        metadata={
            "help": "|u| per joint and step [rad or m]; default 1/40 of the narrowest range "
            "the position actuators command"
        },
    )
    placement: tuple[float, float] | None = field(
        default=None,
        metadata={
            "help": "where the object starts, its centre's x,y [m]; default the support's "
            "centre where a tip can touch the object there",
            "metavar": "X,Y",
        },
    )
    target_x: tuple[float, float] | None = field(
        default=None,
        metadata=_pair(
            "the target's x offset from the placement, drawn from LOW..HIGH [m]; default half "
            "of how far a tip can push the object along x"
        ),
    )
    target_y: tuple[float, float] | None = field(
        default=None,
        metadata=_pair("the target's y offset, as --target-x along y"),
    )
    lift: tuple[float, float] | None = field(
        default=None,
        metadata=_pair(
            "the target's height above its rest, drawn from LOW..HIGH [m]; default where two "
            "opposing tips can squeeze the object, else 0,0"
        ),
    )

    def __post_init__(self):
        joints = self.initial_joints
        if joints is not None and not (
            isinstance(joints, tuple) and joints and all(map(is_finite_number, joints))
        ):
            raise ValueError(f"initial_joints must be None or finite numbers, got {joints!r}")
        bound = self.control_bound
        if bound is not None and not (is_finite_number(bound) and bound > 0):
            raise ValueError(f"control_bound must be a positive finite number, got {bound!r}")
        self.task()  # the task checks its region

    def task(self) -> PoseTask | None:
        """The :class:`~torchcontact.environments.custom.PoseTask` of these options, or None
        where no region is set (the environment's default task)."""
        region = {name: getattr(self, name) for name in REGION if getattr(self, name) is not None}
        return PoseTask(**region) if region else None

    def environment_arguments(self) -> dict:
        """The keyword arguments of :func:`~torchcontact.environments.custom.from_mjcf` that
        these options set."""
        given = {"initial_joints": self.initial_joints, "control_bound": self.control_bound}
        given["task"] = self.task()
        return {name: value for name, value in given.items() if value is not None}

    @property
    def is_default(self) -> bool:
        """Whether nothing is set."""
        return self == RobotOptions()


REGION = ("placement", "target_x", "target_y", "lift")
"""The fields of :class:`RobotOptions` that set its task's region."""
