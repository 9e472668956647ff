"""ContactDetector on real MuJoCo scenes: row signs by finite differences, and its semantics."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest
import torch
import trimesh

from torchcontact.contacts import PAD_DISTANCE
from torchcontact.sim import ContactDetector

MARGIN = 0.03
PLANE = mujoco.mjtGeom.mjGEOM_PLANE
SPHERE = mujoco.mjtGeom.mjGEOM_SPHERE
BOX = mujoco.mjtGeom.mjGEOM_BOX
MESH = mujoco.mjtGeom.mjGEOM_MESH
SLIDE = mujoco.mjtJoint.mjJNT_SLIDE
HINGE = mujoco.mjtJoint.mjJNT_HINGE


# --- scenes ---------------------------------------------------------------------------------


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    x = rng.normal(size=n)
    return x / np.linalg.norm(x)


def _spec() -> mujoco.MjSpec:
    spec = mujoco.MjSpec()
    spec.option.ccd_tolerance = 1e-12  # GJK/EPA distances precise enough for differences
    spec.option.ccd_iterations = 200
    spec.worldbody.add_geom(name="floor", type=PLANE, size=[1, 1, 0.1], friction=[0.7, 0, 0])
    return spec


def _add_mesh(spec: mujoco.MjSpec, name: str, mesh: trimesh.Trimesh) -> None:
    spec.add_mesh(
        name=name,
        uservert=mesh.vertices.flatten().tolist(),
        userface=mesh.faces.flatten().tolist(),
    )


def box_ball_scene():
    """(a) A free box and a free sphere on a plane; both are modelled bodies."""
    spec = _spec()
    box = spec.worldbody.add_body(name="box", pos=[0, 0, 0.1])
    box.add_freejoint()
    box.add_geom(type=BOX, size=[0.03, 0.02, 0.04], friction=[0.4, 0, 0])
    ball = spec.worldbody.add_body(name="ball", pos=[0.2, 0, 0.1])
    ball.add_freejoint()
    ball.add_geom(type=SPHERE, size=[0.03, 0, 0], friction=[0.2, 0, 0])
    model = spec.compile()
    half = np.array([0.03, 0.02, 0.04])

    def sample(rng):
        q = model.qpos0.copy()
        quat = _unit(rng, 4)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, quat)
        extent = np.abs(rot.reshape(3, 3)[2]) @ half  # lowest corner below the centre
        q[0:3] = [0, 0, extent + rng.uniform(-0.005, 0.015)]
        q[3:7] = quat
        q[7:10] = q[0:3] + _unit(rng, 3) * rng.uniform(0.03, 0.08)
        q[9] = max(q[9], 0.025)
        q[10:14] = _unit(rng, 4)
        return q

    return model, ["box", "ball"], sample


def mesh_scene():
    """(b) A free mesh object (a squashed icosphere) on a plane, touched by a free sphere."""
    spec = _spec()
    blob = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    blob.apply_scale([0.04, 0.03, 0.025])
    _add_mesh(spec, "blob", blob)
    obj = spec.worldbody.add_body(name="object", pos=[0, 0, 0.1])
    obj.add_freejoint()
    obj.add_geom(type=MESH, meshname="blob", friction=[0.9, 0, 0])
    tip = spec.worldbody.add_body(name="tip", pos=[0.1, 0, 0.1])
    tip.add_freejoint()
    tip.add_geom(type=SPHERE, size=[0.01, 0, 0], friction=[0.5, 0, 0])
    model = spec.compile()

    def sample(rng):
        q = model.qpos0.copy()
        q[0:3] = [0, 0, rng.uniform(0.02, 0.045)]
        q[3:7] = _unit(rng, 4)
        q[7:10] = q[0:3] + _unit(rng, 3) * rng.uniform(0.02, 0.05)
        return q

    return model, ["object"], sample


def object_first_scene():
    """(c) An object sphere (geom1 in MuJoCo's pair order) touched by a robot box and mesh.

    The box rides on slide x, y, z and a hinge; the mesh (a hull of random points) is free.
    """
    spec = _spec()
    points = np.random.default_rng(7).normal(size=(30, 3)) * [0.02, 0.015, 0.01]
    _add_mesh(spec, "finger", trimesh.Trimesh(points).convex_hull)
    obj = spec.worldbody.add_body(name="object", pos=[0, 0, 0.1])
    obj.add_freejoint()
    obj.add_geom(type=SPHERE, size=[0.03, 0, 0], friction=[0.4, 0, 0])
    pusher = spec.worldbody.add_body(name="pusher")
    for axis in np.eye(3):
        pusher.add_joint(type=SLIDE, axis=axis)
    pusher.add_joint(type=HINGE, axis=[0, 0, 1])
    pusher.add_geom(type=BOX, size=[0.02, 0.03, 0.015], friction=[0.2, 0, 0])
    finger = spec.worldbody.add_body(name="finger", pos=[0, 0.1, 0.1])
    finger.add_freejoint()
    finger.add_geom(type=MESH, meshname="finger", friction=[0.3, 0, 0])
    model = spec.compile()

    def sample(rng):
        q = model.qpos0.copy()
        q[0:3] = [0, 0, 0.03 + rng.uniform(-0.005, 0.01)]
        q[3:7] = _unit(rng, 4)
        q[7:10] = q[0:3] + _unit(rng, 3) * rng.uniform(0.04, 0.07)
        q[10] = rng.uniform(-np.pi, np.pi)
        q[11:14] = q[0:3] + _unit(rng, 3) * rng.uniform(0.035, 0.06)
        q[14:18] = _unit(rng, 4)
        return q

    return model, ["object"], sample


SCENES = {"box_ball": box_ball_scene, "mesh": mesh_scene, "object_first": object_first_scene}


# --- an independent reading of MuJoCo's collisions ------------------------------------------


class Collider:
    """MuJoCo's raw contact list at a state, every geom given ``margin`` (a private copy)."""

    def __init__(self, model: mujoco.MjModel, margin: float = MARGIN):
        self.model = copy.deepcopy(model)
        self.model.geom_margin[:] = margin
        self.data = mujoco.MjData(self.model)

    def __call__(self, qpos: np.ndarray):
        m, d = self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_forward(m, d)
        contacts = [
            {
                "geoms": (int(c.geom1), int(c.geom2)),
                "bodies": (int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])),
                "dist": float(c.dist),
                "pos": c.pos.copy(),
                "frame": c.frame.reshape(3, 3).copy(),
                "friction": float(c.friction[0]),
            }
            for c in (d.contact[i] for i in range(d.ncon))
        ]
        return contacts, d.xpos.copy(), d.xmat.reshape(-1, 3, 3).copy()


