"""Transition datasets: the file format round-trips, collection resumes, bad files fail clearly."""

import json
import math

import numpy as np
import pytest
import torch

from torchcontact.environments.presets import MPCSettings
from torchcontact.integrate import JointLayout, integrate
from torchcontact.learn import data
from torchcontact.learn.data import DataFormatError, collect, load, load_objects, read_manifest
from torchcontact.learn.scenes import make_scene
from torchcontact.mpc.controller import ContactImplicitMPC

SCENE = {"scene": "trifinger", "obj": "cube", "steps": 6, "actions": "random"}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    directory = tmp_path_factory.mktemp("dataset")
    collect(directory, trajectories=3, progress=False, **SCENE)
    return directory


def test_round_trip_keeps_shapes_metadata_and_transitions(dataset):
    transitions = load(dataset)
    meta = transitions.meta
    nq, nv, nu, nc = meta["nq"], meta["nv"], meta["nu"], meta["slots"]
    assert (meta["scene"], meta["object"], meta["h"], meta["facets"]) == (
        "trifinger",
        "cube",
        0.1,
        4,
    )
    assert (nq, nv, nu) == (16, 15, 9)
    assert len(transitions) == 18
    assert transitions.q.shape == transitions.q_next.shape == (18, nq)
    assert transitions.u.shape == (18, nu) and transitions.q.dtype == torch.float64
    assert transitions.contacts.jac_tangent.shape == (18, nc, 2, nv)
    assert transitions.contacts.phi.dtype == torch.float32
    assert transitions.trajectory.tolist() == [0] * 6 + [1] * 6 + [2] * 6
    same = transitions.trajectory[1:] == transitions.trajectory[:-1]
    assert torch.equal(transitions.q_next[:-1][same], transitions.q[1:][same])
    lower, upper = (torch.tensor(meta[k], dtype=torch.float64) for k in ("u_lower", "u_upper"))
    assert bool(((transitions.u >= lower) & (transitions.u <= upper)).all())
    # The stored contacts are the scene detector's at q.
    detector = make_scene("trifinger", "cube").plant.detector
    again = detector(transitions.q)
    assert torch.equal(again.active, transitions.contacts.active)
    torch.testing.assert_close(again.jac_normal, transitions.contacts.jac_normal)
    manifest = read_manifest(dataset)
    assert [e["file"] for e in manifest["trajectories"]] == [
        f"trajectory_{i:05d}.npz" for i in range(3)
    ]
    Q, b0, B = (torch.tensor(manifest["system"][k]) for k in ("Q", "b0", "B"))
    assert Q.shape == b0.shape == (nv,) and B.shape == (nv, nu)


def test_random_actions_reach_and_move_the_object(dataset):
    transitions = load(dataset)
    robot_contact = transitions.contacts.active & (
        transitions.contacts.frame[..., 0, 2].abs() < 0.95
    )
    assert bool(robot_contact.any())


def test_split_is_by_trajectory_and_windows_stay_inside_one(dataset):
    transitions = load(dataset)
    parts = transitions.split(seed=1)
    ids = [set(part.trajectory.tolist()) for part in parts]
    assert sorted(i for group in ids for i in group) == [0, 1, 2]
    windows = transitions.windows(4, stride=2)
    assert windows.shape == (6, 4)  # starts 0 and 2 of each 6-step trajectory
    assert bool((transitions.trajectory[windows] == transitions.trajectory[windows[:, :1]]).all())
    assert bool((torch.diff(transitions.step[windows], dim=1) == 1).all())


def test_previous_displacement_is_zero_at_the_start_and_differences_the_states(dataset):
    transitions = load(dataset)
    layout = JointLayout(transitions.meta["joints"])
    order = torch.randperm(len(transitions), generator=torch.Generator().manual_seed(0))
    shuffled = transitions.select(order)  # rows in any order, as a split leaves them
    moved = shuffled.previous_displacement()
    assert moved.shape == (len(transitions), layout.nv)
    first = shuffled.step == 0
    assert bool((moved[first] == 0).all()) and bool(moved[~first].abs().sum(-1).gt(0).all())
    for row in torch.nonzero(~first).flatten()[:5].tolist():
        before = (shuffled.trajectory == shuffled.trajectory[row]) & (
            shuffled.step == shuffled.step[row] - 1
        )
        previous = int(torch.nonzero(before).flatten()[0])
        after = integrate(shuffled.q[previous], moved[row], 1.0, layout)
        torch.testing.assert_close(after, shuffled.q[row])
    alone = shuffled.select(~first)  # a row whose previous step is not among the rows: at rest
    assert bool((alone.previous_displacement()[alone.step == 1] == 0).all())


