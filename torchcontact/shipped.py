"""The contact models that ship with the package: one per environment, each with a manifest.

``torchcontact run ENV`` plans with ``ENV``'s shipped model unless told otherwise (``--stiffness
paper`` takes the paper's constant K). A model is a :mod:`torchcontact.checkpoint` file,
``torchcontact/assets/models/ENV.pt``; its manifest ``ENV.json`` beside it records the command
that made it, the dataset, the library versions, the file's SHA-256 and the validation figures.
``torchcontact learn-k --scene ENV ... --ship`` writes both (README, "Learning"). A model is
checked against its manifest's SHA-256 before it is used (:func:`check_shipped`).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

from torchcontact.digests import file_sha256

SHIPPED = "shipped"
"""The value of a trial's ``learned`` field that names its environment's shipped model."""


def models_dir() -> Path:
    """The installed package's folder of shipped models."""
    from importlib.resources import files

    return Path(str(files("torchcontact.assets") / "models"))


def shipped_environments() -> tuple[str, ...]:
    """The environments that ship a model, sorted."""
    return tuple(sorted(path.stem for path in models_dir().glob("*.pt")))


def shipped_path(env: str) -> Path:
    """The checkpoint shipped for environment ``env``; ``ValueError`` naming those that exist
    when there is none."""
    path = models_dir() / f"{env}.pt"
    if not path.is_file():
        raise ValueError(
            f"env {env!r} ships no model; the environments that do: {shipped_environments()}"
        )
    return path


def shipped_manifest(env: str) -> dict:
    """The manifest of ``env``'s shipped model (see the module's docstring)."""
    return json.loads(shipped_path(env).with_suffix(".json").read_text())


def check_shipped(path: str | Path) -> Path:
    """Check that the shipped model at ``path`` is the file its manifest (``path`` with the
    suffix ``.json``) records: ``ValueError`` in one line when its SHA-256 differs or the
    manifest is missing or records none."""
    path = Path(path)
    stat = path.stat()
    _check_digest(str(path), stat.st_size, stat.st_mtime_ns)
    return path


@functools.lru_cache(maxsize=16)
def _check_digest(path: str, size: int, mtime_ns: int) -> None:
    """:func:`check_shipped` of the file at ``path`` as it is at ``size`` and ``mtime_ns``."""
    manifest = Path(path).with_suffix(".json")
    try:
        expected = json.loads(manifest.read_text()).get("sha256")
    except (OSError, ValueError, AttributeError):
        expected = None
    if not isinstance(expected, str):
        raise ValueError(f"shipped model {path}: its manifest {manifest.name} records no SHA-256")
    digest = file_sha256(path)
    if digest != expected:
        raise ValueError(
            f"shipped model {path}: its SHA-256 {digest[:12]}… differs from its manifest's "
            f"{expected[:12]}…, so it is not the model the manifest describes: reinstall "
            "torchcontact, or ship a model with learn-k --ship"
        )


def resolve_learned(learned: str | Path | None, env: str) -> str | None:
    """A trial's ``learned`` as a file path: :data:`SHIPPED` ↦ ``env``'s shipped model,
    checked against its manifest (:func:`check_shipped`); a path ↦ itself, as a string; None
    ↦ None. ``ValueError`` naming ``learned`` when it is neither :data:`SHIPPED` nor the path
    of an existing file (``TypeError`` when it is no string or path)."""
    if learned is None:
        return None
    if learned == SHIPPED:
        return str(check_shipped(shipped_path(env)))
    if not isinstance(learned, (str, Path)):
        raise TypeError(
            f"learned must be {SHIPPED!r} or a checkpoint's path, got {type(learned).__name__}"
        )
    if not Path(learned).is_file():
        raise ValueError(
            f"learned (--learned) must be {SHIPPED!r} ({env}'s shipped model) or the path of an "
            "existing checkpoint file (the model.pt of learn-k or save_model), got "
            f"{str(learned)!r}"
        )
    return str(learned)
