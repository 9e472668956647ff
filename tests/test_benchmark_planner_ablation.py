"""benchmarks/planner_ablation.py: one row per variant from the same trials, resumable."""

from __future__ import annotations

import json

import pytest

from benchmarks import planner_ablation


def test_each_variant_gets_a_row_from_its_own_trials(tmp_path, capsys):
    argv = ["fingertips", "--task", "rotation", "--object", "cube", "--max-steps", "4",
            "--no-compile", "--variants", "lbfgs", "multistart",
            "--out", str(tmp_path)]  # fmt: skip
    assert planner_ablation.main(argv) == 0
    rows = json.loads((tmp_path / "ablation.json").read_text())["rows"]
    assert [row["variant"] for row in rows] == ["lbfgs", "multistart"]
    assert all(row["trials"] == 1 for row in rows)
    records = [json.loads(p.read_text()) for p in sorted(tmp_path.glob("*/trials/*.json"))]
    assert [r["planner"] for r in records] == ["lbfgs", "multistart"]
    assert records[0]["initial_pose"] == records[1]["initial_pose"]  # the same trial
    planner_ablation.main(argv)  # a rerun reuses the records and prints the same table
    assert capsys.readouterr().out.count("multistart") >= 2


def test_support_rows_are_refused_where_objects_rest_on_the_ground(tmp_path):
    with pytest.raises(SystemExit):
        planner_ablation.main(
            ["trifinger", "--object", "cube", "--variants", "lbfgs+support", "--out", str(tmp_path)]
        )
