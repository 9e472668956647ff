"""Procedurally generated objects: one object per seed, within the family's documented ranges,
resting on a face that holds in MuJoCo, and the ``random:N`` / ``random:A-B`` sets."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from torchcontact import generated
from torchcontact.environments import environment
from torchcontact.generated import (
    ASPECT,
    EXTENT,
    PARTS,
    REPORT_SEEDS,
    expand,
    generate,
    is_generated,
    is_set,
    name,
    seed_of,
)
from torchcontact.resting import BASE_MARGIN
from torchcontact.shapes import DEFAULT_MASS, convex
from torchcontact.sim.hands import ROBOT_PREFIX, HandPlant

SEEDS = [0, 1, 7, 42, 500, 999, REPORT_SEEDS, 1001, 1002, 1003, 1042, 5000]
"""Tuning seeds (< 1000) and reported ones (>= 1000); among them one-part objects (500, 1042),
four-part ones (7, 1000, 1003, 5000) and near 5:1 rods and plates (7, 42)."""


@pytest.fixture(scope="module")
def objects():
    return {seed: generate(seed) for seed in SEEDS}


def test_a_seed_gives_the_same_object_every_time_whatever_the_global_rng():
    np.random.seed(0)
    first = generate(1003)
    np.random.seed(12345)  # trimesh or NumPy's global stream must not leak into the shape
    second = generate(1003)
    assert first.name == second.name == "random-1003"
    assert len(first.parts) == len(second.parts)
    for a, b in zip(first.parts, second.parts, strict=True):
        np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(first.inertia, second.inertia)
    np.testing.assert_array_equal(first.centre_of_mass, second.centre_of_mass)
    assert first.mass == second.mass == DEFAULT_MASS
    assert first.collide_hull == second.collide_hull


def test_different_seeds_give_different_objects(objects):
    sizes = np.array([objects[seed].size for seed in SEEDS])
    # no two of the sample share a bounding box (to 0.1 mm), let alone a shape
    gaps = np.abs(sizes[:, None] - sizes[None]).max(-1)
    assert gaps[~np.eye(len(SEEDS), dtype=bool)].min() > 1e-4


@pytest.mark.parametrize("seed", SEEDS)
def test_every_object_lies_in_the_documented_family(objects, seed):
    obj = objects[seed]
    assert obj.name == f"random-{seed}" and obj.mass == DEFAULT_MASS
    assert PARTS[0] <= len(obj.parts) <= PARTS[1]
    for part in obj.parts:  # each part convex: its hull adds no volume
        assert part.is_watertight
        assert convex(part.vertices).volume == pytest.approx(part.volume, rel=1e-6)
    size = obj.size
    assert EXTENT[0] - 1e-9 <= size.max() <= EXTENT[1] + 1e-9
    assert ASPECT[0] - 1e-6 <= size.max() / size.min() <= ASPECT[1] + 1e-6
    vertices = obj.vertices
    np.testing.assert_allclose((vertices.max(0) + vertices.min(0)) / 2, 0.0, atol=1e-9)
    # resting upright: the centre of mass is over the base (a finite tipping ratio)
    assert math.isfinite(obj.tipping_ratio())
    assert np.all(np.linalg.eigvalsh(obj.inertia) > 0)
    # a multi-part object collides as its hull by default, as the paper's objects do
    assert obj.collide_hull == (len(obj.parts) > 1)


def test_the_family_is_not_one_shape(objects):
    """The sample spans the ranges: single and four-part objects, cubes and 4:1 rods."""
    parts = {len(obj.parts) for obj in objects.values()}
    aspects = [obj.size.max() / obj.size.min() for obj in objects.values()]
    assert {1, 4} <= parts
    assert min(aspects) < 1.5 and max(aspects) > 4.0


def test_the_pinned_object_of_generator_version_1():
    """Seed 1000 under GENERATOR_VERSION 1: a change of what a seed draws must bump the version
    (and the scenes' version), so old records are rerun rather than compared with a new shape."""
    if generated.GENERATOR_VERSION != 1:
        pytest.skip("pinned for GENERATOR_VERSION 1; pin the new version's object")
    obj = generate(1000)
    assert len(obj.parts) == 4
    np.testing.assert_allclose(obj.size, [0.0809, 0.1427, 0.0402], atol=2e-4)


def test_extent_and_scale_resize_the_same_shape():
    drawn = generate(1002)
    largest = float(drawn.size.max())
    sized = generate(1002, extent=0.08)
    assert sized.size.max() == pytest.approx(0.08, abs=1e-12)
    np.testing.assert_allclose(sized.vertices, drawn.vertices * (0.08 / largest), atol=1e-12)
    doubled = generate(1002, scale=2)
    np.testing.assert_allclose(doubled.size, 2 * drawn.size, rtol=1e-12)
    np.testing.assert_allclose(doubled.centre_of_mass, 2 * drawn.centre_of_mass, atol=1e-12)
    heavy = generate(1002, mass=0.05)
    np.testing.assert_allclose(heavy.inertia, 5 * drawn.inertia, rtol=1e-9)
    with pytest.raises(ValueError, match="extent and scale"):
        generate(1002, extent=0.08, scale=2)


def test_collision_parts_keeps_the_parts():
    obj = generate(1000, collision="parts")
    assert len(obj.parts) == 4 and not obj.collide_hull
    assert len(obj.collision_parts) == 4
    assert len(generate(1000).collision_parts) == 1


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"extent": 0.0}, "extent"),
        ({"extent": math.nan}, "extent"),
        ({"scale": -1.0}, "scale"),
        ({"mass": 0.0}, "mass"),
        ({"collision": "mesh"}, "collision"),
    ],
)
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        generate(1000, **kwargs)


