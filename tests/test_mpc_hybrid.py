"""The hybrid planner: seeded sampling, multi-start L-BFGS, never worse than plain L-BFGS."""

import json

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchcontact.cli import main
from torchcontact.environments import environment
from torchcontact.environments.presets import MPCSettings
from torchcontact.mpc.controller import ContactImplicitMPC
from torchcontact.mpc.planners import LBFGS, Hybrid, Objective, planner
from torchcontact.mpc.trial_config import trial_configs

F64 = torch.float64


def double_well(x, tilt):
    """Σ (x² − 1)² + tilt·x per row: two basins per variable, the one at −1 lower for tilt > 0."""
    x = x.detach().requires_grad_(True)
    with torch.enable_grad():
        f = ((x.square() - 1).square() + tilt * x).sum(-1)
        (grad,) = torch.autograd.grad(f.sum(), x)
    return f.detach(), grad


def _box(n, half=2.0, problems=1):
    return (torch.full((problems, n), -half, dtype=F64), torch.full((problems, n), half, dtype=F64))


TILT = torch.tensor(0.2, dtype=F64)


def test_hybrid_is_registered_and_escapes_the_warm_start_basin():
    """From a start in the upper basin L-BFGS stays there; the hybrid finds the lower one."""
    solver = planner("hybrid", max_iter=30, memory=5, compile=False)
    assert isinstance(solver, Hybrid)
    x0 = torch.full((1, 2), 0.9, dtype=F64)
    plain = LBFGS(30, 5).plan(Objective(double_well), x0, _box(2), args=(TILT,))
    hybrid = solver.plan(Objective(double_well), x0, _box(2), args=(TILT,))
    assert bool((plain.x > 0).all()) and bool((hybrid.x < 0).all())
    assert float(hybrid.f) < float(plain.f) - 0.5


def test_the_sampling_is_deterministic_under_its_seed():
    x0 = torch.full((1, 6), 0.3, dtype=F64)
    plans = [
        Hybrid(seed=seed).plan(Objective(double_well), x0, _box(6), args=(TILT,))
        for seed in (7, 7, 8)
    ]
    assert torch.equal(plans[0].x, plans[1].x) and torch.equal(plans[0].f, plans[1].f)
    starts = [Hybrid(seed=s)._sample(Objective(double_well), x0, *_box(6), (TILT,)) for s in (7, 8)]
    assert not torch.equal(starts[0][0], starts[1][0])


@settings(max_examples=25, deadline=None)
@given(
    start=st.lists(st.floats(-3.0, 3.0), min_size=5, max_size=5),
    tilt=st.floats(-0.5, 0.5),
    seed=st.integers(0, 2**31 - 1),
)
def test_never_costlier_than_plain_lbfgs_and_always_in_the_box(start, tilt, seed):
    """Whatever the warm start (even outside the box), the tilt and the seed: the hybrid's plan
    lies in the box and costs no more than plain L-BFGS's from the same warm start."""
    x0 = torch.tensor([start], dtype=F64)
    box = (
        torch.tensor([[-1.5, -2.0, -0.5, -1.0, 0.0]], dtype=F64),
        torch.full((1, 5), 1.2, dtype=F64),
    )
    args = (torch.tensor(tilt, dtype=F64),)
    plain = LBFGS(20, 5).plan(Objective(double_well), x0, box, args)
    hybrid = Hybrid(20, 5, samples=16, seed=seed).plan(Objective(double_well), x0, box, args)
    assert bool(((hybrid.x >= box[0]) & (hybrid.x <= box[1])).all())
    assert float(hybrid.f) <= float(plain.f) + 1e-12 * max(1.0, abs(float(plain.f)))


def test_problems_of_a_batch_are_planned_on_their_own():
    x0 = torch.tensor([[0.9, 0.9], [-0.2, 0.4]], dtype=F64)
    together = Hybrid(seed=3).plan(Objective(double_well), x0, _box(2, problems=2), (TILT,))
    for b in range(2):
        alone = Hybrid(seed=3).plan(Objective(double_well), x0[b : b + 1], _box(2), (TILT,))
        torch.testing.assert_close(together.f[b : b + 1], alone.f, rtol=0, atol=1e-10)


