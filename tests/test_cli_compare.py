"""Two runs' trial records compared trial by trial: pairing, won and lost, the McNemar test, and
the ``torchcontact compare`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import binomtest

from torchcontact.cli import main as cli_main
from torchcontact.cli.compare import compare_runs, load_run, mcnemar_p
from torchcontact.environments.presets import MPCSettings
from torchcontact.mpc.trial_config import trial_configs
from torchcontact.mpc.trials import run_trials
from torchcontact.results import write_json

FAST = trial_configs(
    "fingertips", [("rotation", "cube")], range(1), MPCSettings(max_iter=5, compile=False),
    max_steps=2,
)  # fmt: skip


@pytest.fixture(scope="module")
def record() -> dict:
    """The JSON of a real two-step fingertip trial, run once, writing nothing."""
    (result,) = run_trials(FAST, progress=False)
    return json.loads(json.dumps(result.to_dict()))


def _write_run(folder, record: dict, outcomes: dict[int, tuple[bool, float, float]]):
    """A run folder of ``record`` at each seed of ``outcomes``: (success, mm, degrees)."""
    for seed, (success, mm, degrees) in outcomes.items():
        trial = {**record, "seed": seed, "success": success}
        trial.update(pos_err_mm=mm, angle_err_deg=degrees)
        write_json(folder / "trials" / f"trial_seed{seed}.json", trial)
    return folder


@pytest.mark.parametrize("won, lost", [(0, 0), (5, 0), (10, 8), (21, 10), (3, 17)])
def test_mcnemar_is_the_exact_two_sided_binomial_test_of_the_discordant_trials(won, lost):
    expected = 1.0 if won + lost == 0 else binomtest(won, won + lost, 0.5).pvalue
    assert mcnemar_p(won, lost) == pytest.approx(expected, rel=1e-12)
    assert mcnemar_p(won, lost) == mcnemar_p(lost, won)


@pytest.mark.parametrize("bad", [-1, 1.5, True, None])
def test_mcnemar_refuses_counts_that_are_not_non_negative_integers(bad):
    with pytest.raises(ValueError, match="won must be a non-negative integer"):
        mcnemar_p(bad, 3)


def test_two_runs_are_compared_on_the_trials_both_hold(tmp_path, record):
    a = _write_run(tmp_path / "a", record, {s: (s != 2, 10.0, 5.0) for s in range(4)})
    outcomes = {1: (False, 30.0, 9.0), 2: (True, 4.0, 1.0), 3: (True, 2.0, 2.0)}
    b = _write_run(tmp_path / "b", record, {**outcomes, 4: (True, 0.0, 0.0)})
    comparison = compare_runs(a, b)
    key = (record["env"], record["task"], record["object"])
    assert comparison.common == 3 and comparison.only_a == 1 and comparison.only_b == 1
    assert comparison.successes == (2, 2)
    assert comparison.won == [(*key, 2)] and comparison.lost == [(*key, 1)]
    assert comparison.pos_err_mm == (10.0, pytest.approx(np.mean([30.0, 4.0, 2.0])))
    assert comparison.angle_err_deg == (5.0, 4.0)
    assert comparison.p_value == 1.0
    assert "B won 1, lost 1" in comparison.summary()
    assert comparison.tipped == (0, 0) and "4.0°, tipped 0" in comparison.summary()


def test_a_comparison_counts_the_objects_that_ended_tipped_over(tmp_path, record):
    a = _write_run(tmp_path / "a", record, {s: (False, 10.0, 90.0) for s in range(2)})
    b = _write_run(tmp_path / "b", record, {s: (False, 10.0, 90.0) for s in range(2)})
    lying = [*record["target_pose"][:3], *_on_its_side(record["target_pose"][3:])]
    trial = json.loads((b / "trials" / "trial_seed1.json").read_text())
    write_json(b / "trials" / "trial_seed1.json", {**trial, "final_pose": lying})
    comparison = compare_runs(a, b)
    assert comparison.tipped == (0, 1) and "90.0°, tipped 1" in comparison.summary()


def _on_its_side(quat) -> list[float]:
    """``quat`` (w, x, y, z) turned 90° about the world's x axis."""
    w, x, y, z = quat
    c = s = np.sqrt(0.5)  # (c, s, 0, 0) ⊗ quat
    return [c * w - s * x, c * x + s * w, c * y - s * z, c * z + s * y]


def test_a_run_leaves_out_set_aside_records_and_refuses_what_it_cannot_pair(tmp_path, record):
    run = _write_run(tmp_path / "run", record, {0: (True, 1.0, 1.0)})
    (run / "trials" / "trial_seed0.stale-1.json").write_text("{}")  # set aside: not a trial
    write_json(run / "trials" / "my.part-mesh_seed1.json", {**record, "seed": 1})  # a dotted stem
    key = (record["env"], record["task"], record["object"])
    assert list(load_run(run)) == [(*key, 1), (*key, 0)]
    assert list(load_run(run / "trials")) == list(load_run(run))
    write_json(run / "trials" / "copy.json", {**record, "seed": 0})
    with pytest.raises(ValueError, match="are the same trial"):
        load_run(run)
    (run / "trials" / "copy.json").write_text('{"success": true')
    with pytest.raises(ValueError, match="copy.json is not a trial record"):
        load_run(run)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no trial records"):
        load_run(tmp_path / "empty")
    with pytest.raises(ValueError, match="run must be a folder of trial records"):
        load_run(tmp_path / "missing")
    other = _write_run(tmp_path / "other", record, {7: (True, 1.0, 1.0)})
    with pytest.raises(ValueError, match="share no trial"):
        compare_runs(_write_run(tmp_path / "a", record, {0: (True, 1.0, 1.0)}), other)


def test_the_compare_command_prints_and_writes_the_comparison(tmp_path, record, capsys):
    a = _write_run(tmp_path / "a", record, {s: (False, 9.0, 9.0) for s in range(6)})
    b = _write_run(tmp_path / "b", record, {s: (True, 1.0, 1.0) for s in range(6)})
    out = tmp_path / "out" / "comparison.json"
    assert cli_main(["compare", str(a), str(b), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "B won 6, lost 0: McNemar p = 0.0312" in printed
    saved = json.loads(out.read_text())
    assert saved["successes"] == [0, 6] and saved["p_value"] == pytest.approx(2 / 64)
    with pytest.raises(SystemExit) as stop:
        cli_main(["compare", str(a), str(tmp_path / "missing")])
    assert stop.value.code == 2
    assert "torchcontact compare: error: run must be a folder" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["compare", str(a), str(b), "--json", str(tmp_path)])  # a folder: refused
    assert "error: --json must be a file path" in capsys.readouterr().err
