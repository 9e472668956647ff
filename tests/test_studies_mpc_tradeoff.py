"""The MPC-level trade-off benchmark: its Pareto front, report and a tiny end-to-end sweep."""

import json
import math

import pytest

from studies import mpc_tradeoff as tradeoff
from torchcontact.environments.presets import PAPER
from torchcontact.results import pareto_front

EAGER = PAPER.label.replace("compiled", "eager")


def test_pareto_front_with_three_objectives():
    points = [(1, 0.5, 10), (2, 0.5, 10), (2, 0.1, 10), (3, 0.1, 5), (3, 0.1, 5), (1, 0.9, 1)]
    points += [(math.nan, 0.0, 0.0)]
    # (2, .5, 10) is beaten by (1, .5, 10); equal points both stay; NaNs never count.
    assert pareto_front(points) == [0, 5, 2, 3, 4]


def _row(env, label, ms, success, angle):
    return {
        "env": env,
        "label": label,
        "preset": "",
        "success_rate": success,
        "pos_err_mm_mean": 5.0,
        "angle_err_deg_mean": angle,
        "solve_ms_median": ms,
        "solve_ms_p90": 2 * ms,
    }


def test_the_front_is_per_environment_and_the_report_names_the_presets():
    rows = [
        _row("fingertips", "a", 5.0, 0.9, 10.0),
        _row("fingertips", "b", 8.0, 0.8, 12.0),  # slower, worse: dominated
        _row("trifinger", "b", 8.0, 0.8, 12.0),  # alone in its environment: on its front
    ]
    tradeoff.mark_front(rows)
    assert [r["on_front"] for r in rows] == [True, False, True]
    report = tradeoff.markdown(rows, trials=10)
    assert "| **a** |" in report and "| b |" in report and "| **b** |" in report
    assert "`balanced`: not measured" in report


def test_a_tiny_sweep_runs_collects_and_writes_every_output(tmp_path, capsys):
    out = tmp_path / "mpc"
    argv = ["--env", "fingertips", "--settings", EAGER, "--trials", "1", "--max-steps", "3"]
    assert tradeoff.main([*argv, "--out", str(out), "--no-progress"]) == 0
    data = json.loads((out / "mpc_tradeoff.json").read_text())
    (row,) = data["rows"]
    assert row["label"] == EAGER and row["trials"] == 2 and row["on_front"]
    assert row["compile"] is False and row["solve_ms_median"] > 0
    assert (out / "mpc_pareto_fingertips.png").stat().st_size > 0
    assert "| **" + EAGER + "** |" in (out / "mpc_tradeoff.md").read_text()
    record = next((out / "fingertips").rglob("*_seed0.json"))
    stale = json.loads(record.read_text())
    record.write_text(json.dumps({**stale, "memory": stale["memory"] + 1}))
    with pytest.raises(ValueError, match="other settings"):
        tradeoff.collect(out, ["fingertips"], [EAGER], trials=1)
    record.unlink()
    with pytest.raises(FileNotFoundError, match="run the sweep"):
        tradeoff.collect(out, ["fingertips"], [EAGER], trials=1)


def test_unknown_settings_are_refused(capsys):
    with pytest.raises(SystemExit):
        tradeoff.main(["--settings", "it1000"])
    assert "--settings" in capsys.readouterr().err
