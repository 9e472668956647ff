"""Named MPC presets: their values, the CLI's --preset with single-value overrides, the API."""

import dataclasses

import pytest
import torch

from torchcontact.mpc.evaluate import parse_args
from torchcontact.mpc.fingertips import fingertips_mpc
from torchcontact.mpc.presets import (
    DEFAULT_PRESET,
    PRESETS,
    MPCSettings,
    preset,
    preset_options,
)


def test_the_three_presets_exist_and_balanced_is_the_default():
    assert set(PRESETS) == {"fast", "balanced", "accurate"}
    assert DEFAULT_PRESET == "balanced"
    assert parse_args(["fingertips"]).settings == PRESETS["balanced"]
    assert preset_options() == PRESETS["balanced"].options()


def test_the_cli_takes_a_preset_and_overrides_single_values():
    fast = parse_args(["trifinger", "--preset", "fast"]).settings
    assert fast == PRESETS["fast"]
    mixed = parse_args(["trifinger", "--preset", "fast", "--horizon", "6", "--no-compile"])
    assert mixed.settings == dataclasses.replace(PRESETS["fast"], horizon=6, compile=False)


def test_preset_options_build_the_mpc_they_name():
    options = preset_options("fast")
    assert options["dtype"] in (torch.float32, torch.float64)
    mpc = fingertips_mpc("cube", **{**options, "compile": False})
    settings = preset("fast")
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
    ],
)
def test_bad_settings_are_refused_by_name(bad, message):
    with pytest.raises(ValueError, match=message):
        MPCSettings(**bad)


def test_an_unknown_preset_is_refused_by_name():
    with pytest.raises(ValueError, match="preset must be one of"):
        preset("fastest")
