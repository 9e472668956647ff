"""QuasiDynamic and full_dynamic: the layout of Q and b, and the contact-free step they give."""

from __future__ import annotations

import pytest
import torch

from torchcontact import (
    ComplementarityFree,
    Contacts,
    JointLayout,
    QuasiDynamic,
    carry_momentum,
    cf_velocity,
    full_dynamic,
    integrate,
)
from torchcontact.validation import validate_args

H, EPS, KR, G = 0.02, 40.0, 500.0, 9.8
CUBE_MASS, CUBE_INERTIA = 0.01, 6e-6


def bar_and_cubes(n_cubes: int = 2) -> QuasiDynamic:
    """A bar on a slide joint (velocity index 0) pushing free cubes (indices 1 …)."""
    mass = torch.tensor([CUBE_MASS] * 3 + [CUBE_INERTIA] * 3, dtype=torch.float64)
    gravity = torch.tensor([0, 0, -CUBE_MASS * G, 0, 0, 0], dtype=torch.float64)
    return QuasiDynamic(
        object_metric=(EPS * mass / H**2).repeat(n_cubes),
        robot_stiffness=KR,
        object_force=gravity.repeat(n_cubes),
        object_dofs=range(1, 1 + 6 * n_cubes),
        n_robot=1,
    )


def _free_step(system: QuasiDynamic, u: torch.Tensor, robot_force=None) -> torch.Tensor:
    Q, b = system(u, robot_force)
    no_rows = torch.zeros(*b.shape[:-1], 0, system.nv, dtype=b.dtype)
    return cf_velocity(Q, b, no_rows, torch.zeros(*b.shape[:-1], 0, dtype=b.dtype), H, 1.0)


def test_layout_with_object_dofs_after_the_robot():
    system = bar_and_cubes(2)
    assert (system.n_object, system.n_robot, system.nv) == (12, 1, 13)
    u = torch.tensor([-0.001], dtype=torch.float64)
    Q, b = system(u, robot_force=torch.tensor([0.25], dtype=torch.float64))
    assert Q.shape == (13,) and b.shape == (13,)
    assert float(Q[0]) == KR
    cube = EPS / H**2 * torch.tensor([CUBE_MASS] * 3 + [CUBE_INERTIA] * 3, dtype=torch.float64)
    torch.testing.assert_close(Q[1:], cube.repeat(2))
    torch.testing.assert_close(b[0], torch.tensor(KR * -0.001 + 0.25, dtype=torch.float64))
    torch.testing.assert_close(b[1:7], torch.tensor([0, 0, -CUBE_MASS * G, 0, 0, 0.0]).double())
    torch.testing.assert_close(b[1:7], b[7:13])


def test_interleaved_object_dofs():
    system = QuasiDynamic([1.0, 2.0], [10.0, 20.0, 30.0], [0.5, -0.5], object_dofs=[3, 1])
    Q, b = system(torch.tensor([1.0, 2.0, 3.0]))
    torch.testing.assert_close(Q, torch.tensor([10.0, 2.0, 20.0, 1.0, 30.0]))
    torch.testing.assert_close(b, torch.tensor([10.0, -0.5, 40.0, 0.5, 90.0]))


def test_free_motion_moves_the_robot_by_u_and_drops_the_object():
    """Without contact ``h·v = Q⁻¹b``: the robot moves by u, each cube by ``h²τ/(εM)``."""
    system = bar_and_cubes(2)
    u = torch.tensor([-0.0013], dtype=torch.float64)
    v = _free_step(system, u)
    torch.testing.assert_close(H * v[0], u[0], rtol=1e-15, atol=0)
    fall = -G * H**2 / EPS  # per step, independent of the cube's mass
    expected = torch.zeros(12, dtype=torch.float64)
    expected[[2, 8]] = fall
    torch.testing.assert_close(H * v[1:], expected, rtol=1e-6, atol=1e-18)
    Q, b = system(u)
    torch.testing.assert_close(H * v, b / Q, rtol=1e-14, atol=0)
    # Integrated: the bar's coordinate moves by u, the cubes' heights by the fall.
    layout = JointLayout(["slide", "free", "free"])
    q = torch.tensor([0.1, 0, 0, 0.03, 1, 0, 0, 0, 0.1, 0, 0.03, 1, 0, 0, 0], dtype=torch.float64)
    q_next = integrate(q, v, H, layout)
    torch.testing.assert_close(q_next[0] - q[0], u[0], rtol=1e-12, atol=0)
    torch.testing.assert_close(q_next[[3, 10]] - q[[3, 10]], torch.full((2,), fall).double())
    torch.testing.assert_close(q_next[4:8], q[4:8])


