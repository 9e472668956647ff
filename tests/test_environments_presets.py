"""Named MPC presets per environment: their values, the CLI's --preset with overrides, the API."""

import dataclasses

import pytest
import torch

from studies.mpc_tradeoff import GRID
from torchcontact.cli.run import parse_args
from torchcontact.environments import ENVIRONMENTS, environment
from torchcontact.environments.presets import DEFAULT_PRESET, NAMES, PAPER, MPCSettings
from torchcontact.mpc.controller import ContactImplicitMPC


def test_every_environment_has_the_three_presets_and_balanced_is_the_default():
    assert NAMES == ("fast", "balanced", "accurate") and DEFAULT_PRESET == "balanced"
    assert set(ENVIRONMENTS) == {"fingertips", "trifinger", "allegro"}
    for name, env in ENVIRONMENTS.items():
        assert set(env.presets) == set(NAMES)
        assert env.preset() == env.preset("balanced") == env.presets["balanced"]
        assert parse_args([name]).settings == env.presets["balanced"]


def test_the_fingertips_plan_with_propagated_gaps_by_default_the_hands_with_frozen():
    presets = {name: env.presets for name, env in ENVIRONMENTS.items()}
    assert presets["fingertips"]["balanced"].gaps == "propagated"
    assert presets["trifinger"]["balanced"].gaps == presets["allegro"]["balanced"].gaps == "frozen"
    assert parse_args(["fingertips"]).settings.gaps == "propagated"
    assert "propagated gaps" in presets["fingertips"]["balanced"].label


def test_the_swept_environments_presets_are_all_in_the_measured_grid():
    for env in ("fingertips", "trifinger"):
        assert all(p.label in GRID for p in environment(env).presets.values())


def test_the_cli_takes_a_preset_and_overrides_single_values():
    fast = parse_args(["trifinger", "--preset", "fast"]).settings
    assert fast == environment("trifinger").preset("fast")
    mixed = parse_args(["fingertips", "--preset", "fast", "--horizon", "6", "--no-compile"])
    assert mixed.settings == dataclasses.replace(
        environment("fingertips").preset("fast"), horizon=6, compile=False
    )


@pytest.mark.parametrize("name", NAMES)
def test_a_preset_builds_the_mpc_it_names(name):
    """``from_env`` takes a preset by name: its iterations, memory and compilation go to the
    planner, its horizon, dtype and gaps to the MPC."""
    env = environment("fingertips")
    plant = env.make_plant("cube")
    mpc = ContactImplicitMPC.from_env(env, plant, settings=name)
    settings = env.preset(name)
    assert (mpc.planner.max_iter, mpc.planner.memory, mpc.horizon) == (
        settings.max_iter,
        settings.memory,
        settings.horizon,
    )
    assert mpc.dtype == getattr(torch, settings.dtype)
    assert mpc.gaps == settings.gaps
    assert mpc.compiled == mpc.planner.compile == settings.compile
    default = ContactImplicitMPC.from_env(env, plant)  # no settings: the default preset
    balanced = env.preset(DEFAULT_PRESET)
    assert (default.planner.max_iter, default.dtype) == (
        balanced.max_iter,
        getattr(torch, balanced.dtype),
    )


def test_the_papers_settings_and_their_label():
    assert (PAPER.max_iter, PAPER.memory, PAPER.horizon, PAPER.dtype) == (30, 8, 4, "float64")
    assert PAPER.compile and PAPER.gaps == "frozen"
    assert PAPER.label == "it30 m8 T4 f64 compiled"


@pytest.mark.parametrize(
    "bad, message",
    [
        (dict(max_iter=0), "max_iter"),
        (dict(memory=2.5), "memory"),
        (dict(horizon=-1), "horizon"),
        (dict(dtype="float16"), "dtype"),
        (dict(gaps="moving"), "gaps"),
    ],
)
def test_bad_settings_are_refused_by_name(bad, message):
    with pytest.raises(ValueError, match=message):
        MPCSettings(**bad)


def test_an_unknown_preset_or_environment_is_refused_by_name():
    with pytest.raises(ValueError, match="preset must be one of"):
        environment("trifinger").preset("fastest")
    with pytest.raises(ValueError, match="preset must be one of"):
        ContactImplicitMPC.from_env(
            environment("fingertips"), environment("fingertips").make_plant("cube"), settings="x"
        )
    with pytest.raises(ValueError, match="env must be one of"):
        environment("shadow_hand")