def test_collection_resumes_after_an_interruption(tmp_path, monkeypatch):
    reference = tmp_path / "reference"
    collect(reference, trajectories=3, progress=False, **SCENE)
    interrupted = tmp_path / "interrupted"
    original = data.collect_trajectory
    calls = []

    def flaky(scene, actions, seed, steps, noise=None):
        calls.append(seed)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return original(scene, actions, seed, steps, noise)

    monkeypatch.setattr(data, "collect_trajectory", flaky)
    with pytest.raises(KeyboardInterrupt):
        collect(interrupted, trajectories=3, progress=False, **SCENE)
    assert [e["id"] for e in read_manifest(interrupted)["trajectories"]] == [0, 1]
    calls.clear()
    collect(interrupted, trajectories=3, progress=False, **SCENE)
    assert calls == [2]  # only the missing trajectory
    first, second = load(reference), load(interrupted)
    for key in ("q", "u", "q_next", "trajectory", "step"):
        assert torch.equal(getattr(first, key), getattr(second, key)), key
    assert torch.equal(first.contacts.jac_tangent, second.contacts.jac_tangent)
    calls.clear()
    collect(interrupted, trajectories=4, progress=False, **SCENE)  # appends one more
    assert calls == [3] and len(load(interrupted)) == 24
    assert len(load(interrupted, trajectories=3)) == 18


def test_mixed_actions_alternate_random_and_mpc(tmp_path):
    settings = MPCSettings(max_iter=3, compile=False)

    def planner(scene):
        return ContactImplicitMPC.from_env(scene.environment, scene.plant, settings=settings)

    with pytest.raises(ValueError, match="planner is required by actions='mixed'"):
        collect(tmp_path, "trifinger", trajectories=2, steps=2, actions="mixed")
    collect(
        tmp_path,
        "trifinger",
        trajectories=2,
        steps=2,
        actions="mixed",
        progress=False,
        planner=planner,
    )
    entries = read_manifest(tmp_path)["trajectories"]
    assert [e["actions"] for e in entries] == ["random", "mpc"]


def test_collecting_other_settings_into_a_dataset_is_refused(dataset):
    with pytest.raises(DataFormatError, match=r"manifest.json.*'steps': \(6, 7\)"):
        collect(dataset, "trifinger", trajectories=3, steps=7, progress=False)


def test_data_of_an_object_whose_shape_changed_are_not_resumed(dataset, tmp_path):
    """The manifest records the object's size and mass: data of a name whose shape has
    changed since (a generated family's new version, an edited mesh) are not mixed in."""
    other = _copy(dataset, tmp_path / "reshaped")
    manifest = json.loads((other / "manifest.json").read_text())
    assert len(manifest["object_size"]) == 3 and manifest["object_mass"] > 0
    manifest["object_size"] = [0.05, 0.06, 0.07]
    (other / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DataFormatError, match=r"manifest.json.*'object_size'"):
        collect(other, "trifinger", trajectories=3, steps=6, progress=False)


def _copy(source, target):
    target.mkdir()
    for path in source.iterdir():
        (target / path.name).write_bytes(path.read_bytes())
    return target


def test_truncated_file_names_the_file(dataset, tmp_path):
    broken = _copy(dataset, tmp_path / "broken")
    path = broken / "trajectory_00001.npz"
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(DataFormatError, match=r"trajectory_00001\.npz: truncated"):
        load(broken)


def test_wrong_version_and_scene_are_named(dataset, tmp_path):
    broken = _copy(dataset, tmp_path / "version")
    manifest = json.loads((broken / "manifest.json").read_text())
    (broken / "manifest.json").write_text(json.dumps({**manifest, "version": 99}))
    with pytest.raises(DataFormatError, match="expected format version 1, found 99"):
        load(broken)
    other = _copy(dataset, tmp_path / "scene")
    (other / "manifest.json").write_text(json.dumps({**manifest, "scene": "allegro"}))
    with pytest.raises(DataFormatError, match=r"trajectory_00000\.npz.*'scene': \('trifinger'"):
        load(other)


def test_wrong_shape_names_the_array_and_the_expected_shape(dataset, tmp_path):
    broken = _copy(dataset, tmp_path / "shape")
    path = broken / "trajectory_00002.npz"
    with np.load(path) as archive:
        arrays = dict(archive)
    arrays["jac_normal"] = arrays["jac_normal"][:, :-1]
    np.savez(path, **arrays)
    with pytest.raises(DataFormatError, match=r"trajectory_00002\.npz: array 'jac_normal' should"):
        load(broken)


