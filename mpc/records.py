"""Reading and judging saved trial records: whether one is usable, how it differs from a trial's
identity, and so whether a run reuses it, sets it aside or refuses to run.

On resume, a record at a trial's path is reused when its identity equals the trial's; set aside
(renamed ``NAME.corrupt-<n>.json``, with a warning) and run again when it is not a readable record;
set aside (``NAME.stale-<n>.json``) and run again when it differs only in
:data:`~torchcontact.mpc.trial_config.RELEASE_FIELDS` (an older release of our scenes or of a
library); and any other difference refuses the whole run before a trial runs
(:class:`RecordMismatch`): a run never overwrites a record made with other settings or inputs. A
record without ``inputs`` (written before them) counts as made with the current inputs when it
names no file, and as one of an older release when it does.
"""

from __future__ import annotations

import json
import math
import re
import typing
from dataclasses import fields
from pathlib import Path

import numpy as np

from torchcontact.mpc.trial_config import (
    RECORD_PARTS,
    RELEASE_FIELDS,
    REMOVED_OPTIONS,
    TrialConfig,
    TrialRecord,
    config_from_flat,
    flat_config,
    record_key,
    stored_config,
    trial_inputs,
)
from torchcontact.results import read_json
from torchcontact.shipped import SHIPPED

FINITE_KEYS = (
    "pos_err_mm",
    "quat_err",
    "angle_err_deg",
    "initial_pose",
    "target_pose",
    "aim_pose",
    "final_pose",
)
"""Record values that must be finite: a record holding a non-finite one is never written and
counts as corrupt on reading."""


ERROR_KEYS = ("pos_err_mm", "quat_err", "angle_err_deg")
"""A record's final errors, which are never negative: a record holding one that is counts as
corrupt, as one with a NaN solve time or more steps than its ``max_steps`` does."""


class RecordMismatch(ValueError):
    """A saved record at a trial's path was made with other settings or inputs than the run's."""


def _json_kind(hint) -> str:
    """The :func:`_is` kind of a field annotated ``hint`` (``X | None``: ``"X?"``)."""
    args = typing.get_args(hint)
    optional = type(None) in args and typing.get_origin(hint) is not tuple
    if optional:
        (hint,) = [a for a in args if a is not type(None)]
    if typing.get_origin(hint) is tuple:
        kind = {float: "numbers", int: "ints", str: "strs"}[typing.get_args(hint)[0]]
    else:
        kind = {float: "number", int: "int", str: "str", bool: "bool"}[hint]
    return kind + ("?" if optional else "")


def _config_kinds() -> dict[str, str]:
    """The kind of each of :data:`~torchcontact.mpc.trial_config.RECORD_KEYS`, from the
    annotations of the fields it holds."""
    kinds = {}
    for name, hint in typing.get_type_hints(TrialConfig).items():
        if name not in RECORD_PARTS:
            kinds[name] = _json_kind(hint)
            continue
        cls, prefix = RECORD_PARTS[name]
        for field in fields(cls):  # a field whose record holds a narrower kind says so
            kind = field.metadata.get("record_kind")
            kinds[record_key(prefix, field.name)] = kind or _json_kind(
                typing.get_type_hints(cls)[field.name]
            )
    return kinds


_CONFIG_KINDS = _config_kinds()
_OUTCOME_KINDS = {
    **dict.fromkeys(("success", "fell"), "bool"),
    **dict.fromkeys(("steps", "contact_slots", "contacts_found_max"), "int"),
    "steps_with_dropped_contacts": "int",
    **dict.fromkeys(("pos_err_mm", "quat_err", "angle_err_deg", "contacts_found_mean"), "number"),
    **dict.fromkeys(("initial_pose", "target_pose", "aim_pose", "final_pose"), "pose"),
    **dict.fromkeys(("detect_ms", "solve_ms", "sim_ms"), "numbers"),
    "iterations": "ints",
    "eager_steps": "ints?",  # absent from records written before background compiles
    "start_penetration_mm": "number?",  # absent before scenes 10
}
_ITEM_KINDS = {"numbers": "number", "ints": "int", "strs": "str", "pose": "number"}


def _is(value, kind: str) -> bool:
    """Whether the JSON ``value`` is of ``kind`` (a key of the schemas above; ``?``: or None)."""
    if kind.endswith("?"):
        return value is None or _is(value, kind[:-1])
    if kind in _ITEM_KINDS:
        if not isinstance(value, (list, tuple)) or (kind == "pose" and len(value) != 7):
            return False
        return all(_is(item, _ITEM_KINDS[kind]) for item in value)
    if kind == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, {"bool": bool, "str": str}[kind])


