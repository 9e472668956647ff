"""Objects: sizes, mass properties and MuJoCo bodies of every built-in shape; user meshes."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from torchcontact.sim.objects import (
    OBJECT_ORIGIN_HEIGHTS,
    OBJECT_SIZES,
    add_goal_marker,
    add_object,
    load_object,
    make_object,
    object_names,
)


def _compiled(obj):
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    add_object(spec, obj)
    add_goal_marker(spec, obj)
    return spec.compile()


def _body_frame_vertices(model: mujoco.MjModel, body: int) -> np.ndarray:
    """All mesh vertices of ``body``'s geoms in the body frame, as MuJoCo compiled them."""
    points = []
    for geom in np.flatnonzero(model.geom_bodyid == body):
        mesh = model.geom_dataid[geom]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, model.geom_quat[geom])
        local = model.mesh_vert[start : start + count]
        points.append(local @ rotation.reshape(3, 3).T + model.geom_pos[geom])
    return np.concatenate(points)


@pytest.mark.parametrize("name", object_names())
def test_every_object_builds_at_its_listed_size_and_mass(name):
    obj = make_object(name)
    model = _compiled(obj)
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    vertices = _body_frame_vertices(model, body)
    np.testing.assert_allclose(np.ptp(vertices, axis=0), OBJECT_SIZES[name], atol=1e-3)
    np.testing.assert_allclose(obj.size, OBJECT_SIZES[name], atol=1e-9)
    assert model.body_mass[body] == pytest.approx(0.01)
    centre = (vertices.min(0) + vertices.max(0)) / 2
    origin_height = OBJECT_ORIGIN_HEIGHTS.get(name, OBJECT_SIZES[name][2] / 2)
    np.testing.assert_allclose(centre[:2], 0.0, atol=1e-6)
    assert -vertices[:, 2].min() == pytest.approx(origin_height, abs=1e-6)
    np.testing.assert_allclose(model.body_ipos[body], obj.centre_of_mass, atol=1e-9)
    principal = np.sort(model.body_inertia[body])
    assert principal[0] > 0 and principal[0] + principal[1] >= principal[2]
    goal = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "goal")
    goal_geoms = model.geom_bodyid == goal
    assert model.body_mocapid[goal] == 0
    assert goal_geoms.sum() == len(obj.parts)
    assert not model.geom_contype[goal_geoms].any() and not model.geom_conaffinity[goal_geoms].any()


@pytest.mark.parametrize("name", object_names())
def test_every_object_stays_upright_where_it_is_set_down(name):
    # The samplers set objects down upright and take that as the resting pose: an object
    # that rolls off it (a round bottom) fails its task before the robot touches it.
    obj = make_object(name)
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], condim=6)
    add_object(spec, obj, friction=0.5)
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[:7] = [0, 0, obj.resting_height(), 1, 0, 0, 0]
    tilts = []
    for _ in range(500):  # 1 s
        mujoco.mj_step(model, data)
        w, x, y, z = data.qpos[3:7]
        tilts.append(math.degrees(math.acos(min(1.0, 1 - 2 * (x * x + y * y)))))
    assert max(tilts) < 1.0, f"{name} tips over by {max(tilts):.1f} degrees"


def test_tipping_ratio_is_pose_height_over_the_base_edge_distance(tmp_path):
    assert make_object("cube").tipping_ratio() == pytest.approx(1.0, rel=1e-6)
    tall = make_object("cube", size=(0.02, 0.04, 0.1))  # centre 0.05 m up, nearest edge 0.01 m
    assert tall.tipping_ratio() == pytest.approx(5.0, rel=1e-6)
    cone = trimesh.creation.cone(radius=0.03, height=0.05)
    cone.apply_transform(trimesh.transformations.rotation_matrix(math.pi, [1, 0, 0]))
    cone.export(tmp_path / "point_down.stl")
    standing_on_its_tip = load_object(tmp_path / "point_down.stl", 0.06, decomposition="hull")
    assert standing_on_its_tip.tipping_ratio() == math.inf


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