def test_missing_manifest_or_file_is_reported(dataset, tmp_path):
    with pytest.raises(DataFormatError, match="no dataset manifest"):
        load(tmp_path)
    broken = _copy(dataset, tmp_path / "missing")
    (broken / "trajectory_00000.npz").unlink()
    with pytest.raises(DataFormatError, match=r"trajectory_00000\.npz: trajectory file missing"):
        load(broken)


def test_box_pushing_collects_random_pushes_of_a_bar_that_moves_as_commanded(tmp_path):
    collect(tmp_path / "bp", "box_pushing", trajectories=2, steps=25, progress=False)
    transitions = load(tmp_path / "bp")
    meta = transitions.meta
    assert (meta["scene"], meta["task"], meta["nq"], meta["nu"]) == ("box_pushing", "push", 71, 1)
    assert meta["joints"] == ["free"] * 10 + ["slide"] and meta["gamma"] is None
    u = transitions.u[:, 0]
    assert bool((u <= 0).all()) and bool((u >= -0.002).all()) and u.std() > 1e-4
    bar = transitions.q_next[:, -1] - transitions.q[:, -1]
    assert torch.allclose(bar, u, atol=1e-12)  # the plant's bar goes exactly where sent
    first_cube_x = transitions.q_next[transitions.trajectory == 0, 0]
    assert float(first_cube_x[-1] - first_cube_x[0]) < -0.005  # pushed along −x
    assert bool(transitions.contacts.active.any(-1).all())  # the cubes rest on the ground


def test_box_pushing_refuses_mpc_actions_by_name(tmp_path):
    with pytest.raises(ValueError, match="actions must be 'random'"):
        collect(tmp_path / "bp", "box_pushing", trajectories=1, steps=5, actions="mpc")
    with pytest.raises(ValueError, match="box_pushing has object 'cube'"):
        make_scene("box_pushing", "stick")


def test_nan_in_a_trajectory_is_reported_with_its_file(dataset, tmp_path):
    broken = _copy(dataset, tmp_path / "nan")
    path = broken / "trajectory_00001.npz"
    with np.load(path) as archive:
        arrays = dict(archive)
    arrays["phi"][2, 0] = np.nan
    np.savez(path, **arrays)
    with pytest.raises(DataFormatError, match=r"trajectory_00001\.npz: array 'phi' holds NaN"):
        load(broken)


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"noise": -1.0}, "noise must be a non-negative finite number"),
        ({"noise": math.inf}, "noise must be a non-negative finite number"),
        ({"workers": 0}, "workers must be a positive integer"),
        ({"backend": "slurm"}, "backend must be one of"),
        ({"address": "auto"}, "address is for backend='ray'"),
    ],
)
def test_bad_arguments_are_refused_before_anything_is_written(tmp_path, bad, message):
    directory = tmp_path / "data"
    with pytest.raises(ValueError, match=message):
        collect(directory, trajectories=1, progress=False, **{**SCENE, **bad})
    assert not directory.exists()


def test_objects_join_with_their_own_systems_and_split_whole(dataset, tmp_path):
    """Datasets of several objects join into one set: rows indexed by object, trajectory ids
    unique, each object's system kept; an object split puts every object in one set only."""
    other = tmp_path / "random-5"
    collect(
        other, "trifinger", "random-5", trajectories=3, steps=6, actions="random", progress=False
    )
    third = tmp_path / "stick"
    collect(third, "trifinger", "stick", trajectories=3, steps=6, actions="random", progress=False)
    joined = load_objects([dataset, other, third])
    assert joined.meta["objects"] == ["cube", "random-5", "stick"]
    assert len(joined.meta["systems"]) == 3 and len(joined) == 54
    slots = max(load(d).meta["slots"] for d in (dataset, other, third))
    assert joined.meta["slots"] == slots == joined.contacts.slots
    assert len(joined.trajectory_ids()) == 9
    for seed in range(4):
        parts = joined.split_objects(seed=seed)
        sets = [set(part.object_ids()) for part in parts]
        assert sorted(map(len, sets)) == [1, 1, 1] and set.union(*sets) == {0, 1, 2}
        assert all(len(window) for part in parts for window in part.windows(3))
    with pytest.raises(DataFormatError, match="each object must come once"):
        load_objects([dataset, dataset])
    box = tmp_path / "box"
    collect(box, "box_pushing", trajectories=1, steps=4, actions="random", progress=False)
    with pytest.raises(DataFormatError, match="differs from"):
        load_objects([dataset, box])
    with pytest.raises(ValueError, match="splitting needs at least 3 objects"):
        load_objects([dataset, other]).split_objects()
