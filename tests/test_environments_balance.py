"""The balance term of the hands' cost: an object's base from its geometry, the centre of
pressure a planned push puts on it, the gate that lifts the term while fingers hold the object,
and the options that set it."""

from __future__ import annotations

import math

import pytest
import torch
import trimesh

from mpc.trials import LEGACY_DEFAULTS, build_trial, stored_config, trial_configs
from torchcontact.cli import main
from torchcontact.contacts import Contacts
from torchcontact.environments import environment
from torchcontact.environments.costs import (
    BALANCE_DIRECTIONS,
    HOLDING_DISTANCE,
    Balance,
    ManipulationCost,
    balance_cost,
    balance_directions,
)
from torchcontact.environments.hands import HAND_METRIC, balance_of
from torchcontact.rotations import quaternion_exp
from torchcontact.shapes import load_object
from torchcontact.sim.hands import HandEnv

F64 = torch.float64
LEVER, WEIGHT = HAND_METRIC[3] / HAND_METRIC[0], 9.81 * 0.01 / HAND_METRIC[0]
UPRIGHT = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64)


def square_base(half: float, height: float, friction: float = 0.5, threshold: float = 0.5):
    corners = [(-half, -half), (half, -half), (half, half), (-half, half)]
    return Balance.of_base(
        corners, (0.0, 0.0), height=height, friction=friction, lever=LEVER, weight=WEIGHT,
        threshold=threshold,
    )  # fmt: skip


def rollout(steps: torch.Tensor, turns: torch.Tensor | None = None, start=UPRIGHT):
    """Positions and quaternions ``(T+1, ·)`` of an object moved by ``steps (T, 3)`` [m] and
    turned by the world rotation vectors ``turns (T, 3)`` [rad]."""
    positions = torch.cat([torch.zeros(1, 3, dtype=F64), steps.cumsum(0)])
    quats = [start]
    for turn in torch.zeros_like(steps) if turns is None else turns:
        w1, v1 = quaternion_exp(turn).split([1, 3])
        w2, v2 = quats[-1].split([1, 3])
        quats.append(torch.cat([w1 * w2 - (v1 * v2).sum(0, keepdim=True),
                                w1 * v2 + w2 * v1 + torch.linalg.cross(v1, v2)]))  # fmt: skip
    return positions, torch.stack(quats)


def test_a_base_reaches_as_far_as_its_outline_in_each_direction():
    base = square_base(0.02, 0.05)
    directions = balance_directions()
    assert directions.shape == (BALANCE_DIRECTIONS, 2)
    expected = 0.02 * (directions[:, 0].abs() + directions[:, 1].abs())  # a square's support
    torch.testing.assert_close(base.reaches, expected)
    off_centre = Balance.of_base(
        [(-0.02, -0.02), (0.02, -0.02), (0.02, 0.02), (-0.02, 0.02)], (0.015, 0.0),
        height=0.05, friction=0.5, lever=LEVER, weight=WEIGHT,
    )  # fmt: skip
    assert float(off_centre.reaches[0]) == pytest.approx(0.005)  # towards +x, the near edge
    assert float(off_centre.reaches[8]) == pytest.approx(0.035)


def test_a_slide_pushed_high_on_a_tall_object_costs_and_one_low_enough_does_not():
    """Pushed 2 mm a step at the pose point, 5 cm up, the centre of pressure lies μ·5 cm =
    2.5 cm out, past the 1 cm base: charged. With the model's turn that a push at the base's
    height adds (−z·F/lever), the moment cancels: free."""
    base = square_base(0.01, 0.05)
    steps = torch.tensor([[0.002, 0.0, 0.0]] * 3, dtype=F64)
    high = balance_cost(*rollout(steps), base)
    sliding = 0.05 * 0.002 / math.sqrt(WEIGHT**2 + (0.002 / 0.5) ** 2)
    assert float(high) == pytest.approx(3 * (sliding / 0.01 - 0.5) ** 2)
    turns = torch.tensor([[0.0, -0.05 * 0.002 / LEVER, 0.0]] * 3, dtype=F64)
    assert float(balance_cost(*rollout(steps, turns), base)) == pytest.approx(0.0, abs=1e-6)
    wide_and_low = square_base(0.03, 0.01)
    assert float(balance_cost(*rollout(steps), wide_and_low)) == 0.0


def test_turning_in_place_about_the_vertical_costs_nothing():
    base = square_base(0.005, 0.05)
    turns = torch.tensor([[0.0, 0.0, 0.1]] * 4, dtype=F64)
    assert float(balance_cost(*rollout(torch.zeros(4, 3, dtype=F64), turns), base)) == 0.0


