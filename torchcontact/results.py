"""Result files written atomically: a crash never leaves a half-written JSON, CSV or PNG.

A folder that one process fills (a sweep's ``--out``) is held with :func:`locked_folder`, so a
second process writing there is refused instead of overwriting the first one's records.
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import io
import json
import math
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

LOCK_FILE = ".lock"
"""The file in a folder that :func:`locked_folder` holds (it stays; the lock goes with the
process that held it, however that process ends)."""

_HELD: dict[Path, int] = {}  # folders this process holds, with how many holders nest


class FolderInUse(ValueError):
    """Another process holds the folder a run would write to."""


@contextlib.contextmanager
def locked_folder(folder: str | Path, option: str = "out") -> Iterator[Path]:
    """Hold an exclusive lock on ``folder`` (created) for the ``with`` block: a second process
    asking for it meanwhile gets :class:`FolderInUse` naming ``option`` and the holder's
    process id, at once. Nested holds in one process share the lock."""
    folder = Path(folder)
    key = folder.resolve()
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield folder
        finally:
            _HELD[key] -= 1
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle = open(folder / LOCK_FILE, "a+")
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise ValueError(
            f"{option} {str(folder)!r} cannot be locked for this run ({reason})"
        ) from None
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            raise FolderInUse(
                f"{option} {str(folder)!r} is in use by another run (process {holder}): wait "
                "for it to finish or write to another folder"
            ) from None
        handle.truncate(0)
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        _HELD[key] = 1
        try:
            yield folder
        finally:
            del _HELD[key]
    finally:
        handle.close()  # releases the lock


def _nearest_existing(option: str, path: Path) -> Path:
    """The deepest existing folder on the way to ``path``; ``ValueError`` if it is a file."""
    parent = path.absolute()
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{option} must lie in a directory, but {str(parent)!r} is a file")
    return parent


def writable_directory(option: str, path: Path, create: bool = True) -> Path:
    """Check that files can be written in the folder ``path`` by creating it and a probe file
    in it (``create`` False: the folders it made are removed again): ``ValueError`` naming
    ``option`` otherwise. Permissions are not asked (``os.access``), since as root they are
    always granted where writing still fails."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option} must be a directory, got the file {str(path)!r}")
    existing = _nearest_existing(option, path)
    chain = [path.absolute(), *path.absolute().parents]
    made = [] if create else chain[: chain.index(existing)]  # the folders this probe makes
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise ValueError(
            f"{option} must be a writable directory, got {str(path)!r} ({reason})"
        ) from None
    finally:
        for folder in made:  # deepest first
            with contextlib.suppress(OSError):
                folder.rmdir()
    return path


def _temporary(path: Path) -> tuple[int, str]:
    """A new temporary file beside ``path`` (the one :func:`atomic_write` renames onto it)."""
    return tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")


def writable_file(option: str, path: str | Path) -> Path:
    """Check that :func:`atomic_write` can write ``path``, by creating and removing the
    temporary file it would write there (and the missing folders on the way, removed again):
    ``ValueError`` naming ``option`` and the reason otherwise."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{option} must be a file path, got the directory {str(path)!r}")
    missing = []
    parent = path.absolute().parent
    while not parent.exists():
        missing.append(parent)
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{option} must lie in a directory, but {str(parent)!r} is a file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, tmp = _temporary(path)
        os.close(handle)
        os.unlink(tmp)
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise ValueError(
            f"{option} must be a writable file path, got {str(path)!r} ({reason})"
        ) from None
    finally:
        for folder in missing:  # deepest first
            with contextlib.suppress(OSError):
                folder.rmdir()
    return path


def atomic_write(
    path: str | Path, write: Callable[[io.IOBase], None], binary: bool = False
) -> Path:
    """Call ``write(file)`` on a temporary file beside ``path``, then rename it onto ``path``."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:  # name the file, not the first folder that could not be made
        raise type(error)(error.errno, f"cannot write {path}: {error.strerror}") from None
    handle, tmp = _temporary(path)
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
        try:
            return json.load(f)
        except json.JSONDecodeError as error:
            message = f"{path} must hold JSON: {error.msg}"  # still a JSONDecodeError
            raise json.JSONDecodeError(message, error.doc, error.pos) from None


def write_csv(path: str | Path, rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write dict rows as CSV; the header is the union of keys in first-seen order."""
    rows = list(rows)
    for row in rows:
        if not isinstance(row, Mapping):
            raise TypeError(f"rows must be mappings of column to value, got {type(row).__name__}")
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
