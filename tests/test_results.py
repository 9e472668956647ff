"""Result files: strict JSON (no NaN/Infinity literals) written atomically."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from torchcontact.results import json_safe, read_json, write_json


def _strict(text: str):
    def refuse(constant):
        raise AssertionError(f"{constant} written")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_floats_are_written_as_null_at_any_depth(tmp_path):
    data = {
        "nan": float("nan"),
        "inf": [1.0, float("inf"), {"deep": -float("inf")}],
        "numpy": (np.float32("nan"), np.float64(2.5), np.int64(3)),
        "array": np.array([[1.0, np.nan], [np.inf, 4.0]]),
        "kept": {"flag": True, "none": None, "text": "NaN", "int": 7},
    }
    expected = {
        "nan": None,
        "inf": [1.0, None, {"deep": None}],
        "numpy": [None, 2.5, 3],
        "array": [[1.0, None], [None, 4.0]],
        "kept": {"flag": True, "none": None, "text": "NaN", "int": 7},
    }
    path = write_json(tmp_path / "out.json", data)
    assert _strict(path.read_text()) == read_json(path) == expected  # no NaN/Infinity literal
    assert json_safe(data)["numpy"] == [None, 2.5, 3]


def test_a_value_json_cannot_write_raises_naming_the_file_and_writes_nothing(tmp_path):
    with pytest.raises(TypeError, match="cannot write object to JSON.*bad.json"):
        write_json(tmp_path / "bad.json", {"x": object()})
    assert list(tmp_path.iterdir()) == []


def test_paths_are_written_as_their_strings(tmp_path):
    path = write_json(tmp_path / "out.json", {"out": tmp_path / "run", "all": [Path("a/b")]})
    assert read_json(path) == {"out": str(tmp_path / "run"), "all": ["a/b"]}
