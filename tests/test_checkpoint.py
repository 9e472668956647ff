"""Checkpoints: a file that is not one is refused by name, without unsafe advice; models are
built by registry, saved only when they load, and checked against the scene they plan."""

import math

import pytest
import torch

from torchcontact.checkpoint import (
    PARAMETERIZATIONS,
    STIFFNESS_KINDS,
    CheckpointError,
    FitConfig,
    build_model,
    check_fits,
    load_checkpoint,
    save_checkpoint,
    save_model,
)
from torchcontact.networks import ObjectContactNetwork
from torchcontact.shipped import resolve_learned
from torchcontact.stiffness import Constant, ContactNetwork, PerRow, StateNetwork


def test_a_file_that_is_no_checkpoint_is_named_without_unpickling_advice(tmp_path):
    path = tmp_path / "notes.pt"
    path.write_text("not a checkpoint\n")
    with pytest.raises(CheckpointError, match=r"notes\.pt: not a torchcontact checkpoint") as info:
        load_checkpoint(path)
    assert "weights_only" not in str(info.value)
    assert isinstance(info.value, ValueError)


def test_a_torch_file_of_other_content_is_refused(tmp_path):
    path = tmp_path / "weights.pt"
    torch.save({"layer.weight": torch.zeros(2)}, path)
    with pytest.raises(CheckpointError, match="expected version 1, found None"):
        load_checkpoint(path)
    torch.save({"version": 1, "config": {"no_such_field": 1}}, path)
    with pytest.raises(CheckpointError, match="damaged checkpoint"):
        load_checkpoint(path)


# --- building, saving and checking, on a hand-made meta (no dataset) -------------------------

META = {
    "scene": None,
    "gamma": 100.0,
    "facets": 4,
    "slots": 3,
    "nq": 9,
    "nv": 8,
    "nu": 2,
    "joints": ["free", "slide", "hinge"],
    "paper_stiffness": 2.0,
}


@pytest.mark.parametrize(
    ("kind", "expected"),
    [
        ("constant", Constant),
        ("per_row", PerRow),
        ("contact_network", ContactNetwork),
        ("state_network", StateNetwork),
        ("object_network", ObjectContactNetwork),
    ],
)
def test_each_kind_builds_its_registered_parameterization(kind, expected):
    assert STIFFNESS_KINDS == tuple(PARAMETERIZATIONS)
    model = build_model(FitConfig(stiffness=kind, damping=kind), META)
    assert type(model.stiffness) is expected and type(model.damping) is expected
    if kind == "constant":
        assert model.stiffness.value == pytest.approx(2.0)  # meta's K, config naming none
        assert model.damping.value == pytest.approx(0.2)


def test_a_saved_model_loads_to_the_same_weights(tmp_path):
    config = FitConfig(stiffness="per_row", damping="relative")
    model = build_model(config, META)
    path = save_checkpoint(tmp_path / "m.pt", model, config, META)
    loaded, loaded_config, meta = load_checkpoint(path)
    assert loaded_config == config and meta == META
    for a, b in zip(model.state_dict().values(), loaded.state_dict().values(), strict=True):
        assert torch.equal(a, b)


def test_weights_of_other_sizes_are_one_line(tmp_path):
    config = FitConfig(stiffness="per_row", damping="per_row")
    path = save_checkpoint(tmp_path / "m.pt", build_model(config, META), config, META)
    payload = torch.load(path, weights_only=True)
    payload["meta"]["slots"] = 5  # the weights stay those of 3 slots
    torch.save(payload, path)
    with pytest.raises(CheckpointError, match=r"does not rebuild its model.*size mismatch") as info:
        load_checkpoint(path)
    assert "\n" not in str(info.value) and "and 1 more" in str(info.value)


def test_a_meta_without_joints_is_named(tmp_path):
    config = FitConfig(stiffness="constant")
    path = save_checkpoint(tmp_path / "m.pt", build_model(config, META), config, META)
    payload = torch.load(path, weights_only=True)
    del payload["meta"]["joints"]
    torch.save(payload, path)
    with pytest.raises(
        CheckpointError, match=r"m\.pt: a damaged checkpoint: its meta records no joints"
    ):
        load_checkpoint(path)
    with pytest.raises(ValueError, match="meta must hold .*; it lacks joints$"):
        build_model(config, payload["meta"])


def test_arguments_of_the_wrong_type_are_named(tmp_path):
    config = FitConfig(stiffness="constant")
    model = build_model(config, META)
    path = tmp_path / "m.pt"
    with pytest.raises(TypeError, match="^model must be a ComplementarityFree, got dict$"):
        save_checkpoint(path, {}, config, META)
    with pytest.raises(TypeError, match="^config must be a FitConfig, got dict$"):
        save_checkpoint(path, model, {"stiffness": "constant"}, META)
    with pytest.raises(TypeError, match="^meta must be a dict .*, got list$"):
        save_checkpoint(path, model, config, [])
    with pytest.raises(TypeError, match="^config must be a FitConfig"):
        build_model("constant", META)
    other = build_model(FitConfig(stiffness="per_row"), META)
    with pytest.raises(ValueError, match="^model is not the architecture config and meta describe"):
        save_checkpoint(path, other, config, META)  # a file that would not load
    assert not path.exists()
    with pytest.raises(TypeError, match="^fitted must be the result of torchcontact.learn.fit.fit"):
        save_model(path, model)


@pytest.mark.parametrize(
    ("field", "value"),
    [("distance_scale", 0.0), ("distance_scale", math.nan), ("distance_scale", -1e-3),
     ("seed", -1), ("seed", 1.5), ("lr", 0)],
)  # fmt: skip
def test_fit_config_refuses_bad_numbers_naming_the_field(field, value):
    with pytest.raises(ValueError, match=f"^{field} must be"):
        FitConfig(**{field: value})


def test_a_checkpoint_fits_its_own_scene_only():
    joints = META["joints"]
    check_fits("m.pt", META, None, joints)  # a user's robot's checkpoint on a user's robot
    trifinger = {**META, "scene": "trifinger", "joints": ["free"] + ["hinge"] * 9}
    message = (
        r"^m\.pt: a checkpoint learned in the 'trifinger' environment on states of joints "
        r"free \+ 9 hinge, not for this robot \(joints free \+ slide \+ hinge\)"
    )
    with pytest.raises(CheckpointError, match=message):
        check_fits("m.pt", trifinger, None, joints)
    with pytest.raises(CheckpointError, match="learned on a user's robot, not 'fingertips'"):
        check_fits("m.pt", META, "fingertips", joints)
    with pytest.raises(CheckpointError, match="but this scene's are free \\+ 2 slide"):
        check_fits("m.pt", META, None, ["free", "slide", "slide"])


def test_learned_is_the_shipped_model_or_an_existing_file(tmp_path):
    assert resolve_learned(None, "trifinger") is None
    with pytest.raises(
        ValueError, match=r"^learned \(--learned\) must be 'shipped' .*got 'bogus'$"
    ):
        resolve_learned("bogus", "trifinger")
    with pytest.raises(TypeError, match="^learned must be 'shipped' or a checkpoint's path"):
        resolve_learned(3, "trifinger")
    path = tmp_path / "m.pt"
    path.write_bytes(b"")
    assert resolve_learned(path, "trifinger") == str(path)
