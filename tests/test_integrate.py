"""integrate (q ⊕ h·v) against MuJoCo's mj_integratePos, batched and differentiable."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from torchcontact import JointLayout, integrate
from torchcontact.integrate import difference
from torchcontact.sim import joint_layout

XML = """
<mujoco>
  <worldbody>
    <body name="free"><freejoint/><geom size="0.1"/>
      <body name="ball" pos="0.2 0 0"><joint type="ball"/><geom size="0.05"/>
        <body pos="0.1 0 0"><joint type="hinge" axis="0 1 0"/><geom size="0.05"/></body>
      </body>
    </body>
    <body pos="1 0 0"><joint type="slide" axis="1 0 0"/><joint type="hinge" axis="0 0 1"/>
      <geom size="0.05"/>
      <body><joint type="ball"/><geom size="0.05"/></body>
    </body>
    <body pos="0 1 0"><freejoint/><geom size="0.05"/></body>
  </worldbody>
</mujoco>
"""
MODEL = mujoco.MjModel.from_xml_string(XML)
QUATERNIONS = [(3, 7), (7, 11), (14, 18), (21, 25)]  # qpos slices of the four quaternions


def _random_state(rng: np.random.Generator, model: mujoco.MjModel = MODEL):
    q = rng.normal(size=model.nq)
    for start, stop in QUATERNIONS:
        q[start:stop] /= np.linalg.norm(q[start:stop])
    return q, rng.normal(size=model.nv) * 3


def _mujoco(q: np.ndarray, v: np.ndarray, h: float) -> np.ndarray:
    out = q.copy()
    mujoco.mj_integratePos(MODEL, out, v, h)
    return out


def _assert_same_configuration(actual: np.ndarray, expected: np.ndarray, atol=1e-10):
    """Equal up to the sign of each quaternion (q and −q are the same rotation)."""
    actual, expected = actual.copy(), expected.copy()
    for start, stop in QUATERNIONS:
        if actual[start:stop] @ expected[start:stop] < 0:
            actual[start:stop] *= -1
    np.testing.assert_allclose(actual, expected, rtol=0, atol=atol)


def test_joint_layout_of_the_model():
    layout = joint_layout(MODEL)
    assert layout.joints == ("free", "ball", "hinge", "slide", "hinge", "ball", "free")
    assert (layout.nq, layout.nv) == (MODEL.nq, MODEL.nv) == (25, 21)


@pytest.mark.parametrize("h", [1e-3, 0.05, 0.7])
def test_matches_mj_integrate_pos(h):
    rng = np.random.default_rng(0)
    layout = joint_layout(MODEL)
    for _ in range(20):
        q, v = _random_state(rng)
        ours = integrate(torch.tensor(q), torch.tensor(v), h, layout).numpy()
        _assert_same_configuration(ours, _mujoco(q, v, h))


def test_large_rotation_and_zero_velocity():
    rng = np.random.default_rng(1)
    layout = joint_layout(MODEL)
    q, v = _random_state(rng)
    v *= 10  # rotations of several turns in one step
    _assert_same_configuration(
        integrate(torch.tensor(q), torch.tensor(v), 1.0, layout).numpy(), _mujoco(q, v, 1.0)
    )
    still = integrate(torch.tensor(q), torch.zeros(MODEL.nv, dtype=torch.float64), 0.1, layout)
    np.testing.assert_allclose(still.numpy(), q, rtol=0, atol=1e-15)


def test_batched_shapes_and_tensor_h():
    rng = np.random.default_rng(2)
    layout = joint_layout(MODEL)
    B, T = 3, 4
    states = [_random_state(rng) for _ in range(B * T)]
    q = torch.tensor(np.stack([s[0] for s in states])).reshape(B, T, -1)
    v = torch.tensor(np.stack([s[1] for s in states])).reshape(B, T, -1)
    h = torch.tensor(rng.uniform(0.01, 0.2, size=(B, T)))
    out = integrate(q, v, h, layout)
    assert out.shape == (B, T, MODEL.nq)
    for i in range(B):
        for j in range(T):
            expected = _mujoco(q[i, j].numpy(), v[i, j].numpy(), float(h[i, j]))
            _assert_same_configuration(out[i, j].numpy(), expected)
    # (B,) batch with a (B,) step.
    flat = integrate(q[:, 0], v[:, 0], h[:, 0], layout)
    assert flat.shape == (B, MODEL.nq)
    torch.testing.assert_close(flat, out[:, 0], rtol=0, atol=1e-15)
    # One q shared by a batch of velocities.
    shared = integrate(q[0, 0], v[:, 0], 0.1, layout)
    assert shared.shape == (B, MODEL.nq)
    for i in range(B):
        _assert_same_configuration(
            shared[i].numpy(), _mujoco(q[0, 0].numpy(), v[i, 0].numpy(), 0.1)
        )


def test_gradient_is_finite_at_zero_rotation_and_matches_finite_differences():
    rng = np.random.default_rng(3)
    layout = joint_layout(MODEL)
    q, v = _random_state(rng)
    v[:] = 0  # zero angular velocity everywhere: the exp map's 0/0 point
    q_t = torch.tensor(q, requires_grad=True)
    v_t = torch.tensor(v, requires_grad=True)
    out = integrate(q_t, v_t, 0.1, layout)
    (gq, gv) = torch.autograd.grad(out.sum(), (q_t, v_t))
    assert torch.isfinite(gq).all() and torch.isfinite(gv).all()
    assert torch.autograd.gradcheck(lambda a, b: integrate(a, b, 0.1, layout), (q_t, v_t))
    # Away from zero, and with respect to a tensor step h.
    h = torch.tensor(0.3, dtype=torch.float64, requires_grad=True)
    v_t = torch.tensor(_random_state(rng)[1], requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b, c: integrate(a, b, c, layout), (q_t, v_t, h))


def test_small_rotation_is_first_order_exact():
    """At tiny ω, ``q ⊗ exp(hω)`` has derivative ``½ q ⊗ (0, ω)`` with respect to h."""
    layout = JointLayout(["ball"])
    q = torch.tensor([0.5, 0.5, -0.5, 0.5], dtype=torch.float64)
    omega = torch.tensor([0.3, -1.2, 0.7], dtype=torch.float64)
    h = 1e-7
    rate = (integrate(q, omega, h, layout) - integrate(q, -omega, h, layout)) / (2 * h)
    w, x, y, z = q
    a, b, c = omega
    expected = 0.5 * torch.stack(
        [
            -x * a - y * b - z * c,
            w * a + y * c - z * b,
            w * b - x * c + z * a,
            w * c + x * b - y * a,
        ]
    )
    torch.testing.assert_close(rate, expected, rtol=1e-7, atol=1e-9)


def test_layout_without_quaternions_or_without_linear_joints():
    slides = JointLayout(["slide", "hinge", "slide"])
    q, v = torch.tensor([1.0, 2.0, 3.0]), torch.tensor([0.5, -1.0, 2.0])
    torch.testing.assert_close(integrate(q, v, 0.1, slides), q + 0.1 * v)
    balls = JointLayout(["ball"])
    out = integrate(torch.tensor([1.0, 0, 0, 0]), torch.tensor([0.0, 0.0, np.pi]), 1.0, balls)
    torch.testing.assert_close(out, torch.tensor([0.0, 0, 0, 1]), atol=1e-6, rtol=0)


def test_float32_and_unit_quaternions():
    rng = np.random.default_rng(4)
    layout = joint_layout(MODEL)
    q, v = _random_state(rng)
    out = integrate(
        torch.tensor(q, dtype=torch.float32), torch.tensor(v, dtype=torch.float32), 0.05, layout
    )
    assert out.dtype == torch.float32
    _assert_same_configuration(out.double().numpy(), _mujoco(q, v, 0.05), atol=1e-5)
    for start, stop in QUATERNIONS:
        assert float(out[start:stop].norm()) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    "q_size, v_size, name", [(24, 21, "q"), (25, 20, "v"), (25, 22, "v"), (7, 21, "q")]
)
def test_bad_shapes_raise_naming_the_argument(q_size, v_size, name):
    layout = joint_layout(MODEL)
    with pytest.raises(ValueError, match=rf"^{name} must have shape"):
        integrate(torch.zeros(q_size), torch.zeros(v_size), 0.1, layout)


def test_scalar_and_integer_inputs_are_rejected():
    layout = JointLayout(["slide"])
    with pytest.raises(ValueError, match="q"):
        integrate(torch.tensor(1.0), torch.zeros(1), 0.1, layout)
    with pytest.raises(TypeError, match="v"):
        integrate(torch.zeros(1), torch.zeros(1, dtype=torch.long), 0.1, layout)


def test_unknown_joint_raises():
    with pytest.raises(ValueError, match="joints"):
        JointLayout(["free", "planar"])


def test_named_blocks_slice_q_and_v():
    layout = JointLayout(["free", "ball", "hinge", "slide"], blocks={"object": 1, "arm": 3})
    assert (layout.q_slice("object"), layout.v_slice("object")) == (slice(0, 7), slice(0, 6))
    assert (layout.q_slice("arm"), layout.v_slice("arm")) == (slice(7, 13), slice(6, 11))
    q = torch.arange(2 * layout.nq, dtype=torch.float64).reshape(2, layout.nq)
    v = torch.arange(2 * layout.nv, dtype=torch.float64).reshape(2, layout.nv)
    assert torch.equal(layout.block(q, "arm"), q[:, 7:])
    assert torch.equal(layout.block_velocity(v, "object"), v[:, :6])
    assert torch.equal(layout.object_pose(q), q[:, :7])
    assert repr(layout) == "JointLayout(['free', 'ball', 'hinge', 'slide'], " + (
        "blocks={'object': 1, 'arm': 3})"
    )


def test_default_block_is_all_joints():
    layout = joint_layout(MODEL)
    assert layout.blocks == {"all": 7}
    assert (layout.q_slice("all"), layout.v_slice("all")) == (slice(0, 25), slice(0, 21))
    assert repr(JointLayout(["slide"])) == "JointLayout(['slide'])"


def test_manipulation_layout_is_the_object_then_the_robot():
    layout = JointLayout.manipulation(["hinge"] * 9)
    assert layout.joints == ("free",) + ("hinge",) * 9
    assert layout.blocks == {"object": 1, "robot": 9}
    q = torch.randn(3, 5, 16)
    assert torch.equal(layout.object_pose(q), q[..., :7])
    assert torch.equal(layout.robot(q), q[..., 7:])
    assert layout.v_slice("robot") == slice(6, 15)


def test_blocks_do_not_change_the_integration():
    joints = ["free", "hinge", "hinge"]
    q, v = torch.randn(4, 9, dtype=torch.float64), torch.randn(4, 8, dtype=torch.float64)
    plain = integrate(q, v, 0.05, JointLayout(joints))
    assert torch.equal(integrate(q, v, 0.05, JointLayout.manipulation(joints[1:])), plain)


@pytest.mark.parametrize(
    "blocks, message",
    [
        ({"object": 1, "robot": 1}, "blocks must count all 3 joints"),
        ({"object": 1, "robot": -1, "rest": 3}, r"blocks\['robot'\] must be"),
        ({"object": 1.0, "robot": 2}, r"blocks\['object'\] must be"),
        ({1: 3}, "blocks must be named by strings"),
        ([("object", 3)], "blocks must map"),
    ],
)
def test_bad_blocks_raise_naming_the_argument(blocks, message):
    with pytest.raises(ValueError, match=message):
        JointLayout(["free", "hinge", "hinge"], blocks=blocks)


def test_missing_or_wrong_blocks_raise():
    layout = JointLayout(["hinge", "free"], blocks={"robot": 1, "object": 1})
    with pytest.raises(ValueError, match="name must be a block among"):
        layout.q_slice("hand")
    with pytest.raises(ValueError, match="q must have shape"):
        layout.robot(torch.zeros(7))
    with pytest.raises(ValueError, match="v must have shape"):
        layout.block_velocity(torch.zeros(6), "robot")
    assert torch.equal(layout.object_pose(torch.arange(8.0)), torch.arange(1.0, 8.0))
    for joints, blocks in ((["ball", "hinge"], {"object": 1, "robot": 1}), (["free"], None)):
        with pytest.raises(ValueError, match="block 'object' of one free joint"):
            JointLayout(joints, blocks).object_pose(torch.zeros(JointLayout(joints).nq))


def _bad_integrate_inputs(name, value):
    layout = JointLayout(["free", "slide", "ball"])
    q = torch.tensor([0, 0, 0.1, 1, 0, 0, 0, 0.2, 0.5, 0.5, 0.5, 0.5], dtype=torch.float64)
    args = {"q": q.expand(2, -1).clone(), "v": torch.ones(2, 10, dtype=torch.float64), "h": 0.1}
    args[name] = value(args[name]) if callable(value) else value
    return args, layout


def _set(index, value):
    def fn(x):
        x = x.clone()
        x[1, index] = value
        return x

    return fn


@pytest.mark.parametrize(
    "name, value, match",
    [
        ("h", -0.1, "^h must be positive"),
        ("h", 0.0, "^h must be positive"),
        ("h", float("nan"), "^h must be finite"),
        ("h", torch.tensor([0.1, -0.1], dtype=torch.float64), "^h must be positive"),
        ("h", torch.full((2, 1), 0.1, dtype=torch.float64), r"^h must broadcast to \(2,\)"),
        ("h", torch.full((3, 2), 0.1, dtype=torch.float64), r"^h must broadcast to \(2,\)"),
        ("v", _set(4, float("nan")), "^v must be finite"),
        ("q", _set(0, float("inf")), "^q must be finite"),
        ("q", _set(slice(3, 7), 0.0), "^q must hold non-zero quaternions"),
        ("q", _set(slice(8, 12), 0.0), "^q must hold non-zero quaternions"),
        ("v", lambda v: v[:1].expand(3, -1), "^batch shapes of q and v must broadcast"),
    ],
)
def test_bad_inputs_name_the_argument(name, value, match):
    args, layout = _bad_integrate_inputs(name, value)
    with pytest.raises(ValueError, match=match):
        integrate(layout=layout, **args)


def test_value_checks_can_be_switched_off():
    from torchcontact import validate_args

    args, layout = _bad_integrate_inputs("v", _set(4, float("nan")))
    with validate_args(False):
        assert integrate(layout=layout, **args)[1].isnan().any()


@pytest.mark.parametrize("h", [0.05, 1.0])
def test_difference_matches_mj_differentiate_pos_and_inverts_integrate(h):
    rng = np.random.default_rng(1)
    layout = joint_layout(MODEL)
    for _ in range(10):
        q0, _ = _random_state(rng)
        q1, _ = _random_state(rng)
        expected = np.zeros(MODEL.nv)
        mujoco.mj_differentiatePos(MODEL, expected, h, q0, q1)
        v = difference(torch.tensor(q0), torch.tensor(q1), h, layout)
        np.testing.assert_allclose(v.numpy(), expected, rtol=0, atol=1e-9)
        back = integrate(torch.tensor(q0), v, h, layout).numpy()
        _assert_same_configuration(back, q1, atol=1e-9)


def test_difference_is_batched_differentiable_and_checks_its_inputs():
    layout = JointLayout(["free", "hinge"])
    q = torch.tensor([0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0, 0.4], dtype=torch.float64)
    generator = torch.Generator().manual_seed(0)
    v = torch.randn(5, 3, layout.nv, dtype=torch.float64, generator=generator)
    q1 = integrate(q, v, 0.1, layout)
    torch.testing.assert_close(difference(q, q1, 0.1, layout), v)
    same = q.clone().requires_grad_()
    (grad,) = torch.autograd.grad(difference(same, q, 0.1, layout).sum(), same)
    assert torch.isfinite(grad).all()  # at zero rotation, where log's 0/0 is guarded
    with pytest.raises(ValueError, match="q1"):
        difference(q, q[:-1], 0.1, layout)
    with pytest.raises(ValueError, match="h"):
        difference(q, q, 0.0, layout)