@pytest.mark.parametrize(
    "options, message",
    [
        ({"samples": 1}, "samples must be an integer ≥ 2"),
        ({"rounds": -1}, "rounds must be an integer ≥ 0"),
        ({"elites": 40}, "elites must be an integer in"),
        ({"starts": 0}, "starts must be a positive integer"),
        ({"spread": 0.0}, "spread must be positive"),
    ],
)
def test_bad_settings_are_refused_by_name(options, message):
    with pytest.raises(ValueError, match=message):
        Hybrid(**options)


def test_a_short_closed_loop_run_with_the_hybrid(tmp_path):
    """The CLI's fingertips rotation, 12 steps planned by the hybrid: a finite record of it."""
    main(["run", "fingertips", "--task", "rotation", "--object", "cube", "--trials", "1",
          "--max-steps", "12", "--max-iter", "5", "--no-compile", "--no-progress",
          "--planner", "hybrid", "--out", str(tmp_path)])  # fmt: skip
    (path,) = (tmp_path / "trials").glob("*.json")
    record = json.loads(path.read_text())
    assert record["planner"] == "hybrid" and record["steps"] == 12
    assert record["pos_err_mm"] < 1e3 and len(record["solve_ms"]) == 12


def test_the_sampling_asks_for_values_only_where_the_objective_offers_them():
    """A sampling round needs no gradient: with ``value`` given, only the L-BFGS stage calls
    ``value_and_grad``, once per round for the starts of one batched solve."""
    calls = {"value": 0, "value_and_grad": 0}

    def value(x, tilt):
        calls["value"] += 1
        return double_well(x, tilt)[0]

    def value_and_grad(x, tilt):
        calls["value_and_grad"] += 1
        return double_well(x, tilt)

    x0 = torch.full((1, 3), 0.4, dtype=F64)
    objective = Objective(value_and_grad, value=value)
    with_values = Hybrid(10, 5, rounds=3, seed=1).plan(objective, x0, _box(3), (TILT,))
    without = Hybrid(10, 5, rounds=3, seed=1).plan(Objective(double_well), x0, _box(3), (TILT,))
    assert calls["value"] == 3 and calls["value_and_grad"] == with_values.iterations + 1
    torch.testing.assert_close(with_values.x, without.x, rtol=0, atol=1e-12)
    torch.testing.assert_close(objective.values(x0, TILT), double_well(x0, TILT)[0])


def test_without_sampling_the_hybrid_starts_from_the_warm_start_and_zero():
    """No sampling rounds: L-BFGS from the warm start and from zero, no samples evaluated."""
    solver = Hybrid(30, 5, rounds=0, starts=2)
    x0 = torch.full((1, 4), 0.9, dtype=F64)
    plan = solver.plan(Objective(double_well), x0, _box(4), args=(TILT,))
    plain = LBFGS(30, 5).plan(Objective(double_well), x0, _box(4), args=(TILT,))
    assert float(plan.f) < float(plain.f) - 1.0  # zero's descent finds the lower basin
    starts = torch.cat([x0, torch.zeros_like(x0)])
    both = LBFGS(30, 5).plan(Objective(double_well), starts, _box(4, problems=2), (TILT,))
    assert plan.evaluations == both.evaluations  # L-BFGS's points only


def test_an_environments_default_planner_is_what_its_mpc_and_trials_use(monkeypatch):
    env = environment("fingertips")
    assert env.planner == "lbfgs"
    monkeypatch.setattr(env, "planner", "hybrid")
    mpc = ContactImplicitMPC.from_env(
        env, env.make_plant("cube"), settings=MPCSettings(compile=False)
    )
    assert isinstance(mpc.planner, Hybrid)
    (config,) = trial_configs("fingertips", [("rotation", "cube")], [0])
    assert config.planner == "hybrid"
    (chosen,) = trial_configs("fingertips", [("rotation", "cube")], [0], planner="lbfgs")
    assert chosen.planner == "lbfgs"


def test_the_cli_takes_the_environments_planner_unless_told():
    from torchcontact.cli.run import parse_args

    assert parse_args(["allegro"]).planner == environment("allegro").planner == "lbfgs"
    assert parse_args(["allegro", "--planner", "hybrid"]).planner == "hybrid"
