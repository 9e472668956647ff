"""Python's defaults are the command line's: ``ContactImplicitMPC.from_env(env, plant)`` builds
the MPC that ``torchcontact run ENV`` builds (:func:`~torchcontact.mpc.trials.build_trial` of
the run's first trial): the same model (the shipped one where the environment ships one),
cost, solver settings and control box. Building an MPC compiles nothing (a compiled MPC
compiles at its first plan), so both are built with their default, compiled settings."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import torch

from torchcontact.cli.run import configs_of, parse_args
from torchcontact.environments import ENVIRONMENTS, environment
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.models import default_model_fields
from torchcontact.mpc.trial_config import trial_configs
from torchcontact.mpc.trials import build_trial
from torchcontact.shipped import SHIPPED

ROOT = Path(__file__).resolve().parents[1]
GRIPPER = str(ROOT / "examples" / "two_finger_gripper.xml")

CASES = {name: [name] for name in sorted(ENVIRONMENTS)}
CASES["custom"] = ["custom", "--robot", GRIPPER, "--object", "cube"]
CASES["trifinger-stick"] = ["trifinger", "--object", "stick"]  # tips before it slides: a hold
"""``torchcontact run`` arguments per case: each registered environment with its default
object, a user's robot, and an object whose cost holds it first."""


def same(a, b) -> bool:
    """Whether two field values are equal: tensors exactly, dataclasses field by field, other
    objects without an equality of their own attribute by attribute."""
    if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
        return isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor) and torch.equal(a, b)
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(
            same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    if isinstance(a, (tuple, list)):
        return type(a) is type(b) and len(a) == len(b) and all(map(same, a, b))
    if type(a).__eq__ is object.__eq__ and hasattr(a, "__dict__"):  # a term's own state
        return (
            type(a) is type(b)
            and vars(a).keys() == vars(b).keys()
            and all(same(value, getattr(b, key)) for key, value in vars(a).items())
        )
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        return math.isnan(b)
    return a == b


def same_module(a: torch.nn.Module, b: torch.nn.Module) -> None:
    assert type(a) is type(b)
    left, right = a.state_dict(), b.state_dict()
    assert left.keys() == right.keys()
    for key in left:
        assert left[key].dtype == right[key].dtype and torch.equal(left[key], right[key]), key


@pytest.fixture(scope="module", params=sorted(CASES))
def built(request):
    """The CLI's default config of a case, the MPC it runs and the MPC from Python."""
    config = configs_of(parse_args(CASES[request.param]))[0]
    env, plant, cli = build_trial(config)
    assert env is environment(config.env, config.robot, config.tips)
    python = ContactImplicitMPC.from_env(env, env.make_plant(config.object))
    return request.param, env, config, cli, python


def test_the_cli_config_is_trial_configs_default(built):
    name, env, config, _, _ = built
    options = {"robot": config.robot} if config.robot else {}
    default = trial_configs(config.env, [(config.task, config.object)], [config.seed], **options)
    assert default == [config]
    assert config.settings == env.preset()
    model = config.model_options
    assert {k: getattr(model, k) for k in ("learned", "stiffness")} == default_model_fields(env)
    assert (model.learned == SHIPPED) == env.ships_model
    assert model.model == "paper" and config.planner == env.planner


def test_the_model_is_the_clis(built):
    name, env, config, cli, python = built
    same_module(python.model, cli.model)
    same_module(python.system, cli.system)  # a shipped calibration calibrates both
    if env.ships_model:  # the shipped model, not the paper's constant K
        assert config.model_options.learned == SHIPPED and config.model_options.stiffness is None
    else:
        assert float(python.model.stiffness.value) == pytest.approx(env.default_stiffness)


def test_the_settings_are_the_clis(built):
    _, env, config, cli, python = built
    settings = env.preset()
    for mpc in (cli, python):
        assert (mpc.horizon, mpc.dtype, mpc.gaps, mpc.compiled) == (
            settings.horizon,
            getattr(torch, settings.dtype),
            settings.gaps,
            settings.compile,
        )
        assert (mpc.planner.max_iter, mpc.planner.memory, mpc.planner.compile) == (
            settings.max_iter,
            settings.memory,
            settings.compile,
        )
    assert type(python.planner) is type(cli.planner)
    assert type(python.contacts_at) is type(cli.contacts_at)
    assert (python.h, python.residual_plan) == (cli.h, cli.residual_plan)


def test_the_control_box_is_the_clis(built):
    _, _, _, cli, python = built
    assert torch.equal(python.lower, cli.lower) and torch.equal(python.upper, cli.upper)


def test_the_cost_is_the_clis(built):
    name, env, _, cli, python = built
    assert type(python.cost) is type(cli.cost)
    if name == "trifinger-stick":  # the environment's hold-first term, in both
        assert cli.cost.hold is not None and cli.cost.hold.grip == env.cost_defaults.hold_first
    assert dataclasses.is_dataclass(cli.cost)
    for field in dataclasses.fields(cli.cost):
        assert same(getattr(python.cost, field.name), getattr(cli.cost, field.name)), field.name
