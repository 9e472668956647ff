"""The torch contact geometry against MuJoCo: kinematics, distances, contacts and rollout."""

import mujoco
import numpy as np
import pytest
import torch

from torchcontact.environments import environment
from torchcontact.geometry import Shape, rollout
from torchcontact.model import paper_model
from torchcontact.sim.detect import ContactDetector
from torchcontact.sim.fingertips import FingertipsPlant
from torchcontact.sim.geometry import body_tree, scene_geometry
from torchcontact.sim.hands import HandPlant

RNG = np.random.default_rng(7)
POINTS = RNG.normal(size=(30, 3)) * [0.03, 0.02, 0.025]

VERTICES = " ".join(map(str, POINTS.ravel()))
PAIRS_XML = f"""<mujoco><asset><mesh name="m" vertex="{VERTICES}"/></asset>
<worldbody><geom name="ground" type="plane" size="1 1 .1"/>
<body name="object"><freejoint/><geom name="hull" type="mesh" mesh="m"/></body>
<body name="s"><freejoint/><geom name="sphere" type="sphere" size="0.01"/></body>
<body name="c"><freejoint/><geom name="capsule" type="capsule" size="0.012 0.02"/></body>
<body name="b"><freejoint/><geom name="box" type="box" size="0.02 0.015 0.01"/></body>
</worldbody></mujoco>"""
OTHER = {"plane": "ground", "point": "sphere", "segment": "capsule", "polytope": "box"}


