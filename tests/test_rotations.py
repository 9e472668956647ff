"""Quaternion helpers: bit-identical to pytorch-kinematics, differentiable, batched."""

import math

import pytest
import torch
from pytorch_kinematics import transforms

from torchcontact.rotations import (
    quaternion_angle,
    quaternion_error,
    quaternion_exp,
    quaternion_log,
    quaternion_multiply,
    quaternion_to_matrix,
    up_axis,
)

DTYPES = [torch.float32, torch.float64]
IDENTITY = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)


def _quats(*batch, dtype=torch.float64, unit=True, seed=0):
    generator = torch.Generator().manual_seed(seed)
    q = torch.randn(*batch, 4, dtype=dtype, generator=generator)
    return q / torch.linalg.vector_norm(q, dim=-1, keepdim=True) if unit else q


def _axis_angle(axis, angle):
    axis = torch.tensor(axis, dtype=torch.float64)
    axis = axis / torch.linalg.vector_norm(axis)
    return torch.cat(
        [torch.tensor([math.cos(angle / 2)], dtype=torch.float64), math.sin(angle / 2) * axis]
    )


@pytest.mark.parametrize("dtype", DTYPES)
def test_multiply_is_bit_identical_to_pytorch_kinematics_raw_multiply(dtype):
    a, b = _quats(50, 3, dtype=dtype, unit=False), _quats(3, dtype=dtype, unit=False, seed=1)
    assert torch.equal(quaternion_multiply(a, b), transforms.quaternion_raw_multiply(a, b))


@pytest.mark.parametrize("dtype", DTYPES)
def test_to_matrix_is_bit_identical_to_pytorch_kinematics(dtype):
    for unit in (True, False):
        q = _quats(7, 5, dtype=dtype, unit=unit)
        assert torch.equal(quaternion_to_matrix(q), transforms.quaternion_to_matrix(q))


@pytest.mark.parametrize("dtype", DTYPES)
def test_exp_agrees_with_pytorch_kinematics_axis_angle(dtype):
    rotation = torch.randn(20, 3, dtype=dtype)
    expected = transforms.axis_angle_to_quaternion(rotation)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(quaternion_exp(rotation), expected, atol=tol, rtol=0)
    assert torch.equal(quaternion_exp(torch.zeros(3, dtype=dtype)), IDENTITY.to(dtype))


def test_matrix_is_a_rotation_and_the_product_composes():
    a, b = _quats(10), _quats(10, seed=1)
    R = quaternion_to_matrix(a)
    torch.testing.assert_close(R @ R.mT, torch.eye(3, dtype=torch.float64).expand(10, 3, 3))
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(10, dtype=torch.float64))
    torch.testing.assert_close(
        quaternion_to_matrix(quaternion_multiply(a, b)), R @ quaternion_to_matrix(b)
    )


def test_up_axis_is_the_third_column_of_the_matrix():
    q = _quats(4, 6)
    torch.testing.assert_close(up_axis(q), quaternion_to_matrix(q)[..., :, 2])


def test_error_and_angle_of_known_rotations():
    for angle in (0.0, 0.3, math.pi / 2, 2.0, math.pi):
        q = _axis_angle([1.0, 2.0, -0.5], angle)
        e = quaternion_error(q, IDENTITY)
        assert float(e) == pytest.approx(math.sin(angle / 2) ** 2, abs=1e-15)
        assert float(quaternion_error(-q, IDENTITY)) == float(e)  # q and −q agree
        assert float(quaternion_angle(q, IDENTITY)) == pytest.approx(angle, abs=1e-7)
    assert float(quaternion_angle(IDENTITY, IDENTITY)) == 0.0


def test_error_is_the_mpc_cost_expression_exactly():
    q, target = _quats(3, 8), _quats(8, seed=1)
    assert torch.equal(quaternion_error(q, target), 1.0 - (q * target).sum(-1).square())
    expected = torch.arccos((1.0 - 2.0 * quaternion_error(q, target)).clamp(-1.0, 1.0))
    assert torch.equal(quaternion_angle(q, target), expected)
    assert quaternion_angle(q, target).shape == (3, 8)


def test_gradcheck_in_float64():
    a = _quats(3).requires_grad_()
    b = _quats(3, seed=1).requires_grad_()
    rotation = torch.randn(3, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(quaternion_multiply, (a, b))
    assert torch.autograd.gradcheck(quaternion_exp, (rotation,))
    assert torch.autograd.gradcheck(quaternion_to_matrix, (a,))
    assert torch.autograd.gradcheck(up_axis, (a,))
    assert torch.autograd.gradcheck(quaternion_error, (a, b))
    assert torch.autograd.gradcheck(quaternion_angle, (a, b))


def test_finite_gradients_at_identity():
    q = IDENTITY.clone().requires_grad_()
    rotation = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    outputs = [
        quaternion_exp(rotation).sum(),
        quaternion_to_matrix(q).sum(),
        up_axis(q).sum(),
        quaternion_multiply(q, IDENTITY).sum(),
        quaternion_error(q, IDENTITY),
    ]
    for out in outputs:
        grads = torch.autograd.grad(out, (q, rotation), allow_unused=True)
        assert all(g is None or torch.isfinite(g).all() for g in grads)
    (grad,) = torch.autograd.grad(quaternion_exp(rotation)[1:].sum(), rotation)
    torch.testing.assert_close(grad, torch.full((3,), 0.5, dtype=torch.float64))


@pytest.mark.parametrize("dtype", DTYPES)
def test_log_inverts_exp_taking_the_shorter_rotation(dtype):
    quats = _quats(64, dtype=dtype, seed=3)
    rotation = quaternion_log(quats)
    assert (torch.linalg.vector_norm(rotation, dim=-1) <= math.pi + 1e-5).all()
    back = quaternion_exp(rotation)
    torch.testing.assert_close(quaternion_error(back, quats), torch.zeros(64, dtype=dtype))
    torch.testing.assert_close(quaternion_log(-quats), rotation)  # q and −q: one rotation
    small = torch.tensor([[1e-9, -2e-9, 3e-9]], dtype=torch.float64)
    torch.testing.assert_close(quaternion_log(quaternion_exp(small)), small)
