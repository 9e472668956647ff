"""Object strings by their registered source: built-in names, generated objects, mesh files
and a user's own prefix, each told apart by :mod:`torchcontact.object_sources` alone, and a
user's prefix working from the registry to a plant, a trial's record and ``torchcontact run``."""

from __future__ import annotations

import json
import sys

import pytest
import trimesh

from torchcontact.cli import main
from torchcontact.digests import content_sha256
from torchcontact.environments import environment
from torchcontact.mpc.trial_config import trial_configs, trial_inputs
from torchcontact.object_sources import (
    OBJECT_SOURCES,
    canonical_object,
    expand_objects,
    mesh_file_of,
    object_source,
    record_stem,
    register_object_source,
)

BOX = (0.05, 0.04, 0.03)  # [m]


@pytest.fixture
def shelf(tmp_path):
    """A folder of the user's meshes, registered as the source ``shelf``; unregistered after."""
    folder = tmp_path / "shelf"
    folder.mkdir()
    trimesh.creation.box(extents=BOX).export(folder / "box.stl")
    register_object_source("shelf", lambda name: folder / f"{name}.stl", "shelf:NAME, a test mesh")
    yield folder
    OBJECT_SOURCES.pop("shelf", None)


@pytest.mark.parametrize(
    "obj, source, expanded, stem",
    [
        ("cube", None, None, "cube"),
        ("random-7", "generated", ["random-7"], "random-7"),
        ("random:3-5", "generated", ["random-3", "random-4", "random-5"], "random:3-5"),
    ],
)
def test_each_string_has_one_source(obj, source, expanded, stem):
    found = object_source(obj)
    assert (found and found.name) == source
    assert expand_objects(obj) == expanded and record_stem(obj) == stem
    assert mesh_file_of(obj) is None and canonical_object(obj) == obj


def test_a_mesh_path_is_one_file_however_it_is_typed(tmp_path, monkeypatch):
    trimesh.creation.box(extents=BOX).export(tmp_path / "part.stl")
    monkeypatch.chdir(tmp_path)
    assert object_source("part.stl").name == "mesh"
    assert canonical_object("part.stl") == str(tmp_path / "part.stl")
    assert record_stem(canonical_object("part.stl")).startswith("part-mesh-")
    with pytest.raises(ValueError, match="object must be an existing mesh file, got 'gone.stl'"):
        expand_objects("gone.stl")


def test_a_users_prefix_maps_names_to_its_mesh_files(shelf):
    assert object_source("shelf:box").name == "shelf"
    assert expand_objects("shelf:box") == ["shelf:box"]
    assert mesh_file_of("shelf:box") == shelf / "box.stl"
    assert record_stem("shelf:box") == "shelf-box"
    with pytest.raises(ValueError, match="must name an existing mesh file"):
        expand_objects("shelf:mug")
    with pytest.raises(ValueError, match="are named 'shelf:NAME'"):
        expand_objects("shelf:")


@pytest.mark.parametrize(
    "prefix, message",
    [
        ("Shelf", "prefix must be a lower-case name"),
        ("random", "prefix must be a new object source's"),
        ("mesh", "prefix must be a new object source's"),
    ],
)
def test_a_prefix_must_be_new_and_lower_case(prefix, message):
    with pytest.raises(ValueError, match=message):
        register_object_source(prefix, lambda name: name)


def test_a_users_object_reaches_a_plant_and_a_trials_record(shelf):
    env = environment("trifinger")
    assert env.select("all", "shelf:box") == [(task, "shelf:box") for task in env.tasks]
    plant = env.make_plant("shelf:box")
    assert plant.object.name == "mesh_box"  # built as a mesh file's object
    (config,) = trial_configs("trifinger", [("in-hand", "shelf:box")], [0])
    assert config.name == "trifinger_in-hand_shelf-box_seed0"
    inputs = trial_inputs(config)
    assert inputs["object_sha256"] == content_sha256(shelf / "box.stl")  # a changed file is new


@pytest.fixture
def module(tmp_path, shelf):
    """A user's module registering the same folder, as ``--import`` names it."""
    OBJECT_SOURCES.pop("shelf")
    path = tmp_path / "my_objects.py"
    path.write_text(
        "from torchcontact.object_sources import register_object_source\n"
        f"register_object_source('shelf', lambda name: {str(shelf)!r} + f'/{{name}}.stl')\n"
    )
    yield path
    for name in [n for n in sys.modules if n.startswith("torchcontact_user_my_objects_")]:
        del sys.modules[name]


def test_run_takes_an_object_of_a_prefix_its_module_registers(module, tmp_path):
    out = tmp_path / "out"
    argv = ["run", "trifinger", "--import", str(module), "--object", "shelf:box", "--trials", "1",
            "--max-steps", "1", "--no-compile", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    (record,) = [json.loads(p.read_text()) for p in (out / "trials").glob("*.json")]
    assert record["object"] == "shelf:box" and record["env_module"] == str(module)
