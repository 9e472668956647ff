"""A user's mesh rests as the generated objects do: on a stable face from its centre of mass,
unless ``pose="as-is"`` keeps its file's; trials of meshes posed before the rule are rerun."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from torchcontact.cli import main
from torchcontact.objects import ObjectOptions, describe_pose, resolve
from torchcontact.resting import BASE_MARGIN, base_margin, rest_on_stable_face
from torchcontact.shapes import load_object


@pytest.fixture
def standing(tmp_path):
    """A 10 cm capsule saved standing on its rounded end, and a 12 cm cylinder saved tilted
    30° off its end."""
    capsule = tmp_path / "capsule.stl"
    trimesh.creation.capsule(radius=0.015, height=0.07, count=(12, 12)).export(capsule)
    cylinder = tmp_path / "cylinder.stl"
    tilted = trimesh.creation.cylinder(radius=0.02, height=0.12, sections=24)
    tilted.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30), (1, 0, 0)))
    tilted.export(cylinder)
    return capsule, cylinder


def test_a_capsule_saved_on_its_end_lies_on_its_side(standing):
    path = str(standing[0])
    as_is = resolve(path, ObjectOptions(pose="as-is"), collision="hull")
    rested = resolve(path, ObjectOptions(), collision="hull")
    assert np.argmax(as_is.size) == 2  # standing, as saved
    assert rested.size[2] == pytest.approx(min(rested.size))  # lying down
    assert rested.mass == as_is.mass and max(rested.size) == pytest.approx(max(as_is.size))
    assert "rests on stable face " in describe_pose(path, collision="hull")
    assert describe_pose(path, ObjectOptions(pose="as-is")) == "posed as in its file"


def test_a_tilted_mesh_is_turned_onto_a_face_its_centre_of_mass_stands_over(standing):
    path = str(standing[1])
    rest = rest_on_stable_face(load_object(path, decomposition="hull"))
    assert rest.turn_deg > 1.0  # turned out of the file's tilt
    margin = base_margin(rest.obj)
    assert margin >= BASE_MARGIN * float(rest.obj.size.max())
    assert resolve(path, collision="hull").size == pytest.approx(rest.obj.size)


def test_a_mesh_already_on_its_stable_face_is_not_turned(tmp_path):
    path = tmp_path / "slab.stl"
    trimesh.creation.box((0.08, 0.05, 0.02)).export(path)
    rest = rest_on_stable_face(load_object(path))
    assert rest.rank == 0 and rest.turn_deg == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(rest.obj.size, (0.08, 0.05, 0.02), atol=1e-9)


def test_the_pose_is_checked_and_is_for_mesh_files_only():
    with pytest.raises(ValueError, match="^pose must be one of"):
        ObjectOptions(pose="upright")
    with pytest.raises(ValueError, match="object pose 'as-is' is for a mesh file"):
        resolve("cube", ObjectOptions(pose="as-is"))


def test_the_header_names_the_face_and_a_pose_for_a_built_in_is_refused(standing, tmp_path, capsys):
    out = str(tmp_path / "o")
    argv = ["run", "trifinger", "--object", str(standing[0]), "--trials", "1", "--max-steps", "2",
            "--max-iter", "2", "--no-compile", "--no-progress", "--out", out]  # fmt: skip
    assert main(argv) == 0
    assert "rests on stable face " in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["run", "trifinger", "--object", "cube", "--object-pose", "as-is"])
    assert "--object-pose as-is is for mesh files, got 'cube'" in capsys.readouterr().err


def test_records_of_a_mesh_posed_before_the_rule_are_rerun(standing, tmp_path):
    from torchcontact.mpc.records import record_differences
    from torchcontact.mpc.trial_config import (
        RELEASE_FIELDS,
        RESTING_RULE,
        flat_config,
        trial_configs,
        trial_inputs,
    )

    (config,) = trial_configs("trifinger", [("in-hand", str(standing[0]))], [0])
    inputs = trial_inputs(config)
    assert inputs["object_rest"] is not None
    as_is = dataclasses.replace(config, object_options=ObjectOptions(pose="as-is"))
    assert trial_inputs(as_is)["object_rest"] is None
    assert trial_inputs(dataclasses.replace(config, object="cube"))["object_rest"] is None
    # a record written before the rule: its inputs lack the key; a release change, rerun
    old = {k: v for k, v in inputs.items() if k != "object_rest"}
    record = {**flat_config(config), "inputs": old}
    differences = record_differences(record, config, inputs)
    assert differences == {"inputs.object_rest": (None, RESTING_RULE)}
    assert set(differences) <= set(RELEASE_FIELDS)  # stale: set aside and run again
    assert record_differences({**flat_config(as_is), "inputs": old}, as_is, old) == {}
