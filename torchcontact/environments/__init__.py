"""Environment descriptions: a robot, its object's plant, the model's system, cost, tasks and
presets, one registered instance per environment (``fingertips``, ``trifinger``, ``allegro``).

``environment("trifinger")`` returns the registered description; a user's robot becomes one
with :func:`~torchcontact.environments.custom.from_mjcf` and, to run it by name,
:func:`register_environment` (from the command line: ``torchcontact run NAME --import
MODULE``, :func:`import_environments`).
"""

import functools
import hashlib
import importlib
import importlib.util
import sys
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


def import_environments(module: str) -> list[str]:
    """Import ``module`` (a dotted module name, or the path of a ``.py`` file) for the
    environments it registers (:func:`register_environment`); returns the names registered
    by it (none when it was imported before). ``ValueError`` naming ``module`` when it cannot
    be imported, with the error it raised."""
    if not isinstance(module, str) or not module:
        raise ValueError(f"module must be a module name or a .py file, got {module!r}")
    before = set(ENVIRONMENTS)
    try:
        if module.endswith(".py"):
            _import_file(Path(module).resolve())
        else:
            importlib.import_module(module)
    except Exception as error:  # whatever the user's module raises, named in one line
        raise ValueError(
            f"module {module!r} must import, got {type(error).__name__}: {error}"
        ) from None
    return sorted(set(ENVIRONMENTS) - before)


def _import_file(path: Path) -> None:
    """Execute the Python file ``path`` once per process, as a module named after its path."""
    if not path.is_file():
        raise FileNotFoundError(f"no file {str(path)!r}")
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:8]
    name = f"torchcontact_user_{path.stem}_{digest}"
    if name in sys.modules:
        return
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise


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
    "import_environments",
    "CostOptions",
    "Environment",
    "RobotOptions",
    "environment",
    "from_mjcf",
    "register_environment",
]
