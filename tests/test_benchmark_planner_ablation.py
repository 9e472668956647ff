"""benchmarks/planner_ablation.py: one row per variant from the same trials, resumable."""

from __future__ import annotations

import json

from benchmarks import planner_ablation


def test_each_variant_gets_a_row_from_its_own_trials(tmp_path, capsys):
    argv = ["fingertips", "--task", "rotation", "--object", "cube", "--max-steps", "4",
            "--no-compile", "--variants", "lbfgs", "hybrid",
            "--out", str(tmp_path)]  # fmt: skip
    assert planner_ablation.main(argv) == 0
    rows = json.loads((tmp_path / "ablation.json").read_text())["rows"]
    assert [row["variant"] for row in rows] == ["lbfgs", "hybrid"]
    assert all(row["trials"] == 1 for row in rows)
    records = [json.loads(p.read_text()) for p in sorted(tmp_path.glob("*/trials/*.json"))]
    assert [r["planner"] for r in records] == ["hybrid", "lbfgs"]  # by folder name
    assert records[0]["initial_pose"] == records[1]["initial_pose"]  # the same trial
    planner_ablation.main(argv)  # a rerun reuses the records and prints the same table
    assert capsys.readouterr().out.count("hybrid") >= 2