def test_the_centre_of_pressure_is_judged_in_the_body_frame():
    """A base long along the body's x: a push along the world's x is free while the body's x
    lies along it, charged once the object is turned a quarter turn about the vertical."""
    corners = [(-0.04, -0.008), (0.04, -0.008), (0.04, 0.008), (-0.04, 0.008)]
    base = Balance.of_base(corners, (0.0, 0.0), height=0.04, friction=0.5, lever=LEVER,
                           weight=WEIGHT)  # fmt: skip
    steps = torch.tensor([[0.002, 0.0, 0.0]] * 2, dtype=F64)
    assert float(balance_cost(*rollout(steps), base)) == 0.0
    quarter = quaternion_exp(torch.tensor([0.0, 0.0, math.pi / 2], dtype=F64))
    assert float(balance_cost(*rollout(steps, start=quarter), base)) > 1.0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_balance_cost_batches_with_finite_gradients(dtype):
    base = square_base(0.01, 0.05)
    generator = torch.Generator().manual_seed(0)
    positions = 0.003 * torch.randn(2, 3, 5, 3, generator=generator, dtype=F64)
    quats = UPRIGHT + 0.02 * torch.randn(2, 3, 5, 4, generator=generator, dtype=F64)
    quats = (quats / quats.norm(dim=-1, keepdim=True)).to(dtype)
    positions = positions.to(dtype).requires_grad_()
    value = balance_cost(positions, quats, base)
    assert value.shape == (2, 3) and value.dtype == dtype
    (grad,) = torch.autograd.grad(value.sum(), positions)
    assert torch.isfinite(grad).all() and grad.abs().sum() > 0
    still = balance_cost(torch.zeros(4, 3, dtype=dtype), UPRIGHT.to(dtype).expand(4, 4), base)
    assert float(still) == 0.0


def test_balance_cost_gradcheck():
    base = square_base(0.01, 0.05)
    steps = torch.tensor([[0.002, 0.001, 0.0], [0.0015, -0.0005, 0.0001]], dtype=F64)
    turns = torch.tensor([[0.001, 0.002, 0.03], [-0.001, 0.0, 0.01]], dtype=F64)
    positions, quats = rollout(steps, turns)
    assert torch.autograd.gradcheck(
        lambda p, q: balance_cost(p, q / q.norm(dim=-1, keepdim=True), base),
        (positions.requires_grad_(), quats.requires_grad_()),
    )


def test_the_term_is_lifted_while_two_fingers_hold_the_object():
    base = square_base(0.01, 0.05)
    nv = 15

    def contacts(phi, static):
        n = len(phi)
        return Contacts(
            phi=torch.tensor(phi, dtype=F64),
            jac_normal=torch.zeros(n, nv, dtype=F64),
            jac_tangent=torch.zeros(n, 2, nv, dtype=F64),
            mu=torch.full((n,), 0.5, dtype=F64),
            active=torch.tensor([True] * (n - 1) + [False]),
            static=torch.tensor(static),
        )

    near = HOLDING_DISTANCE / 2
    steps = torch.tensor([[0.002, 0.0, 0.0]] * 2, dtype=F64)
    ground = [0.0, 0.0, 0.0]
    base.observe(contacts([*ground, near, 0.0], [True] * 3 + [False, False]))
    assert float(base.alone) == 1.0 and float(balance_cost(*rollout(steps), base)) > 0
    base.observe(contacts([*ground, near, near, 0.0], [True] * 3 + [False] * 3))
    assert float(base.alone) == 0.0 and float(balance_cost(*rollout(steps), base)) == 0.0
    far = 2 * HOLDING_DISTANCE  # a second finger farther off: the first pushes alone
    base.observe(contacts([*ground, near, far, 0.0], [True] * 3 + [False] * 3))
    assert float(base.alone) == 1.0
    unmarked = contacts([near, 0.0], [False, False])
    with pytest.raises(ValueError, match="contacts.static is None"):
        base.observe(Contacts(**{**vars(unmarked), "static": None}))


@pytest.mark.parametrize(
    "options, message",
    [
        ({"reaches": torch.full((BALANCE_DIRECTIONS,), -0.01)}, "reaches must be 16 positive"),
        ({"reaches": torch.full((3,), 0.01)}, "reaches must be 16 positive"),
        ({"height": 0.0}, "height must be a positive finite number"),
        ({"friction": math.nan}, "friction must be a positive finite number"),
        ({"threshold": -1.0}, "threshold must be a positive finite number"),
    ],
)
def test_bad_balances_are_refused_by_name(options, message):
    arguments = {"reaches": torch.full((BALANCE_DIRECTIONS,), 0.01), "height": 0.05,
                 "friction": 0.5, "lever": LEVER, "weight": WEIGHT, **options}  # fmt: skip
    with pytest.raises(ValueError, match=message):
        Balance(**arguments)


