"""Shapes without MuJoCo: sizes, mass properties, resting heights and holes of the built-in
objects; user meshes; input checks; and that ``torchcontact.shapes`` never loads MuJoCo."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from torchcontact.shapes import OBJECT_SIZES, load_object, make_object


def test_importing_shapes_leaves_mujoco_unloaded():
    code = "import sys, torchcontact.shapes; print('mujoco' in sys.modules)"
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True
    )
    assert result.stdout.strip() == "False"


def test_tipping_ratio_is_pose_height_over_the_base_edge_distance(tmp_path):
    assert make_object("cube").tipping_ratio() == pytest.approx(1.0, rel=1e-6)
    tall = make_object("cube", size=(0.02, 0.04, 0.1))  # centre 0.05 m up, nearest edge 0.01 m
    assert tall.tipping_ratio() == pytest.approx(5.0, rel=1e-6)
    cone = trimesh.creation.cone(radius=0.03, height=0.05)
    cone.apply_transform(trimesh.transformations.rotation_matrix(math.pi, [1, 0, 0]))
    cone.export(tmp_path / "point_down.stl")
    standing_on_its_tip = load_object(tmp_path / "point_down.stl", 0.06, decomposition="hull")
    assert standing_on_its_tip.tipping_ratio() == math.inf


def test_critical_tilt_is_where_the_centre_of_mass_passes_the_base_edge(tmp_path):
    step = math.radians(0.25) + 1e-9  # the grid's, and rounding at an exact tie
    cube = make_object("cube").critical_tilt()
    assert math.radians(45) <= cube <= math.radians(45) + step
    tall = make_object("cube", size=(0.02, 0.04, 0.1))  # nearest edge 1 cm, centre 5 cm up
    assert math.atan(0.2) <= tall.critical_tilt() <= math.atan(0.2) + step
    flat = make_object("cube", size=(0.1, 0.1, 0.02))  # 5 cm to an edge, centre 1 cm up
    assert math.atan(5.0) <= flat.critical_tilt() <= math.atan(5.0) + step
    # a ball on its round bottom rolls at once
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    ball.export(tmp_path / "ball.stl")
    assert load_object(tmp_path / "ball.stl", 0.06).critical_tilt() < math.radians(15)
    for bad in ({"directions": 0}, {"directions": 2.0}, {"step": 0.0}, {"step": math.nan}):
        with pytest.raises(ValueError, match="directions must be|step must be"):
            make_object("cube").critical_tilt(**bad)


def test_cube_mass_properties_are_exact():
    obj = make_object("cube", mass=0.02)
    np.testing.assert_allclose(obj.inertia, 0.02 * 0.06**2 / 6 * np.eye(3), rtol=1e-6, atol=1e-14)
    assert obj.mass == 0.02


def test_grid_mass_properties_match_exact_integrals_on_a_convex_mesh(tmp_path):
    """The grid integration against trimesh's exact volume integrals, on a tilted ellipsoid."""
    blob = trimesh.creation.icosphere(subdivisions=3)
    blob.apply_scale([1.0, 0.6, 0.4])
    blob.apply_transform(trimesh.transformations.rotation_matrix(0.5, [1, 1, 0]))
    path = tmp_path / "blob.stl"
    blob.export(path)
    obj = load_object(path, 0.08, mass=0.01, decomposition="hull")
    exact = obj.parts[0].copy()
    exact.density = 0.01 / exact.volume
    np.testing.assert_allclose(obj.centre_of_mass, exact.center_mass, atol=2e-4)
    np.testing.assert_allclose(obj.inertia, exact.moment_inertia, atol=0.01 * obj.inertia.max())


def test_the_stick_is_an_elliptic_rod_with_rounded_ends():
    """As the paper's stick mesh: an elliptic section (not a box's corners) that narrows
    toward both ends over their last 15 mm."""
    stick = make_object("stick").parts[0]
    length, width, height = OBJECT_SIZES["stick"]
    elliptic_cylinder = math.pi * (width / 2) * (height / 2) * length
    assert 0.8 * elliptic_cylinder < stick.volume < elliptic_cylinder

    def section_width(x):
        section = stick.section(plane_origin=[x, 0, 0], plane_normal=[1, 0, 0])
        return np.ptp(section.vertices[:, 1])

    assert section_width(0.0) == pytest.approx(width, rel=0.01)
    assert section_width(length / 2 - 0.015) == pytest.approx(width, rel=0.01)
    assert 0.2 * width < section_width(length / 2 - 0.001) < 0.6 * width
    # the box's corner lies outside, at least 3 mm beyond one of the rod's facet planes
    corner = np.array([0.0, width / 2, height / 2, 1.0])
    assert (ConvexHull(stick.vertices).equations @ corner).max() > 3e-3


def test_the_origin_of_a_bottom_heavy_object_is_its_box_centre():
    """The duck's mass sits low in its box; its pose is still that of the box centre."""
    duck = make_object("rubber_duck")
    assert duck.centre_of_mass[2] < -0.005
    assert duck.resting_height() == pytest.approx(OBJECT_SIZES["rubber_duck"][2] / 2)


def test_origins_lower_than_the_box_centre_scale_with_the_object():
    assert make_object("bunny").resting_height() == pytest.approx(0.03)
    assert make_object("cup").resting_height() == pytest.approx(0.02)
    smaller = make_object("bunny", size=np.multiply(OBJECT_SIZES["bunny"], 0.9))
    assert smaller.resting_height() == pytest.approx(0.027)


def test_resting_height_of_a_turned_cube():
    cube = make_object("cube")
    assert cube.resting_height() == pytest.approx(0.03)
    yaw = [math.cos(0.3), 0, 0, math.sin(0.3)]
    assert cube.resting_height(yaw) == pytest.approx(0.03)
    on_edge = [math.cos(math.pi / 8), math.sin(math.pi / 8), 0, 0]
    assert cube.resting_height(on_edge) == pytest.approx(0.03 * math.sqrt(2))


def test_hollow_objects_keep_their_holes_open():
    """A sphere fits through the torus' hole and inside the cup: parts, not one hull."""
    torus = make_object("torus")
    cup = make_object("cup")
    for obj, point in ((torus, [0, 0, 0]), (cup, [0, 0, 0.01])):
        inside = [part.convex_hull.contains([point])[0] for part in obj.parts]
        assert not any(inside)
        assert len(obj.parts) > 1


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: make_object("spoon"), "name"),
        (lambda: make_object("cube", mass=0), "mass"),
        (lambda: make_object("cube", size=(0.1, -0.1, 0.1)), "size"),
        (lambda: load_object("/no/such/file.stl", 0.1), "path"),
        (lambda: make_object("cube").resting_height([0, 0, 0, 0]), "quat"),
    ],
)
def test_bad_input_names_the_argument(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_bad_decomposition_names_the_argument(tmp_path):
    path = tmp_path / "box.stl"
    trimesh.creation.box().export(path)
    with pytest.raises(ValueError, match="decomposition"):
        load_object(path, 0.1, decomposition="vhacd")


def test_a_flat_mesh_is_refused_by_name_not_by_qhull(tmp_path):
    path = tmp_path / "flat.stl"
    trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]]).export(path)
    for decomposition in ("hull", "auto"):
        # at its own size, as scaled to a size: either way refused as flat, by name
        for size in (None, 0.1):
            with pytest.raises(ValueError, match=r"solid mesh, but .*flat\.stl' is flat"):
                load_object(path, size, decomposition=decomposition)