def _collidable_geoms(model: mujoco.MjModel) -> np.ndarray:
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    mine = model.geom_bodyid == body
    return np.flatnonzero(mine & ((model.geom_contype != 0) | (model.geom_conaffinity != 0)))


def test_objects_without_a_reachable_hole_collide_as_their_hull_as_in_the_paper():
    """The airplane collides as one hidden hull geom and shows its parts; the torus keeps
    colliding part by part, its hole open (the default ``collision="auto"``)."""
    airplane = make_object("airplane")
    model = _compiled(airplane)
    collidable = _collidable_geoms(model)
    assert airplane.collide_hull and len(collidable) == 1
    assert model.geom_group[collidable[0]] == 3  # hidden in renderings
    body = model.geom_bodyid[collidable[0]]
    drawn = np.flatnonzero((model.geom_bodyid == body) & (model.geom_group < 3))
    assert len(drawn) == len(airplane.parts) > 1
    hull = trimesh.convex.convex_hull(airplane.vertices)
    mesh = model.geom_dataid[collidable[0]]
    assert model.mesh_vertnum[mesh] == len(hull.vertices)
    torus = make_object("torus")
    assert not torus.collide_hull
    assert len(_collidable_geoms(_compiled(torus))) == len(torus.parts) > 1


def test_collision_can_be_chosen_and_leaves_shape_and_mass_alone():
    parts = make_object("airplane", collision="parts")
    hull = make_object("airplane", collision="hull")
    assert not parts.collide_hull and hull.collide_hull
    assert len(_collidable_geoms(_compiled(parts))) == len(parts.parts)
    np.testing.assert_allclose(parts.inertia, hull.inertia)
    np.testing.assert_allclose(parts.centre_of_mass, hull.centre_of_mass)
    closed = make_object("torus", collision="hull")
    (solid,) = closed.collision_parts
    planes = ConvexHull(solid.vertices).equations  # rows (n, d): n·x + d ≤ 0 inside
    assert (planes[:, 3] < 0).all()  # the centre of the hole is inside: the hull fills it
    assert not make_object("cube", collision="hull").collide_hull  # one part: its own hull
    with pytest.raises(ValueError, match="collision must be one of"):
        make_object("cube", collision="convex")


def test_user_mesh_loads_scaled_to_largest_extent_and_to_a_box(tmp_path):
    path = tmp_path / "bar.stl"
    trimesh.creation.box(extents=[2.0, 1.0, 0.5]).export(path)
    uniform = load_object(path, 0.1, decomposition="hull")
    np.testing.assert_allclose(uniform.size, [0.1, 0.05, 0.025], atol=1e-9)
    assert uniform.name == "bar" and len(uniform.parts) == 1
    boxed = load_object(path, (0.03, 0.04, 0.05), mass=0.05, decomposition="hull")
    np.testing.assert_allclose(boxed.size, [0.03, 0.04, 0.05], atol=1e-9)
    model = _compiled(boxed)
    assert model.body_mass[1] == pytest.approx(0.05)


def test_user_mesh_with_a_hole_is_decomposed_by_coacd(tmp_path):
    pytest.importorskip("coacd")
    path = tmp_path / "ring.obj"
    trimesh.creation.annulus(r_min=0.6, r_max=1.0, height=0.5).export(path)
    ring = load_object(path, 0.08, decomposition="coacd")
    np.testing.assert_allclose(ring.size.max(), 0.08, atol=1e-3)
    assert len(ring.parts) > 1
    assert not any(part.convex_hull.contains([[0, 0, 0]])[0] for part in ring.parts)
    _compiled(ring)


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


def test_bad_decomposition_and_friction_name_the_argument(tmp_path):
    path = tmp_path / "box.stl"
    trimesh.creation.box().export(path)
    with pytest.raises(ValueError, match="decomposition"):
        load_object(path, 0.1, decomposition="vhacd")
    with pytest.raises(ValueError, match="friction"):
        add_object(mujoco.MjSpec(), make_object("cube"), friction=-1.0)
