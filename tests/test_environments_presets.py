"""Named MPC presets per environment: their values, the CLI's --preset with overrides, the API."""

import dataclasses

import pytest
import torch

from torchcontact.environments.presets import (
    DEFAULT_PRESET,
    NAMES,
    PRESETS,
    MPCSettings,
    preset,
    preset_options,
)
from torchcontact.mpc.evaluate import parse_args
from torchcontact.mpc.fingertips import fingertips_mpc
from torchcontact.mpc.suites import SUITES
from torchcontact.mpc.tradeoff import GRID


def test_every_environment_has_the_three_presets_and_balanced_is_the_default():
    assert NAMES == ("fast", "balanced", "accurate") and DEFAULT_PRESET == "balanced"
    assert set(PRESETS) == set(SUITES)
    for env in SUITES:
        assert set(PRESETS[env]) == set(NAMES)
        assert parse_args([env]).settings == PRESETS[env]["balanced"]
        assert preset_options(env) == PRESETS[env]["balanced"].options()


def test_the_fingertips_plan_with_propagated_gaps_by_default_the_hands_with_frozen():
    assert PRESETS["fingertips"]["balanced"].gaps == "propagated"
    assert PRESETS["trifinger"]["balanced"].gaps == PRESETS["allegro"]["balanced"].gaps == "frozen"
    assert parse_args(["fingertips"]).settings.gaps == "propagated"
    assert "propagated gaps" in PRESETS["fingertips"]["balanced"].label


def test_the_swept_environments_presets_are_all_in_the_measured_grid():
    for env in ("fingertips", "trifinger"):
        assert all(p.label in GRID for p in PRESETS[env].values())


def test_the_cli_takes_a_preset_and_overrides_single_values():
    fast = parse_args(["trifinger", "--preset", "fast"]).settings
    assert fast == PRESETS["trifinger"]["fast"]
    mixed = parse_args(["fingertips", "--preset", "fast", "--horizon", "6", "--no-compile"])
    assert mixed.settings == dataclasses.replace(
        PRESETS["fingertips"]["fast"], horizon=6, compile=False
    )


def test_preset_options_build_the_mpc_they_name():
    options = preset_options("fingertips", "balanced")
    mpc = fingertips_mpc("cube", **{**options, "compile": False})
    settings = preset("fingertips", "balanced")
    assert (mpc.max_iter, mpc.memory, mpc.horizon) == (
        settings.max_iter,
        settings.memory,
        settings.horizon,
    )
    assert mpc.dtype == getattr(torch, settings.dtype)


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
        preset("trifinger", "fastest")
    with pytest.raises(ValueError, match="env must be one of"):
        preset("shadow_hand", "fast")