def test_momentum_blends_the_free_step_with_the_previous_displacement():
    """Free: the object moves by ``(Δ_quasi + m·Δ_prev)/(1 + m)``; the robot as before."""
    base = bar_and_cubes(2)
    m = 3.0
    system = QuasiDynamic(
        base.object_metric, KR, base.object_force, object_dofs=range(1, 13), n_robot=1,
        object_momentum=m,
    )  # fmt: skip
    u = torch.tensor([[0.002], [-0.001]], dtype=torch.float64)
    previous = torch.randn(2, 12, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    quasi = H * _free_step(base, u)
    Q, b = system(u, object_displacement=previous)
    moved = b / Q
    torch.testing.assert_close(moved[:, 0], quasi[:, 0])
    torch.testing.assert_close(moved[:, 1:], (quasi[:, 1:] + m * previous) / (1 + m))
    Q_rest, b_rest = system(u)  # at rest: the same metric, nothing carried
    torch.testing.assert_close(Q_rest, Q)
    torch.testing.assert_close((b_rest / Q_rest)[:, 1:], quasi[:, 1:] / (1 + m))
    Q_none, b_none = carry_momentum(*base(u), previous, 0.0, torch.arange(1, 13))
    torch.testing.assert_close((Q_none, b_none), base(u))
    with pytest.raises(ValueError, match="object_momentum must be >= 0"):
        QuasiDynamic(torch.ones(6), 1.0, torch.zeros(6), n_robot=1, object_momentum=-0.5)


def test_free_motion_through_the_contact_model_with_empty_contacts():
    system = bar_and_cubes(1)
    u = torch.tensor([[0.002], [-0.001]], dtype=torch.float64)
    Q, b = system(u)
    contacts = Contacts.empty(4, system.nv, batch=(2,), dtype=torch.float64)
    v = ComplementarityFree(stiffness=1.0)(Q, b, contacts, H)
    torch.testing.assert_close(H * v[:, 0], u[:, 0], rtol=1e-15, atol=0)


def test_batch_shapes():
    system = bar_and_cubes(3)
    u = torch.randn(4, 5, 1, dtype=torch.float64)
    force = torch.randn(4, 5, 1, dtype=torch.float64)
    Q, b = system(u, robot_force=force)
    assert Q.shape == (system.nv,) and b.shape == (4, 5, system.nv)
    torch.testing.assert_close(b[..., 0], KR * u[..., 0] + force[..., 0])
    torch.testing.assert_close(b[..., 1:], system(u[0, 0])[1][1:].expand(4, 5, -1))
    v = _free_step(system, u, force)
    assert v.shape == (4, 5, system.nv)
    torch.testing.assert_close(H * v[..., 0], u[..., 0] + force[..., 0] / KR)


def test_float64_arguments_keep_their_precision():
    """Float64 tensors given to the constructor are not rounded to the default dtype."""
    metric = torch.tensor([0.1, 1 / 3], dtype=torch.float64)
    force = torch.tensor([0.1, -0.7], dtype=torch.float64)
    system = QuasiDynamic(metric, torch.tensor([1 / 7], dtype=torch.float64), force)
    Q, b = system(torch.zeros(1, dtype=torch.float64))
    torch.testing.assert_close(Q[:2], metric, rtol=1e-15, atol=0)
    torch.testing.assert_close(b[:2], force, rtol=1e-15, atol=0)


def test_dtype_follows_u_and_to_moves_buffers():
    system = bar_and_cubes(1)
    Q, b = system(torch.zeros(1, dtype=torch.float64))
    assert Q.dtype == b.dtype == torch.float64
    Q32, b32 = system.to(torch.float32)(torch.zeros(1, dtype=torch.float32))
    assert Q32.dtype == b32.dtype == torch.float32


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"object_metric": [1.0, -1.0]}, "object_metric"),
        ({"object_metric": [[1.0, 1.0]]}, "object_metric"),
        ({"object_metric": [1.0, float("nan")]}, "object_metric"),
        ({"robot_stiffness": [1.0, 0.0]}, "robot_stiffness"),
        ({"robot_stiffness": [1.0, 2.0], "n_robot": 3}, "robot_stiffness"),
        ({"robot_stiffness": 3.0}, "n_robot"),
        ({"object_force": [1.0]}, "object_force"),
        ({"object_dofs": [0, 0]}, "object_dofs"),
        ({"object_dofs": [0, 4]}, "object_dofs"),
        ({"object_dofs": [0]}, "object_dofs"),
        ({"object_dofs": [-1, 0]}, "object_dofs"),
    ],
)
def test_bad_arguments_raise_naming_them(kwargs, name):
    args = {
        "object_metric": [1.0, 1.0],
        "robot_stiffness": [2.0, 2.0],
        "object_force": [0.0, 0.0],
        "n_robot": 2,
        **kwargs,
    }
    if isinstance(args["robot_stiffness"], float) and "n_robot" not in kwargs:
        args.pop("n_robot")
    with pytest.raises(ValueError, match=name):
        QuasiDynamic(**args)