@pytest.mark.parametrize("seed", [-1, 1.5, True, "3", None])
def test_bad_seeds_are_refused_by_name(seed):
    with pytest.raises(ValueError, match="seed"):
        generate(seed)
    with pytest.raises(ValueError, match="seed"):
        name(seed)


def test_names_and_seeds():
    assert name(1042) == "random-1042" and name(np.int64(7)) == "random-7"
    assert seed_of("random-1042") == 1042 and seed_of(name(0)) == 0
    for other in ("cube", "random-", "random-x", "random-1.5", "random:3", "xrandom-3", 3, None):
        assert seed_of(other) is None
        assert not is_generated(other)
    assert is_generated("random-3")
    assert is_set("random:3") and is_set("random:5-7")
    assert not is_set("random-3") and not is_set("random:") and not is_set(3)


def test_expand_names_the_reported_set_and_ranges():
    assert REPORT_SEEDS == 1000
    assert expand("random:3") == ["random-1000", "random-1001", "random-1002"]
    assert expand("random:5-7") == ["random-5", "random-6", "random-7"]
    assert expand("random:4-4") == ["random-4"]
    assert len(expand("random:50")) == 50


@pytest.mark.parametrize(
    "spec", ["random:0", "random:7-5", "random:x", "random:-3", "random-3", "random:1-", "cube"]
)
def test_bad_sets_are_refused(spec):
    with pytest.raises(ValueError, match="random:"):
        expand(spec)


def _turn_degrees(a: np.ndarray, b: np.ndarray) -> float:
    dot = abs(float(np.dot(a, b))) / float(np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(2 * math.acos(min(1.0, dot)))


def _robot_contacts(env: HandPlant) -> int:
    """Contacts between the object and the robot's links in the current state."""
    model, data = env.model, env.data
    robot = {model.body(b).id for b in range(model.nbody)
             if model.body(b).name.startswith(ROBOT_PREFIX)}  # fmt: skip
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    count = 0
    for contact in data.contact[: data.ncon]:
        bodies = {int(model.geom_bodyid[contact.geom1]), int(model.geom_bodyid[contact.geom2])}
        count += obj in bodies and bool(bodies & robot)
    return count


@pytest.mark.parametrize("obj", expand("random:4"))
def test_the_computed_resting_face_holds_in_mujoco(obj):
    """The first four reported objects (what ``--object random:4`` runs) set down on their
    computed face in the TriFinger's arena stay put under zero commands for 50 steps (2 s).

    Their bases carry the centre of mass at 7–18 % of the largest extent from the nearest edge
    (random-1003, 4.9 %, falls just short of BASE_MARGIN: the face of the widest margin), and
    none reaches the fingertips at their start, so only the resting face is on test."""
    env = HandPlant("trifinger", obj, overflow="deepest")
    body = env.object
    assert body.name == obj
    margin = body.resting_height() / body.tipping_ratio() / body.size.max()
    assert margin > 0.8 * BASE_MARGIN
    pose = env.resting_pose(env.support_centre, [1.0, 0.0, 0.0, 0.0])
    env.reset(pose, pose)
    assert _robot_contacts(env) == 0
    for _ in range(50):
        state = env.step(np.zeros(9))
    assert np.linalg.norm(state[:3] - pose[:3]) < 5e-3
    assert _turn_degrees(state[3:7], pose[3:]) < 5.0
    env.close()


def test_the_base_margin_is_judged_after_the_stretch():
    """random-257's likeliest face, judged in the drawn box before the stretch to its sides,
    stood it as a 7.2 cm column 1.5 mm (2 %) from its base's edge, where a push tips it.
    Judged after the stretch, that face fails BASE_MARGIN and the object lies on a face that
    meets it."""
    obj = generate(257)
    margin = obj.resting_height() / obj.tipping_ratio()
    assert margin >= BASE_MARGIN * obj.size.max()
    assert obj.size.argmax() != 2  # lying: its longest side is horizontal


def test_a_generated_object_builds_through_the_environments():
    trifinger = environment("trifinger")
    plant = trifinger.make_plant("random-1001")
    assert plant.object.name == "random-1001" and plant.object.collide_hull
    np.testing.assert_allclose(plant.object.size, generate(1001).size)
    allegro = environment("allegro").make_plant("random-1004")
    assert allegro.object.name == "random-1004" and allegro.object.mass == DEFAULT_MASS


def test_select_expands_generated_sets_for_the_hands_only():
    trifinger = environment("trifinger")
    assert trifinger.select("all", "random:3") == [
        ("in-hand", "random-1000"),
        ("in-hand", "random-1001"),
        ("in-hand", "random-1002"),
    ]
    assert trifinger.select("in-hand", "random-17") == [("in-hand", "random-17")]
    assert environment("allegro").select("all", "random:2-3") == [
        ("on-palm", "random-2"),
        ("on-palm", "random-3"),
    ]
    with pytest.raises(ValueError, match="--object"):
        trifinger.select("all", "random:0")
    fingertips = environment("fingertips")
    for spec in ("random:3", "random-1000"):
        with pytest.raises(ValueError, match="--object"):
            fingertips.select("all", spec)


def test_select_takes_a_comma_separated_union_in_order():
    trifinger = environment("trifinger")
    assert trifinger.select("all", "cube,random-7,random:2-3,random-7") == [
        ("in-hand", "cube"),
        ("in-hand", "random-7"),
        ("in-hand", "random-2"),
        ("in-hand", "random-3"),
    ]
    with pytest.raises(ValueError, match="--object"):
        trifinger.select("all", "cube,no_such_object")
