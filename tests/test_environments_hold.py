"""The hold-first term of the hands' cost: a lone object that would tip is held where it
stands until fingertips hold it, for objects chosen by their geometry, and the options that set
it."""

from __future__ import annotations

import math

import pytest
import torch

from torchcontact.cli import main
from torchcontact.contacts import Contacts
from torchcontact.environments import CostOptions, environment
from torchcontact.environments.costs import HOLDING_DISTANCE, HoldFirst, ManipulationCost
from torchcontact.environments.hands import tips_before_sliding
from torchcontact.mpc.trial_config import LEGACY_DEFAULTS, flat_config, stored_config, trial_configs
from torchcontact.mpc.trials import build_trial
from torchcontact.sim.hands import HandPlant

F64 = torch.float64
NV = 15


def contacts(phi, static) -> Contacts:
    """Contacts at distances ``phi`` [m], ``static`` marking the support's; one empty slot."""
    n = len(phi) + 1
    return Contacts(
        phi=torch.tensor([*phi, 1.0], dtype=F64),
        jac_normal=torch.zeros(n, NV, dtype=F64),
        jac_tangent=torch.zeros(n, 2, NV, dtype=F64),
        mu=torch.full((n,), 0.5, dtype=F64),
        active=torch.tensor([True] * (n - 1) + [False]),
        static=torch.tensor([*static, False]),
    )


GROUND = ([0.0, 0.0, 0.0], [True, True, True])
NEAR = HOLDING_DISTANCE / 2


def held_by(*tips: float) -> Contacts:
    return contacts(GROUND[0] + list(tips), GROUND[1] + [False] * len(tips))


def test_the_object_counts_as_held_once_enough_fingertips_touch_it():
    hold = HoldFirst(grip=2)
    hold.observe(held_by(NEAR))
    assert float(hold.held) == 0.0
    hold.observe(held_by(NEAR, NEAR))
    assert float(hold.held) == 1.0
    hold.observe(held_by(NEAR, 2 * HOLDING_DISTANCE))  # the second one still on its way
    assert float(hold.held) == 0.0
    hold.observe(contacts([0.0] * 4, [True] * 4))  # the support alone holds nothing
    assert float(hold.held) == 0.0
    assert float(HoldFirst(grip=1).held) == 0.0
    one = HoldFirst(grip=1)
    one.observe(held_by(NEAR))
    assert float(one.held) == 1.0
    unmarked = held_by(NEAR, NEAR)
    with pytest.raises(ValueError, match="contacts.static is None: the hold-first term"):
        hold.observe(Contacts(**{**vars(unmarked), "static": None}))