def _random_state(model, rng, spread=0.04):
    q = np.zeros(model.nq)
    for body in range(model.nq // 7):
        q[7 * body : 7 * body + 3] = rng.uniform(-spread, spread, 3) + [0, 0, 0.05]
        quat = rng.normal(size=4)
        q[7 * body + 3 : 7 * body + 7] = quat / np.linalg.norm(quat)
    return q


@pytest.fixture(scope="module")
def pairs_scene():
    model = mujoco.MjModel.from_xml_string(PAIRS_XML)
    detector = ContactDetector(model, ["object"], 8, margin=0.02, per_pair=4)
    return model, scene_geometry(detector, dtype=torch.float64)


@pytest.mark.parametrize("hand", ["allegro", "trifinger"])
def test_kinematics_and_point_jacobians_match_mujoco(hand):
    env = HandPlant(hand, "cube")
    model, data = env.model, mujoco.MjData(env.model)
    tree = body_tree(model)
    levels = [bodies for bodies, _ in tree._stages if len(bodies) > 1]
    assert len(levels) >= 3 and all(len(b) >= 3 for b in levels)  # the fingers' levels batched
    rng = np.random.default_rng(0)
    jacp = np.zeros((3, model.nv))
    for _ in range(5):
        data.qpos[:] = env.data.qpos + rng.normal(0, 0.3, model.nq) * (np.arange(model.nq) >= 7)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        (position, rotation), dofs = tree._poses(torch.tensor(data.qpos))
        np.testing.assert_allclose(position.numpy(), data.xpos, atol=1e-12)
        np.testing.assert_allclose(rotation.numpy().reshape(-1, 9), data.xmat, atol=1e-12)
        for body in range(1, model.nbody):
            point = data.xpos[body] + rng.normal(0, 0.02, 3)
            mujoco.mj_jac(model, data, jacp, None, point, body)
            ours = tree.point_jacobian(dofs, torch.tensor([body]), torch.tensor(point)[None])
            np.testing.assert_allclose(ours[0].numpy(), jacp, atol=1e-12)


def test_a_level_of_hinges_composed_at_once_equals_one_joint_at_a_time():
    """Two branches of two hinge links each (references, anchors and offsets not zero), and a
    slide beside them: the batched levels give the poses and axes of joint-by-joint."""
    from torchcontact.geometry import BodyTree, Joint

    rng = np.random.default_rng(3)
    joints = [
        Joint(1, "hinge", (0, 0, 1), (0.01, 0, 0), 0, 0, 0.3),
        Joint(2, "hinge", (0, 1, 0), (0, 0.02, 0), 1, 1, -0.2),
        Joint(3, "hinge", (1, 0, 0), (0, 0, 0.01), 2, 2, 0.1),
        Joint(4, "hinge", (0, 0.6, 0.8), (0.02, 0, 0), 3, 3),
        Joint(5, "slide", (1, 0, 0), (0, 0, 0), 4, 4, 0.05),
    ]
    offsets = torch.tensor(rng.normal(0, 0.05, (6, 3)))
    turns = torch.nn.functional.normalize(torch.tensor(rng.normal(0, 1, (6, 4))), dim=-1)
    tree = BodyTree([0, 0, 0, 1, 2, 0], offsets, turns, joints, 5, 5)
    assert [len(bodies) for bodies, _ in tree._stages] == [1, 2, 2]
    q = torch.tensor(rng.normal(0, 1, (4, 5)))
    batched = torch.utils._pytree.tree_leaves(tree._poses(q))
    tree._stages = [((b,), tuple(tree._by_body[b])) for b in tree._moving]
    one_at_a_time = torch.utils._pytree.tree_leaves(tree._poses(q))
    for ours, theirs in zip(batched, one_at_a_time, strict=True):
        torch.testing.assert_close(ours, theirs, rtol=0, atol=1e-14)


@pytest.mark.parametrize("kind", ["plane", "point", "segment", "polytope"])
def test_distances_match_mj_geom_distance(pairs_scene, kind):
    """Random poses, in penetration and apart up to the margin: φ within 0.1 mm, normal 1°."""
    model, geometry = pairs_scene
    data = mujoco.MjData(model)
    pair = [geometry.shapes[p.b].kind for p in geometry.pairs].index(kind)
    hull, other = model.geom("hull").id, model.geom(OTHER[kind]).id
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(60):
        data.qpos[:] = _random_state(model, rng)
        mujoco.mj_forward(model, data)
        fromto = np.zeros(6)
        reference = mujoco.mj_geomDistance(model, data, hull, other, 0.02, fromto)
        if reference >= 0.02:
            continue
        phi, normal = geometry.distances(torch.tensor(data.qpos))
        assert abs(phi[pair].item() - reference) < 1e-4
        if reference > 1e-3:  # apart: the normal is the witnesses' direction
            expected = (fromto[3:] - fromto[:3]) / np.linalg.norm(fromto[3:] - fromto[:3])
            assert normal[pair].numpy() @ expected > np.cos(np.radians(1))
        checked += 1
    assert checked > 20


@pytest.mark.parametrize(
    "make",
    [
        lambda: HandPlant("trifinger", "bunny"),
        lambda: HandPlant("allegro", "cube"),
        lambda: FingertipsPlant("cube"),
    ],
)
def test_contacts_match_the_detector(make):
    """At states near the environment's start: the same active count and the same φ set,
    and rows that agree at the deepest contact."""
    env = make()
    detector = env.detector
    geometry = scene_geometry(detector, dtype=torch.float64)
    rng = np.random.default_rng(2)
    for _ in range(4):
        q = env.data.qpos.copy()
        q[7:] += rng.normal(0, 0.01, q.size - 7)
        q[2] -= 0.001
        expected = detector(q)
        ours = geometry(torch.tensor(q))
        found = np.sort(expected.phi[expected.active].numpy())
        got = np.sort(ours.phi[ours.active].numpy())
        assert got.size > 0 and abs(got[0] - found[0]) < 1e-4
        deepest = int(ours.phi.argmin())
        match = int(torch.argmin(expected.phi))
        cosine = torch.nn.functional.cosine_similarity(
            ours.jac_normal[deepest], expected.jac_normal[match].double(), dim=0
        )
        assert cosine > 0.99


def test_normal_rows_are_the_gradient_of_phi():
    """Jⁿ v equals the rate of φ along q ⊕ εv (finite differences), contact by contact."""
    env = HandPlant("trifinger", "cube")
    geometry = scene_geometry(env.detector, dtype=torch.float64)
    layout = environment("trifinger").layout
    from torchcontact.integrate import integrate

    q = torch.tensor(env.data.qpos)
    q[7:] += torch.tensor([0.0, 0.4, 0.2] * 3)
    q[3:7] = torch.tensor([0.999, 0.03, 0.02, 0.0])  # tilted: one corner is the deepest
    q[3:7] /= q[3:7].norm()
    q[2] -= 0.002
    contacts = geometry(q)
    v = torch.tensor(np.random.default_rng(3).normal(size=layout.nv))
    eps = 1e-6
    ahead = geometry(integrate(q, v, eps, layout))
    behind = geometry(integrate(q, -v, eps, layout))
    rate = (ahead.phi - behind.phi) / (2 * eps)
    active = contacts.active & ahead.active & behind.active
    assert active.any()
    # slot order is by depth; compare the deepest contact, which keeps its slot
    np.testing.assert_allclose(rate[0].item(), (contacts.jac_normal[0] @ v).item(), atol=1e-5)


def test_batched_equals_looped_and_float32(pairs_scene):
    model, geometry = pairs_scene
    rng = np.random.default_rng(4)
    q = torch.tensor(np.stack([_random_state(model, rng) for _ in range(6)])).reshape(2, 3, -1)
    batched = geometry(q)
    assert batched.phi.shape == (2, 3, geometry.slots)
    looped = geometry(q[1, 2])
    torch.testing.assert_close(batched.phi[1, 2], looped.phi)
    torch.testing.assert_close(batched.jac_normal[1, 2], looped.jac_normal)
    single = scene_geometry(
        ContactDetector(model, ["object"], 8, margin=0.02, per_pair=4), dtype=torch.float32
    )
    low = single(q.float())
    assert low.phi.dtype == torch.float32
    torch.testing.assert_close(low.phi, batched.phi.float(), atol=1e-5, rtol=0)


def test_gradcheck_of_distances(pairs_scene):
    model, geometry = pairs_scene
    q = torch.tensor(_random_state(model, np.random.default_rng(5), spread=0.02))
    for smoothing in (None, 1e-3):
        geometry.smoothing = smoothing
        assert torch.autograd.gradcheck(lambda q: geometry.distances(q)[0], (q.requires_grad_(),))
    geometry.smoothing = None


def test_smoothing_error_is_bounded(pairs_scene):
    model, geometry = pairs_scene
    rng = np.random.default_rng(6)
    q = torch.tensor(np.stack([_random_state(model, rng) for _ in range(40)]))
    exact = geometry.distances(q)[0]
    geometry.smoothing = 1e-4
    smooth = geometry.distances(q)[0]
    geometry.smoothing = None
    assert (smooth - exact).abs().max() < 1e-3


def test_distance_properties():
    """Apart by d along the normal gives d; a common rigid motion changes nothing; a point
    inside a hull has a negative distance."""
    from torchcontact.geometry import BodyTree, Joint, Pair, SceneGeometry

    hull = Shape.hull(POINTS)
    joints = [
        Joint(1, "free", (0, 0, 1), (0, 0, 0), 0, 0),
        Joint(2, "free", (0, 0, 1), (0, 0, 0), 7, 6),
    ]
    unturned = torch.tensor([[1.0, 0, 0, 0]] * 3, dtype=torch.float64)
    tree = BodyTree([0, 0, 0], torch.zeros(3, 3, dtype=torch.float64), unturned, joints, 14, 12)
    box = Shape.box([0.02, 0.03, 0.01])
    boxes = SceneGeometry(tree, [box, box], [1, 2], [Pair(0, 1, 0.5)], slots=4, margin=1.0)
    for d in (-0.005, 0.001, 0.01, 0.05):
        q = torch.tensor([0, 0, 0, 1, 0, 0, 0, 0.01, 0, 0.02 + d, 1, 0, 0, 0], dtype=torch.float64)
        torch.testing.assert_close(boxes.distances(q)[0], torch.tensor([d], dtype=torch.float64))
    geometry = SceneGeometry(tree, [hull, hull], [1, 2], [Pair(0, 1, 0.5)], slots=4, margin=1.0)
    turn = torch.tensor([0.8, 0.2, -0.4, 0.4], dtype=torch.float64)
    turn = turn / turn.norm()
    from torchcontact.rotations import quaternion_multiply, quaternion_to_matrix

    q = torch.tensor([0, 0, 0, 1, 0, 0, 0, 0.02, 0.01, 0.08, 1, 0, 0, 0], dtype=torch.float64)
    moved = q.clone()
    for start in (0, 7):
        moved[start : start + 3] = quaternion_to_matrix(turn) @ q[start : start + 3] + 0.3
        moved[start + 3 : start + 7] = quaternion_multiply(turn, q[start + 3 : start + 7])
    torch.testing.assert_close(geometry.distances(moved)[0], geometry.distances(q)[0])
    sphere = SceneGeometry(tree, [hull, Shape.sphere(1e-3)], [1, 2], [Pair(0, 1, 0.5)], 1, 1.0)
    inside = torch.tensor([0, 0, 0, 1, 0, 0, 0, *POINTS.mean(0), 1, 0, 0, 0], dtype=torch.float64)
    assert sphere.distances(inside)[0].item() < 0


def test_rollout_reaches_controls_and_stiffness():
    """A TriFinger rollout with the geometry in the loop: finite, and the gradient of the
    last state reaches the controls and K."""
    env = HandPlant("trifinger", "cube")
    description = environment("trifinger")
    geometry = scene_geometry(env.detector, dtype=torch.float64)
    system = description.system(env).double()
    model = paper_model(0.5).double()
    q0 = torch.tensor(env.data.qpos)
    controls = torch.full((2, 3, 9), 0.01, dtype=torch.float64, requires_grad=True)
    states = rollout(model, system, geometry, description.layout, q0.expand(2, -1), controls, 0.1)
    assert states.shape == (2, 4, 16) and torch.isfinite(states).all()
    states[..., -1, :].sum().backward()
    assert torch.isfinite(controls.grad).all() and controls.grad.abs().sum() > 0
    stiffness = next(model.parameters(), None)
    if stiffness is not None and stiffness.grad is not None:
        assert torch.isfinite(stiffness.grad).all()


def test_a_support_ends_at_its_edge():
    """A box half over the edge of a box support: the corners above the support touch it,
    the corners beyond its edge have nothing under them (φ > 0: no row pushes them)."""
    from torchcontact.geometry import BodyTree, Joint, Pair, SceneGeometry

    joints = [Joint(1, "free", (0, 0, 1), (0, 0, 0), 0, 0)]
    unturned = torch.tensor([[1.0, 0, 0, 0]] * 3, dtype=torch.float64)
    tree = BodyTree([0, 0, 0], torch.zeros(3, 3, dtype=torch.float64), unturned, joints, 7, 6)
    palm = Shape.box([0.05, 0.05, 0.01], position=(0, 0, -0.01))
    cube = Shape.box([0.02, 0.02, 0.02])
    geometry = SceneGeometry(tree, [cube, palm], [1, 2], [Pair(0, 1, 0.5)], slots=8, margin=0.0)
    q = torch.tensor([0.05, 0.0, 0.0199, 1, 0, 0, 0], dtype=torch.float64)  # centred on the edge
    contacts = geometry(q)
    touching = contacts.position[contacts.active]
    assert len(touching) >= 2
    assert (touching[:, 0] <= 0.05 + 1e-9).all()  # every touching point lies over the palm
    assert (contacts.phi[contacts.active] < 0).all()


def test_hulls_of_one_vertex_bucket_share_their_shapes():
    """Hulls of 20 and 30 vertices are padded to one capacity (32 vertices, Euler's bounds on
    edges and triangles), so a compiled geometry serves both; the padding changes no φ."""
    from torchcontact.geometry.scene import vertex_bucket

    assert [vertex_bucket(n) for n in (4, 8, 9, 20, 32, 33)] == [8, 8, 16, 32, 32, 64]
    shapes = []
    for count in (20, 30):
        sphere = RNG.normal(size=(count, 3))
        sphere = 0.03 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True)
        xml = PAIRS_XML.replace(VERTICES, " ".join(map(str, sphere.ravel())))
        model = mujoco.MjModel.from_xml_string(xml)
        detector = ContactDetector(model, ["object"], 8, margin=0.02, per_pair=4)
        geometry = scene_geometry(detector, dtype=torch.float64)
        shapes.append({name: tuple(b.shape) for name, b in geometry.named_buffers()})
        q = _random_state(model, np.random.default_rng(count))
        data = mujoco.MjData(model)
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        hull, ground = model.geom("hull").id, model.geom("ground").id
        expected = mujoco.mj_geomDistance(model, data, hull, ground, 1.0, None)
        phi, _ = geometry.distances(torch.tensor(q))
        label = [pair.label for pair in geometry.pairs].index("hull|ground")
        assert abs(float(phi[label]) - expected) < 1e-6
    assert shapes[0] == shapes[1]
    assert shapes[0]["groups.0.core_a.vertices"][1] == 32


