"""The studies' shared reporting: tables, JSON/CSV/text files, figures and the command line."""

import json
import math

import pytest

from studies import report


def test_text_table_aligns_labels_left_and_numbers_right():
    text = report.format_table(["run", "ms"], [["cf", "0.25"], ["qp eps", "14.5"]], left=1)
    assert text.splitlines() == ["run       ms", "cf      0.25", "qp eps  14.5"]
    assert report.format_table(["N"], [["10"]]).splitlines() == [" N", "10"]


def test_markdown_table():
    text = report.markdown_table(["a", "b"], [["1", "2"]])
    assert text.splitlines() == ["| a | b |", "|---|---|", "| 1 | 2 |"]


def test_json_ready_replaces_non_finite_numbers_at_any_depth():
    value = {"a": math.inf, "b": [1.0, math.nan, (2, -math.inf)], "c": "x"}
    assert report.json_ready(value) == {"a": None, "b": [1.0, None, [2, None]], "c": "x"}


def test_files_are_written_atomically(tmp_path):
    report.write_json(tmp_path / "a" / "x.json", {"v": math.nan, "w": 1})
    assert json.loads((tmp_path / "a" / "x.json").read_text()) == {"v": None, "w": 1}
    report.write_csv(tmp_path / "x.csv", [{"a": 1}, {"a": 2, "b": 3}])
    assert (tmp_path / "x.csv").read_text().splitlines() == ["a,b", "1,", "2,3"]
    report.write_text(tmp_path / "x.md", "# title\n")
    assert (tmp_path / "x.md").read_text() == "# title\n"
    fig, axes = report.figure(1, 2, size=(4, 2))
    axes[0].plot([0, 1], [1, 0])
    report.save_figure(fig, tmp_path / "x.png", dpi=50)
    assert (tmp_path / "x.png").read_bytes()[:4] == b"\x89PNG"
    assert not list(tmp_path.rglob(".*.tmp"))


def test_written_goes_to_stderr(capsys):
    report.written(["a.json", "b.csv"])
    captured = capsys.readouterr()
    assert (captured.out, captured.err) == ("", "wrote a.json, b.csv\n")


def test_parser_has_out_and_no_progress_and_positive_types(capsys):
    parser = report.parser("study", "A study.", "results/study")
    parser.add_argument("--n", type=report.positive_int, default=1)
    parser.add_argument("--x", type=report.positive_float, default=1.0)
    args = parser.parse_args(["--n", "3", "--x", "0.5", "--no-progress"])
    assert (str(args.out), args.no_progress, args.n, args.x) == ("results/study", True, 3, 0.5)
    for argv, message in (
        (["--n", "0"], "expected a positive integer"),
        (["--x", "nan"], "expected a positive number"),
    ):
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
        assert message in capsys.readouterr().err


def test_run_main_exits_with_the_status(monkeypatch):
    monkeypatch.setattr("sys.argv", ["study", "--flag"])
    seen = []
    with pytest.raises(SystemExit) as exit_info:
        report.run_main(lambda argv: seen.append(argv) or 3)
    assert exit_info.value.code == 3 and seen == [["--flag"]]