def _nearest(contacts, pos, geoms=None):
    pool = [c for c in contacts if geoms is None or c["geoms"] == geoms]
    return min(pool, key=lambda c: np.linalg.norm(c["pos"] - pos))


def _shifted(model, q, v, step):
    out = q.copy()
    mujoco.mj_integratePos(model, out, v, step)
    return out


def _states(name, count, seed=0):
    """``count`` random states of a scene, each with a modelled contact, and its parts."""
    model, bodies, sample = SCENES[name]()
    detector = ContactDetector(model, bodies, slots=16, margin=MARGIN, dtype=torch.float64)
    rng = np.random.default_rng(seed)
    states = []
    while len(states) < count:
        q = sample(rng)
        if detector(q).active.any():
            states.append(q)
    return model, bodies, detector, states, rng


def _separation(point, bodies, before, after):
    """``p₂ − p₁`` at pose ``after`` for the points of bodies 1, 2 that were at ``point``."""
    (xpos, xmat), (xpos_new, xmat_new) = before, after
    ends = [xpos_new[b] + xmat_new[b] @ (xmat[b].T @ (point - xpos[b])) for b in bodies]
    return ends[1] - ends[0]


# --- 1. row signs and values by finite differences ------------------------------------------


@pytest.mark.parametrize("name", list(SCENES))
def test_rows_match_finite_differences(name):
    """``Jⁿv`` is the rate of change of the pair's distance, ``Jᵗv`` the tangential slip.

    A positive ``Jⁿv`` opens the gap whichever geom MuJoCo lists first; the tangent rows
    match the relative velocity of the two body-fixed points at the contact, on (t₁, t₂).
    """
    model, bodies, detector, states, rng = _states(name, count=8)
    collider = Collider(model)
    body_ids = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in bodies}
    eps = 1e-6
    checked, object_first, opening, closing = 0, 0, 0, 0
    for q in states:
        contacts = detector(q)
        base, *pose = collider(q)
        v = rng.normal(size=model.nv)
        plus, *pose_p = collider(_shifted(model, q, v, eps))
        minus, *pose_m = collider(_shifted(model, q, v, -eps))
        for k in np.flatnonzero(contacts.active.numpy()):
            raw = _nearest(base, contacts.position[k].numpy())
            # The same contact (GJK/EPA may differ in the last digits with other margins).
            np.testing.assert_allclose(raw["pos"], contacts.position[k].numpy(), atol=1e-6)
            assert raw["dist"] == pytest.approx(float(contacts.phi[k]), abs=1e-6)
            rate = (
                _nearest(plus, raw["pos"], raw["geoms"])["dist"]
                - _nearest(minus, raw["pos"], raw["geoms"])["dist"]
            ) / (2 * eps)
            jn = contacts.jac_normal[k].numpy()
            scale = np.linalg.norm(jn) * np.linalg.norm(v)
            assert jn @ v == pytest.approx(rate, abs=2e-3 * scale), raw["geoms"]

            slip = _separation(raw["pos"], raw["bodies"], pose, pose_p) - _separation(
                raw["pos"], raw["bodies"], pose, pose_m
            )
            relative = raw["frame"] @ slip / (2 * eps)
            rows = np.concatenate([jn[None], contacts.jac_tangent[k].numpy()]) @ v
            np.testing.assert_allclose(rows, relative, atol=1e-6 * scale)

            checked += 1
            object_first += raw["bodies"][0] in body_ids and raw["bodies"][1] not in body_ids
            opening += rate > 0.05 * scale
            closing += rate < -0.05 * scale
    assert checked >= len(states)
    assert opening and closing  # both signs exercised
    if name == "object_first":
        assert object_first >= 3  # the object really is geom1 in MuJoCo's order