def test_the_broad_phase_never_leaves_out_a_pair_within_its_distance(pairs_scene):
    """Each pair's bounding-sphere gap is at most its true distance, so a group ``within``
    leaves out holds no pair that near; leaving the far groups out keeps every contact nearer
    than that distance, and leaving all out gives no contacts."""
    model, geometry = pairs_scene
    rng = np.random.default_rng(11)
    reach = 0.03
    for _ in range(6):
        q = torch.tensor(_random_state(model, rng, spread=0.08))
        phi, _ = geometry.distances(q)
        (position, rotation), _ = geometry.tree._poses(q)
        bounds = torch.cat([g.bound(position, rotation) for g in geometry.groups])
        grouped = [p for g in geometry.groups for p in geometry.pairs if _in(geometry, g, p)]
        order = [geometry.pairs.index(p) for p in grouped]
        assert (bounds <= phi[order] + 1e-9).all()
        near = geometry.within(q, reach)
        full, pruned = geometry(q), geometry(q, near)
        close = np.sort(full.phi[full.active & (full.phi < reach)].numpy())
        kept = np.sort(pruned.phi[pruned.active].numpy())
        np.testing.assert_allclose(kept[: close.size], close)
    none = geometry(q, (False,) * len(geometry.groups))
    assert not none.active.any() and none.jac_normal.shape == full.jac_normal.shape
    with pytest.raises(ValueError, match="groups must hold one flag per group"):
        geometry(q, (True,))
    with pytest.raises(ValueError, match="distance must be a finite length"):
        geometry.within(q, float("nan"))


def _in(geometry, group, pair) -> bool:
    """Whether ``pair`` is one of ``group``'s (its kinds)."""
    kinds = (geometry.shapes[pair.a].kind, geometry.shapes[pair.b].kind)
    return kinds == (group.kind_a, group.kind_b)


def test_the_lever_bounds_how_far_a_joint_step_moves_the_robots_shapes():
    """Turning every TriFinger joint by ±δ moves no bounding sphere farther than lever · δ."""
    env = HandPlant("trifinger", "cube")
    geometry = scene_geometry(env.detector, dtype=torch.float64)
    q = torch.tensor(env.data.qpos.copy())
    lever, step = geometry.lever(q), 0.02
    rng = np.random.default_rng(3)
    (position, rotation), _ = geometry.tree._poses(q)
    for _ in range(5):
        moved = q.clone()
        moved[7:] += torch.tensor(rng.choice([-step, step], q.numel() - 7))
        (after, turned), _ = geometry.tree._poses(moved)
        for group in geometry.groups:
            before = group.spheres(position, rotation)[0]
            assert ((group.spheres(after, turned)[0] - before).norm(dim=-1) <= lever * step).all()
    assert 0.3 < lever < 2.0  # [m per rad] three joints, a finger about 0.3 m long