def record_problem(record) -> str | None:
    """Why a record read from JSON is not a usable trial record (wrong shape, a missing key, a
    wrong type, a non-finite value of :data:`FINITE_KEYS`, an impossible value: a negative
    error or time, more steps than ``max_steps``; malformed ``inputs``); None if it is
    usable."""
    if not isinstance(record, dict):
        return f"a JSON {type(record).__name__}, not an object"
    stored = stored_config(record)
    for key, kind in (*_CONFIG_KINDS.items(), *_OUTCOME_KINDS.items()):
        value = stored[key] if key in stored else record.get(key)
        if not _is(value, kind):
            found = "missing" if key not in record else f"{value!r:.40}"
            return f"{key} must be {kind.replace('?', ' or null')}, got {found}"
    for key in FINITE_KEYS:
        if not all(math.isfinite(x) for x in np.ravel(record[key])):
            return f"{key} is not finite"
    counts = ("contact_slots", "contacts_found_mean", "contacts_found_max")
    for key in (*ERROR_KEYS, "detect_ms", "solve_ms", "sim_ms", "iterations", *counts):
        if not all(math.isfinite(x) and x >= 0 for x in np.ravel(record[key])):
            return f"{key} must be finite and >= 0"
    if not 1 <= record["steps"] <= stored["max_steps"]:
        return f"steps must lie in [1, max_steps = {stored['max_steps']}], got {record['steps']}"
    try:
        config_from_flat(stored)
    except ValueError as error:  # a part that refuses its values: an edited record
        return f"its configuration is refused: {error}"
    inputs = record.get("inputs")
    if inputs is not None and not (
        isinstance(inputs, dict) and all(_is(v, "str?") for v in inputs.values())
    ):
        return f"inputs must be an object of strings or nulls, got {inputs!r:.60}"
    return None


def read_record(path: Path) -> tuple[dict | None, str | None]:
    """``(record, None)`` for a usable record at ``path`` (see :func:`record_problem`),
    ``(None, why)`` for a corrupt one."""
    try:
        record = read_json(path)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        return None, f"not valid JSON: {error}"
    problem = record_problem(record)
    return (None, problem) if problem else (record, None)


def record_differences(record: dict, config: TrialConfig, inputs: dict) -> dict[str, tuple]:
    """Identity fields where the usable saved ``record`` differs from ``config`` and
    ``inputs``, as ``{field: (old, new)}`` (``inputs.KEY`` for an input; ``inputs`` when the
    record predates inputs)."""
    new = flat_config(config)
    stored = stored_config(record)
    differences = {key: (stored[key], new[key]) for key in new if stored[key] != new[key]}
    for key, off in REMOVED_OPTIONS.items():
        if record.get(key, off) != off:
            differences[key] = (record[key], "an option since removed")
    old = record.get("inputs")
    if old is None:  # written before inputs were recorded: no versions, no file hashes
        differences["inputs"] = ("not recorded", "versions and file hashes")
        return differences
    for key in dict.fromkeys([*old, *inputs]):
        if old.get(key) != inputs.get(key):
            differences[f"inputs.{key}"] = (old.get(key), inputs.get(key))
    return differences


def record_status(path: Path, config: TrialConfig, inputs: dict) -> tuple[str, object]:
    """What a run does with ``path`` for ``config`` with ``inputs``: ``("run", None)`` when
    absent, ``("reuse", record)``, ``("corrupt", why)``, ``("stale", differences)`` when it
    differs only in :data:`RELEASE_FIELDS`, ``("mismatch", differences)`` otherwise."""
    if not path.exists():
        return "run", None
    record, problem = read_record(path)
    if record is None:
        return "corrupt", problem
    differences = record_differences(record, config, inputs)
    if not differences:
        return "reuse", TrialRecord.from_dict(record)
    shipped = config.model_options.learned == SHIPPED  # the shipped model moves with releases
    release = RELEASE_FIELDS + (("inputs.learned_sha256",) if shipped else ())
    stale = all(key in release for key in differences)
    return ("stale" if stale else "mismatch"), differences


def finished_record(path: Path, config: TrialConfig, inputs: dict | None = None):
    """The saved :class:`TrialRecord` of ``config`` at ``path``; None if absent, corrupt or
    made with other settings or ``inputs`` (default :func:`trial_inputs` of ``config``)."""
    inputs = trial_inputs(config) if inputs is None else inputs
    status, found = record_status(Path(path), config, inputs)
    return found if status == "reuse" else None


SET_ASIDE_STEM = re.compile(r"\.[a-z]+-\d+$")
"""The end of the stem :func:`set_aside` gives a record (``NAME.corrupt-1``, ``NAME.stale-2``;
its labels are lowercase words); a mesh object's stem may hold other dots."""


def set_aside(path: Path, label: str) -> Path:
    """Rename ``path`` (``NAME.json``) to the first free ``NAME.LABEL-<n>.json`` (n ≥ 1,
    never overwriting a file, ``label`` matching :data:`SET_ASIDE_STEM`) and return the new
    path."""
    n = 1
    while (target := path.with_name(f"{path.stem}.{label}-{n}{path.suffix}")).exists():
        n += 1
    return path.rename(target)


def _shown(key: str, value) -> str:
    """A field's value in a message (a SHA-256 shortened to 12 hex digits)."""
    if isinstance(value, str) and key.endswith("sha256"):
        return f"{value[:12]}…"
    return repr(value)


def describe_differences(differences: dict[str, tuple]) -> str:
    """``"max_steps 5 → 6, inputs.object_sha256 '1a2b…' → '3c4d…'"``."""
    return ", ".join(
        f"{key} {_shown(key, old)} → {_shown(key, new)}" for key, (old, new) in differences.items()
    )