def test_object_is_geom1_against_robot_box_and_mesh():
    """Scene (c) produces both robot–object pairs with the object sphere as geom1."""
    model, _, _, states, _ = _states("object_first", count=8)
    collider = Collider(model)
    pairs = set()
    for q in states:
        for c in collider(q)[0]:
            types = tuple(int(model.geom_type[g]) for g in c["geoms"])
            if c["bodies"][0] == 1:
                pairs.add(types)
    assert (SPHERE, BOX) in pairs
    assert (SPHERE, MESH) in pairs


# --- 2. detection semantics ------------------------------------------------------------------


def _overlapping_robot_state():
    """Scene (c) with the pusher and the finger touching each other and the object."""
    model, _, _ = object_first_scene()
    q = model.qpos0.copy()
    q[0:3] = [0, 0, 0.029]
    q[3:7] = [1, 0, 0, 0]
    q[7:11] = [0.045, 0, 0.03, 0]
    q[11:14] = [0.045, 0, 0.052]
    q[14:18] = [1, 0, 0, 0]
    return model, q


def test_only_contacts_of_declared_bodies_are_kept():
    model, q = _overlapping_robot_state()
    raw = Collider(model)(q)[0]
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    expected = [c for c in raw if obj in c["bodies"]]
    assert len(raw) > len(expected) >= 2  # robot–robot contacts exist and are dropped
    contacts = ContactDetector(model, ["object"], slots=12, margin=MARGIN)(q)
    assert int(contacts.n_active()) == len(expected)
    found = contacts.position[contacts.active].numpy()
    for c in expected:
        assert np.linalg.norm(found - c["pos"], axis=1).min() < 1e-6


