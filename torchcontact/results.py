"""Result files written atomically: a crash never leaves a half-written JSON, CSV or PNG."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any


def atomic_write(
    path: str | Path, write: Callable[[io.IOBase], None], binary: bool = False
) -> Path:
    """Call ``write(file)`` on a temporary file beside ``path``, then rename it onto ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb" if binary else "w", **({} if binary else {"newline": ""})) as f:
            write(f)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; results are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def json_safe(data: Any) -> Any:
    """``data`` with every non-finite float (NaN, ±inf; Python, NumPy or in arrays) replaced by
    None, recursively through dicts, lists and tuples; NumPy scalars and arrays (anything with
    ``tolist``) become Python numbers and lists."""
    if isinstance(data, Mapping):
        return {key: json_safe(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [json_safe(value) for value in data]
    if isinstance(data, (str, bool, int)) or data is None:
        return data
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if hasattr(data, "tolist"):
        return json_safe(data.tolist())
    return data


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented, strict JSON: non-finite floats become ``null`` (see
    :func:`json_safe`), so the file holds no ``NaN``/``Infinity`` literal; a value that still
    is one raises ``ValueError`` before anything is written. Paths are written as strings."""

    def default(x):
        if hasattr(x, "tolist"):
            return json_safe(x.tolist())
        if isinstance(x, os.PathLike):
            return os.fspath(x)
        raise TypeError(f"cannot write {type(x).__name__} to JSON ({path})")

    text = json.dumps(json_safe(data), indent=2, default=default, allow_nan=False)
    return atomic_write(path, lambda f: f.write(text))


def read_json(path: str | Path) -> Any:
    """Read a JSON file written by :func:`write_json`."""
    with open(path) as f:
        return json.load(f)


def write_csv(path: str | Path, rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write dict rows as CSV; the header is the union of keys in first-seen order."""
    rows = list(rows)
    columns = list(dict.fromkeys(key for row in rows for key in row))

    def write(f):
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)

    return atomic_write(path, write)


def save_figure(figure, path: str | Path, dpi: int = 120) -> Path:
    """Save a matplotlib figure as PNG atomically."""
    return atomic_write(path, lambda f: figure.savefig(f, format="png", dpi=dpi), binary=True)


def pareto_front(points: Sequence[Sequence[float]]) -> list[int]:
    """Indices of the points (tuples of objectives, all minimized) that no other point
    dominates, in increasing order of the points. A point is dominated by one no worse in every
    objective and better in one; points with a NaN are never on the front; equal points are all
    kept."""
    finite = [i for i, p in enumerate(points) if all(math.isfinite(x) for x in p)]

    def dominates(a, b) -> bool:
        return all(x <= y for x, y in zip(a, b, strict=True)) and tuple(a) != tuple(b)

    front = [i for i in finite if not any(dominates(points[j], points[i]) for j in finite)]
    return sorted(front, key=lambda i: tuple(points[i]))