@pytest.mark.parametrize("grip", [0, -1, 1.5, True, "2"])
def test_a_meaningless_grip_is_refused(grip):
    with pytest.raises(ValueError, match="grip must be a whole number of contacts >= 1"):
        HoldFirst(grip)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_until_held_the_plan_aims_where_the_object_stands(dtype):
    """Unheld, a rollout that leaves the object where it started has no pose cost, and one
    that moves it toward the target is charged; held, the cost is the paper's, batched."""
    batch, horizon, tips = (2, 5), 3, torch.zeros(2, 5, 4, 3, 3, dtype=dtype)
    start = torch.tensor([0.01, -0.02, 0.03], dtype=dtype)
    still = start.expand(*batch, horizon + 1, 3).clone()
    moved = still.clone()
    moved[..., 1:, 0] += 0.02
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype).expand(*batch, horizon + 1, 4)
    controls = torch.zeros(*batch, horizon, 9, dtype=dtype)
    target_p = torch.tensor([0.05, -0.02, 0.03], dtype=dtype).expand(*batch, 3)
    target_q = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype).expand(*batch, 4)
    hold = HoldFirst(grip=2)
    plain, holding = (
        ManipulationCost(contact=0, grasp=0),
        ManipulationCost(contact=0, grasp=0, hold=hold),
    )

    def cost(c, positions):
        return c(positions, quats, tips, controls, target_p, target_q)

    holding.observe(held_by(NEAR))
    assert cost(holding, still).shape == batch and cost(holding, still).dtype == dtype
    assert torch.equal(cost(holding, still), torch.zeros(batch, dtype=dtype))
    assert bool((cost(holding, moved) > 0).all())
    assert bool((cost(plain, still) > cost(plain, moved)).all())  # the target pulls it on
    holding.observe(held_by(NEAR, NEAR))
    for positions in (still, moved):
        torch.testing.assert_close(cost(holding, positions), cost(plain, positions))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_until_held_the_approach_weighs_the_contact_term(dtype):
    """Unheld, the contact term is ``approach`` times the paper's and every other term is the
    hold's; held, the cost is the hold's, whatever the approach."""
    batch, horizon = (3,), 4
    tips = torch.linspace(-0.04, 0.05, 3 * (horizon + 1) * 3 * 3, dtype=dtype)
    tips = tips.reshape(3, horizon + 1, 3, 3)
    positions = torch.linspace(0, 0.02, 3 * (horizon + 1) * 3, dtype=dtype)
    positions = positions.reshape(*batch, horizon + 1, 3)
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype).expand(*batch, horizon + 1, 4)
    controls = torch.full((*batch, horizon, 9), 0.003, dtype=dtype)
    target_p = torch.tensor([0.05, -0.02, 0.03], dtype=dtype)
    target_q = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype)

    def cost(hold, contact=1.0):
        c = ManipulationCost(contact=contact, hold=hold)
        return c(positions, quats, tips, controls, target_p, target_q)

    plain, drawn = HoldFirst(grip=2), HoldFirst(grip=2, approach=4.0)
    for hold in (plain, drawn):
        hold.observe(held_by(NEAR))
    weighed = cost(drawn)
    assert weighed.shape == batch and weighed.dtype == dtype
    torch.testing.assert_close(weighed, cost(plain, contact=4.0))
    assert bool((weighed > cost(plain)).all())
    for hold in (plain, drawn):
        hold.observe(held_by(NEAR, NEAR))
    torch.testing.assert_close(cost(drawn), cost(plain))
    assert "approach=4.0" in repr(drawn) and "approach" not in repr(plain)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="approach must be a positive finite weight"):
            HoldFirst(2, approach=bad)


def test_the_hands_hold_the_objects_that_tip_before_they_slide():
    env = environment("trifinger")
    tall, wide = HandPlant("trifinger", "water_bottle"), HandPlant("trifinger", "cube")
    assert tips_before_sliding(tall.object) and not tips_before_sliding(wide.object)
    cost = env.cost(tall, CostOptions(hold_first=3))
    assert isinstance(cost, ManipulationCost) and cost.hold.grip == 3
    # it slides, so a lone push is safe: its hold is there (one graph) but switched off
    off = env.cost(wide, CostOptions(hold_first=3)).hold
    off.observe(held_by(NEAR))
    assert float(off.applies) == 0 and float(cost.hold.applies) == 1
    start, target = torch.zeros(2, 4, 3, dtype=F64), torch.ones(3, dtype=F64)
    quats = torch.tensor([1.0, 0, 0, 0], dtype=F64).expand(2, 4, 4)
    aim, _ = off.aims(start, quats, target, quats[0, 0])
    assert torch.equal(aim, target.expand(2, 3))  # the target, as without a hold
    assert float(off.contact_weight(start)) == 1.0
    assert env.cost(tall, CostOptions(hold_first=0)).hold is None
    assert env.cost(tall).hold.grip == env.cost_defaults.hold_first == 2  # the TriFinger's default
    # the repr keys the compiled graphs: one graph for every held object
    assert repr(cost.hold) == repr(
        env.cost(HandPlant("trifinger", "binoculars"), CostOptions(hold_first=3)).hold
    )
    for value in (-1, 1.5, True):
        with pytest.raises(ValueError, match="hold_first must be a number of contacts >= 0"):
            env.cost(tall, CostOptions(hold_first=value))
    fingertips = environment("fingertips")
    with pytest.raises(ValueError, match="hold_first: the fingertips cost has no such term"):
        fingertips.cost(fingertips.make_plant("cube"), CostOptions(hold_first=2))
    with pytest.raises(ValueError, match="hold_approach: the fingertips cost has no such term"):
        fingertips.cost(fingertips.make_plant("cube"), CostOptions(hold_approach=4.0))
    assert (
        fingertips.cost(fingertips.make_plant("cube"), CostOptions(hold_approach=1.0)).hold is None
    )