def test_exclude_drops_pairs():
    model, q = _overlapping_robot_state()
    raw = Collider(model)(q)[0]
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    expected = [c for c in raw if obj in c["bodies"] and 0 not in c["bodies"]]
    assert any(c["bodies"] == (0, obj) for c in raw)  # there was a floor contact to drop
    detector = ContactDetector(
        model, ["object"], slots=12, margin=MARGIN, exclude=[("world", "object")]
    )
    contacts = detector(q)
    assert int(contacts.n_active()) == len(expected)
    by_id = ContactDetector(model, ["object"], slots=12, margin=MARGIN, exclude=[(obj, 0)])(q)
    torch.testing.assert_close(by_id.phi, contacts.phi)


def test_mu_is_mujoco_combined_friction_or_the_override():
    model, q = _overlapping_robot_state()
    raw = Collider(model)(q)[0]
    contacts = ContactDetector(model, ["object"], slots=12, margin=MARGIN, dtype=torch.float64)(q)
    friction = {tuple(np.round(c["pos"], 12)): c["friction"] for c in raw}
    mus = set()
    for k in np.flatnonzero(contacts.active.numpy()):
        mu = float(contacts.mu[k])
        assert mu == pytest.approx(friction[tuple(np.round(contacts.position[k].numpy(), 12))])
        mus.add(mu)
    assert mus == {0.7, 0.4}  # floor–object takes the floor's 0.7, robot–object the object's 0.4
    override = ContactDetector(model, ["object"], slots=12, margin=MARGIN, mu=0.25)(q)
    assert torch.all(override.mu[override.active] == 0.25)
    assert torch.all(override.mu[~override.active] == 0)


def test_padding_slots_are_inactive_and_inert():
    model, q = _overlapping_robot_state()
    contacts = ContactDetector(model, ["object"], slots=12, margin=MARGIN)(q)
    pad = ~contacts.active
    assert 0 < int(pad.sum()) < 12
    assert torch.all(contacts.phi[pad] == PAD_DISTANCE)
    assert torch.all(contacts.jac_normal[pad] == 0)
    assert torch.all(contacts.jac_tangent[pad] == 0)
    assert torch.all(contacts.mu[pad] == 0)
    assert torch.all(contacts.jac_normal[~pad].abs().sum(-1) > 0)


def test_far_state_is_all_padding():
    model, q = _overlapping_robot_state()
    q[2] = 0.5  # the object high above everything
    contacts = ContactDetector(model, ["object"], slots=5, margin=MARGIN)(q)
    assert not contacts.active.any()
    assert torch.all(contacts.phi == PAD_DISTANCE)


def test_overflow_error_and_deepest():
    model, q = _overlapping_robot_state()
    full = ContactDetector(model, ["object"], slots=12, margin=MARGIN, dtype=torch.float64)(q)
    n = int(full.n_active())
    with pytest.raises(ValueError, match="slots"):
        ContactDetector(model, ["object"], slots=n - 1, margin=MARGIN)(q)
    truncating = ContactDetector(
        model, ["object"], slots=n - 1, margin=MARGIN, overflow="deepest", dtype=torch.float64
    )
    deepest = truncating(q)
    assert truncating.found == n  # the count before truncation is reported
    assert bool(deepest.active.all())
    smallest = torch.sort(full.phi[full.active]).values[: n - 1]
    torch.testing.assert_close(torch.sort(deepest.phi).values, smallest)


def _ring_on_floor():
    """A ring of 12 small boxes (one body, like a convex-decomposed cup) resting on the floor."""
    spec = _spec()
    ring = spec.worldbody.add_body(name="object", pos=[0, 0, 0.01])
    ring.add_freejoint()
    for k in range(12):
        angle = 2 * np.pi * k / 12
        ring.add_geom(
            type=BOX, size=[0.008, 0.008, 0.01], pos=[0.05 * np.cos(angle), 0.05 * np.sin(angle), 0]
        )
    model = spec.compile()
    q = np.zeros(model.nq)
    q[2], q[3] = 0.0099, 1.0  # 0.1 mm into the floor
    return model, q


