"""Environment descriptions: a robot, its object's plant, the model's system, cost, tasks and
presets, one registered instance per environment (``fingertips``, ``trifinger``, ``allegro``).

``environment("trifinger")`` returns the registered description; a user's robot becomes one
with :func:`~torchcontact.environments.custom.from_mjcf` and, to run it by name,
:func:`register_environment`.
"""

import functools
from pathlib import Path

from torchcontact.environments.base import Environment
from torchcontact.environments.custom import from_mjcf
from torchcontact.environments.fingertips import FINGERTIPS
from torchcontact.environments.hands import ALLEGRO_ENV, TRIFINGER_ENV
from torchcontact.environments.options import CostOptions
from torchcontact.environments.robot_options import RobotOptions
from torchcontact.validation import register

ENVIRONMENTS: dict[str, Environment] = {
    env.name: env for env in (FINGERTIPS, TRIFINGER_ENV, ALLEGRO_ENV)
}
"""The registered environments by name."""


def register_environment(env: Environment) -> Environment:
    """Register ``env`` under ``env.name`` (which must be new); returns it."""
    if not isinstance(env, Environment):
        raise ValueError(f"env must be an Environment, got {type(env).__name__}")
    register(ENVIRONMENTS, env.name, env, "environment", lambda e: True)
    return env


def environment(
    name: str,
    robot: str | None = None,
    tips: tuple[str, ...] | None = None,
    options: RobotOptions | None = None,
) -> Environment:
    """The registered environment ``name`` (one of :data:`ENVIRONMENTS`), or with ``robot``
    (an MJCF path) the user robot of :func:`~torchcontact.environments.custom.from_mjcf`
    with fingertip sites ``tips`` (None: the file's sites named ``*tip``) and ``options``
    (what is set beyond its file), named ``name``."""
    options = RobotOptions() if options is None else options
    if not isinstance(options, RobotOptions):
        raise TypeError(f"options must be RobotOptions or None, got {type(options).__name__}")
    if robot is not None:
        return _custom(name, str(robot), None if tips is None else tuple(tips), options)
    if not options.is_default:
        raise ValueError("options (RobotOptions) are for a user robot: give its robot file too")
    if name not in ENVIRONMENTS:
        raise ValueError(f"env must be one of {sorted(ENVIRONMENTS)}, got {name!r}")
    return ENVIRONMENTS[name]


@functools.lru_cache(maxsize=8)
def _custom(
    name: str, robot: str, tips: tuple[str, ...] | None, options: RobotOptions
) -> Environment:
    """A user robot's environment, built once per process."""
    env = from_mjcf(robot, tips, name=name, **options.environment_arguments())
    joints = len(env.layout.joints) - 1  # the object's free joint first
    if options.initial_joints is not None and len(options.initial_joints) != joints:
        raise ValueError(
            f"initial_joints must have {joints} values, one per joint of {Path(robot).name}, "
            f"got {len(options.initial_joints)}"
        )
    return env


__all__ = [
    "ENVIRONMENTS",
    "CostOptions",
    "Environment",
    "RobotOptions",
    "environment",
    "from_mjcf",
    "register_environment",
]