def test_the_hands_weigh_the_approach_to_a_hold():
    env, tall = environment("trifinger"), HandPlant("trifinger", "water_bottle")
    hold = env.cost(tall, CostOptions(hold_first=2, hold_approach=3.0)).hold
    assert hold.approach == 3.0
    defaults = env.cost_defaults
    assert env.cost(tall, CostOptions(hold_first=2)).hold.approach == defaults.hold_approach
    with pytest.raises(ValueError, match="hold_approach: it applies with hold_first only; set"):
        env.cost(tall, CostOptions(hold_first=0, hold_approach=3.0))
    for value in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="hold_approach must be a weight > 0"):
            env.cost(tall, CostOptions(hold_approach=value))


def test_a_trial_plans_with_its_hold():
    held = CostOptions(hold_first=2)
    configs = trial_configs("trifinger", [("in-hand", "water_bottle")], [0], cost_options=held)
    assert configs[0].cost_options.hold_first == 2
    _, _, mpc = build_trial(configs[0])
    assert mpc.cost.hold is not None and mpc.cost.hold.grip == 2
    default = trial_configs("trifinger", [("in-hand", "cube")], [0])[0]
    assert default.cost_options.hold_first == environment("trifinger").cost_defaults.hold_first
    fingertips = trial_configs("fingertips", [("rotation", "cube")], [0])[0]
    assert fingertips.cost_options.hold_first == 0
    new_keys = ("hold_first", "hold_approach")
    old = {k: v for k, v in flat_config(default).items() if k not in new_keys}
    assert stored_config(old)["hold_first"] == LEGACY_DEFAULTS["hold_first"] == 0  # ran without
    unheld = trial_configs(
        "trifinger", [("in-hand", "cube")], [0], cost_options=CostOptions(hold_first=0)
    )[0]
    assert stored_config(old)["hold_approach"] == LEGACY_DEFAULTS["hold_approach"] == 1.0
    defaults = environment("trifinger").cost_defaults
    assert default.cost_options.hold_approach == defaults.hold_approach
    assert unheld.cost_options.hold_approach == 1.0  # no hold to approach
    drawn = trial_configs(
        "trifinger", [("in-hand", "water_bottle")], [0], cost_options=CostOptions(hold_approach=3.0)
    )
    assert build_trial(drawn[0])[2].cost.hold.approach == 3.0
    pushing = trial_configs("trifinger", [("in-hand", "cube")], [0], cost="pushing")[0]
    assert pushing.cost_options.hold_approach == 1.0


def test_the_cli_refuses_a_meaningless_hold(capsys):
    for argv, message in (
        (["trifinger", "--hold-first", "-1"], "--hold-first must be a number of contacts >= 0"),
        (["trifinger", "--hold-first", "2", "--cost", "pushing"], "--hold-first is a term of"),
        (["fingertips", "--hold-first", "2"], "--hold-first: the fingertips cost has no such"),
        (["trifinger", "--hold-approach", "0"], "--hold-approach must be a weight > 0"),
        (["trifinger", "--hold-approach", "2", "--hold-first", "0"], "--hold-approach: it applies"),
        (["trifinger", "--hold-approach", "2", "--cost", "pushing"], "--hold-approach is a"),
    ):
        with pytest.raises(SystemExit):
            main(["run", *argv, "--trials", "1"])
        assert message in capsys.readouterr().err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_the_hold_runs_on_cuda():
    hold = HoldFirst(grip=2)
    hold.observe(held_by(NEAR))
    positions = torch.zeros(4, 3, device="cuda", requires_grad=True)
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0], device="cuda").expand(4, 4)
    aim, turn = hold.aims(positions, quats, positions.new_ones(3), quats.new_tensor([0, 0, 0, 1]))
    assert aim.device.type == "cuda" and torch.equal(turn.cpu(), quats[0].cpu())
    (grad,) = torch.autograd.grad(aim.sum(), positions)
    assert torch.isfinite(grad).all()
    drawn = HoldFirst(grip=2, approach=4.0)
    drawn.observe(held_by(NEAR))
    weight = drawn.contact_weight(positions)
    assert weight.device.type == "cuda" and float(weight) == 4.0