def test_per_pair_keeps_a_spanning_subset_of_each_pair():
    model, q = _ring_on_floor()
    every = ContactDetector(model, ["object"], slots=64, dtype=torch.float64)
    full = every(q)
    n = int(full.n_active())
    assert n == every.found >= 12 * 4  # each box touches with its four corners
    reducing = ContactDetector(model, ["object"], slots=8, per_pair=4, dtype=torch.float64)
    reduced = reducing(q)
    assert reducing.found == 4 and int(reduced.n_active()) == 4
    kept = reduced.position[reduced.active][:, :2].numpy()
    points = full.position[full.active][:, :2].numpy()
    # every kept row is one of the found contacts, and the four span the ring
    assert all(np.isclose(points, p).all(axis=1).any() for p in kept)
    assert np.linalg.norm(kept - kept.mean(axis=0), axis=1).min() > 0.04
    # a pair with fewer contacts than per_pair keeps them all
    assert ContactDetector(model, ["object"], slots=64, per_pair=n)(q).n_active() == n


def test_batched_qpos_equals_per_element_calls():
    model, bodies, detector, states, _ = _states("box_ball", count=6, seed=3)
    batch = np.stack(states).reshape(2, 3, model.nq)
    contacts = detector(torch.as_tensor(batch))
    assert contacts.batch_shape == (2, 3)
    for i in range(2):
        for j in range(3):
            one = detector(batch[i, j])
            for field in ("phi", "jac_normal", "jac_tangent", "mu", "active", "frame", "position"):
                torch.testing.assert_close(getattr(contacts, field)[i, j], getattr(one, field))


def test_empty_batch_gives_empty_contacts():
    model, bodies, _ = box_ball_scene()
    contacts = ContactDetector(model, bodies, slots=4)(np.zeros((0, model.nq)))
    assert contacts.phi.shape == (0, 4)
    assert contacts.jac_normal.shape == (0, 4, model.nv)


def test_margin_applies_to_a_copy_only():
    model, bodies, _ = box_ball_scene()
    before = model.geom_margin.copy()
    q = model.qpos0.copy()
    q[2] = 0.04 + 0.01  # box 1 cm above the floor, ball far away
    q[7:10] = [0.5, 0, 0.2]
    near = ContactDetector(model, bodies, slots=8, margin=0.02)(q)
    np.testing.assert_array_equal(model.geom_margin, before)
    assert int(near.n_active()) == 4  # the four bottom corners, 1 cm away
    torch.testing.assert_close(near.phi[near.active], torch.full((4,), 0.01))
    assert not ContactDetector(model, bodies, slots=8)(q).active.any()


def test_from_data_equals_call():
    model, bodies, sample = box_ball_scene()
    model.geom_margin[:] = MARGIN  # the plant's own margins, so both see the same contacts
    detector = ContactDetector(model, bodies, slots=16, dtype=torch.float64)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(5)
    seen = 0
    for _ in range(4):
        q = sample(rng)
        data.qpos[:] = q
        data.qvel[:] = rng.normal(size=model.nv)
        mujoco.mj_forward(model, data)
        a, b = detector.from_data(data), detector(q)
        seen += int(a.n_active())
        for field in ("phi", "jac_normal", "jac_tangent", "mu", "active", "frame", "position"):
            torch.testing.assert_close(getattr(a, field), getattr(b, field), rtol=0, atol=1e-12)
    assert seen > 0


