"""Objects as MuJoCo bodies: every built-in shape compiled at its size and mass, standing
upright, colliding as its hull or part by part; user meshes; resting heights as MuJoCo turns."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from torchcontact.shapes import (
    OBJECT_ORIGIN_HEIGHTS,
    OBJECT_SIZES,
    load_object,
    make_object,
    object_names,
)
from torchcontact.sim.objects import add_goal_marker, add_object


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


def test_resting_height_turns_the_object_as_mujoco_does():
    """Bit for bit: the NumPy rotation of ``torchcontact.shapes`` against ``mju_quat2Mat``."""
    rng = np.random.default_rng(0)
    quats = np.concatenate([rng.normal(size=(200, 4)), np.eye(4), -np.eye(4)])
    for name in ("cube", "bunny", "teapot"):
        obj = make_object(name)
        for quat in quats:
            rotation = np.zeros(9)
            mujoco.mju_quat2Mat(rotation, quat / np.linalg.norm(quat))
            lowest = (obj.vertices @ rotation.reshape(3, 3)[2]).min()
            assert obj.resting_height(quat) == -lowest


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


def test_bad_friction_names_the_argument():
    with pytest.raises(ValueError, match="friction"):
        add_object(mujoco.MjSpec(), make_object("cube"), friction=-1.0)