def test_the_repr_names_the_settings_not_the_object():
    """The repr keys the MPC's compiled graphs: one graph for every object."""
    assert repr(square_base(0.01, 0.05)) == repr(square_base(0.03, 0.02, friction=0.9))
    assert "threshold=0.5" in repr(square_base(0.01, 0.05))


def test_the_hands_cost_carries_the_balance_of_objects_that_stand_on_a_base():
    env, plant = environment("trifinger"), HandEnv("trifinger", "cube")
    assert env.cost(plant, balance=0.0).balance is None
    cost = env.cost(plant, balance=2.0)
    assert isinstance(cost, ManipulationCost) and cost.balance_weight == 2.0
    # the 6 cm cube, its centre of mass at its middle: 3 cm to each face, at 3 cm height
    assert float(cost.balance.reaches[0]) == pytest.approx(0.03)
    assert float(cost.balance.facts[0]) == pytest.approx(0.03)
    assert float(cost.balance.facts[1]) == max(plant.object_friction, plant.ground_friction)
    with pytest.raises(ValueError, match="balance must be a non-negative number"):
        env.cost(plant, balance=-1.0)
    fingertips = environment("fingertips")
    with pytest.raises(ValueError, match="balance: the fingertips keep the paper's cost"):
        fingertips.cost(fingertips.make_plant("cube"), balance=1.0)


def test_an_object_with_no_base_to_stand_on_has_no_balance(tmp_path):
    cone = trimesh.creation.cone(radius=0.03, height=0.05)
    cone.apply_transform(trimesh.transformations.rotation_matrix(math.pi, [1, 0, 0]))
    cone.export(tmp_path / "point_down.stl")
    standing_on_its_tip = load_object(tmp_path / "point_down.stl", 0.06, decomposition="hull")
    assert standing_on_its_tip.base() is None
    plant = HandEnv("trifinger", "cube")
    assert balance_of(plant, HAND_METRIC, 0.5) is not None
    plant.object = standing_on_its_tip
    assert balance_of(plant, HAND_METRIC, 0.5) is None
    assert environment("trifinger").cost(plant, balance=1.0).balance is None


def test_a_trial_plans_with_its_balance():
    configs = trial_configs("trifinger", [("in-hand", "cube")], [0], balance=1.5)
    assert configs[0].balance == 1.5
    _, _, mpc = build_trial(configs[0])
    assert mpc.cost.balance is not None and mpc.cost.balance_weight == 1.5
    default = trial_configs("trifinger", [("in-hand", "cube")], [0])[0]
    assert default.balance == environment("trifinger").balance
    assert trial_configs("allegro", [("on-palm", "cube")], [0])[0].balance == 0.0
    old = {key: value for key, value in vars(default).items() if key != "balance"}
    assert stored_config(old)["balance"] == LEGACY_DEFAULTS["balance"] == 0.0  # ran without


def test_the_cli_refuses_a_meaningless_balance(capsys):
    for argv, message in (
        (["trifinger", "--balance", "-1"], "--balance must be a weight >= 0"),
        (["trifinger", "--balance", "1", "--cost", "pushing"], "--balance is a term of the"),
        (["fingertips", "--balance", "1"], "balance: the fingertips keep the paper's cost"),
    ):
        with pytest.raises(SystemExit):
            main(["run", *argv, "--trials", "1"])
        assert message in capsys.readouterr().err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_balance_cost_and_its_gate_run_on_cuda():
    base = square_base(0.01, 0.05)
    steps = torch.tensor([[0.002, 0.0, 0.0]] * 3, dtype=F64)
    positions, quats = rollout(steps)
    expected = balance_cost(positions, quats, base)
    moved = positions.cuda().float().requires_grad_()
    on_gpu = balance_cost(moved, quats.cuda().float(), base)
    assert on_gpu.device.type == "cuda"
    torch.testing.assert_close(on_gpu.double().cpu(), expected, rtol=1e-4, atol=1e-6)
    (grad,) = torch.autograd.grad(on_gpu, moved)
    assert torch.isfinite(grad).all()
    n, nv = 5, 15
    contacts = Contacts(
        phi=torch.zeros(n, device="cuda"),
        jac_normal=torch.zeros(n, nv, device="cuda"),
        jac_tangent=torch.zeros(n, 2, nv, device="cuda"),
        mu=torch.full((n,), 0.5, device="cuda"),
        active=torch.ones(n, dtype=torch.bool, device="cuda"),
        static=torch.tensor([True, True, True, False, False], device="cuda"),
    )
    base.observe(contacts)  # two fingers touch: held
    assert float(base.alone) == 0.0
    assert float(balance_cost(positions.cuda(), quats.cuda(), base)) == 0.0
