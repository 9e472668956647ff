"""benchmarks/momentum_rollout.py: both variants replay the same recorded states."""

from __future__ import annotations

import json

from benchmarks import momentum_rollout


def test_both_variants_replay_the_recorded_states(tmp_path, capsys):
    argv = ["--object", "cube", "--steps", "2", "--rounds", "1", "--no-compile",
            "--out", str(tmp_path)]  # fmt: skip
    assert momentum_rollout.main(argv) == 0
    rows = json.loads((tmp_path / "momentum_rollout.json").read_text())["rows"]
    assert [row["variant"] for row in rows] == ["momentum", "no momentum"]
    assert rows[1]["ratio_to_no_momentum"] == 1.0
    assert all(row["solve_ms_median"] > 0 and row["evaluations_median"] >= 1 for row in rows)
    assert "no momentum" in capsys.readouterr().out