def test_dtype_and_device_of_outputs():
    model, q = _overlapping_robot_state()
    contacts = ContactDetector(model, ["object"], slots=12, margin=MARGIN, dtype=torch.float32)(q)
    assert contacts.phi.dtype == torch.float32
    assert contacts.jac_normal.dtype == torch.float32
    assert contacts.active.dtype == torch.bool
    assert contacts.phi.device.type == "cpu"


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"slots": -1}, "slots"),
        ({"slots": 2.5}, "slots"),
        ({"mu": -0.1}, "mu"),
        ({"mu": float("nan")}, "mu"),
        ({"margin": -0.01}, "margin"),
        ({"margin": float("inf")}, "margin"),
        ({"overflow": "drop"}, "overflow"),
        ({"per_pair": 0}, "per_pair"),
        ({"per_pair": 2.5}, "per_pair"),
        ({"bodies": []}, "bodies"),
        ({"bodies": ["nope"]}, "nope"),
        ({"bodies": [99]}, "body id"),
        ({"exclude": [("object", "ghost")]}, "ghost"),
    ],
)
def test_bad_arguments_raise_naming_them(kwargs, name):
    model, _ = _overlapping_robot_state()
    args = {"bodies": ["object"], "slots": 4, **kwargs}
    with pytest.raises(ValueError, match=name):
        ContactDetector(model, **args)


@pytest.mark.parametrize("shape", [(), (5,), (2, 17)])
def test_bad_qpos_shape_raises(shape):
    model, _ = _overlapping_robot_state()
    detector = ContactDetector(model, ["object"], slots=4)
    with pytest.raises(ValueError, match="qpos"):
        detector(np.zeros(shape))


def test_nan_qpos_is_named_qpos():
    model, q = _overlapping_robot_state()
    detector = ContactDetector(model, ["object"], slots=12)
    q[5] = np.nan
    with pytest.raises(ValueError, match="^qpos must be finite"):
        detector(q)
    with pytest.raises(ValueError, match="^qpos must be finite"):
        detector(torch.as_tensor(np.stack([model.qpos0, q])))


def test_a_single_body_name_or_id_is_one_body():
    model, q = _overlapping_robot_state()
    listed = ContactDetector(model, ["object"], slots=12, margin=MARGIN)
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    for single in ("object", obj, np.int64(obj)):
        detector = ContactDetector(model, single, slots=12, margin=MARGIN)
        assert detector.bodies == listed.bodies == frozenset({obj})
        torch.testing.assert_close(detector(q).phi, listed(q).phi)


def test_found_describes_every_state_of_a_batch():
    """An int for one state, the count of each state for a batch (the last alone would hide
    that an earlier state needs more slots)."""
    model, bodies, detector, states, _ = _states("box_ball", count=2, seed=3)
    far = model.qpos0.copy()
    far[2] = far[9] = 1.0  # both bodies high above the plane and apart
    far[7] = 1.0
    detector(states[0])
    assert isinstance(detector.found, int) and detector.found >= 1
    counts = [detector(s).n_active().item() for s in (states[0], states[1], far)]
    assert counts[2] == 0
    batch = np.stack([states[0], states[1], far])
    detector(batch)
    assert isinstance(detector.found, np.ndarray)
    assert detector.found.tolist() == counts and detector.found.max() >= 1
    detector(batch.reshape(3, 1, -1))
    assert detector.found.shape == (3, 1)
    detector(np.zeros((0, model.nq)))
    assert detector.found.shape == (0,)


def test_static_marks_contacts_with_bodies_welded_to_the_world():
    model, q = _overlapping_robot_state()
    raw = Collider(model)(q)[0]
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object")
    contacts = ContactDetector(model, ["object"], slots=12, margin=MARGIN)(q)
    expected = [0 in c["bodies"] for c in raw if obj in c["bodies"]]
    assert any(expected) and not all(expected)  # the floor's contact and the robot's
    active = contacts.active
    assert contacts.static.dtype == torch.bool
    assert sorted(contacts.static[active].tolist()) == sorted(expected)
    assert not contacts.static[~active].any()  # padding is never static
    floor = contacts.position[contacts.static][:, 2]
    assert (floor.abs() < MARGIN).all()  # the static contacts are those on the floor