def test_bad_u_raises_naming_u():
    system = bar_and_cubes(1)
    with pytest.raises(ValueError, match="^u must have shape"):
        system(torch.zeros(2))
    with pytest.raises(ValueError, match="^u must have shape"):
        system(torch.tensor(0.0))
    with pytest.raises(TypeError, match="u"):
        system([0.0])


def test_full_dynamic_metric_and_linear_term():
    A = torch.randn(3, 4, 4, dtype=torch.float64)
    M = A @ A.mT + 4 * torch.eye(4, dtype=torch.float64)
    v = torch.randn(3, 4, dtype=torch.float64)
    tau = torch.randn(3, 4, dtype=torch.float64)
    h = 0.01
    Q, b = full_dynamic(M, v, tau, h)
    torch.testing.assert_close(Q, M / h**2)
    torch.testing.assert_close(b, (M @ v.unsqueeze(-1)).squeeze(-1) / h + tau)
    free = cf_velocity(Q, b, torch.zeros(3, 0, 4).double(), torch.zeros(3, 0).double(), h, 1.0)
    torch.testing.assert_close(free, v + h * torch.linalg.solve(M, tau))


@pytest.mark.parametrize(
    "shapes, h, name",
    [
        (((3, 3), (3,), (2,)), 0.1, "force"),
        (((3, 2), (3,), (3,)), 0.1, "mass_matrix"),
        (((3, 3), (3,), (3,)), 0.0, "h"),
        (((3, 3), (3,), (3,)), -0.1, "h"),
    ],
)
def test_full_dynamic_bad_arguments(shapes, h, name):
    M, v, tau = (torch.ones(s, dtype=torch.float64) for s in shapes)
    with pytest.raises(ValueError, match=name):
        full_dynamic(M, v, tau, h)


def test_full_dynamic_rejects_nan():
    with pytest.raises(ValueError, match="velocity"):
        full_dynamic(torch.eye(2), torch.tensor([0.0, float("nan")]), torch.zeros(2), 0.1)


def test_non_finite_commands_name_themselves():
    system = bar_and_cubes(1)
    with pytest.raises(ValueError, match="^u must be finite"):
        system(torch.tensor([[0.01], [float("nan")]], dtype=torch.float64))
    with pytest.raises(ValueError, match="^robot_force must be finite"):
        system(torch.zeros(1, dtype=torch.float64), torch.tensor([float("inf")]))


def test_a_system_carrying_momentum_traces_without_a_graph_break():
    """The MPC compiles its rollout, which calls the system at every step: the object's rows
    must not be derived per call from tensor data (a break would split the graph each time)."""
    system = QuasiDynamic([1e4] * 3, 1e4, [0.0, 0.0, -9.81], n_robot=1, object_momentum=1.5)
    system = system.double()

    def total(u, moved):
        Q, b = system(u, object_displacement=moved)
        return (Q * b).sum()

    with validate_args(False):
        args = (torch.ones(1, dtype=torch.float64), torch.ones(3, dtype=torch.float64))
        explained = torch._dynamo.explain(total)(*args)
    assert explained.graph_break_count == 0
