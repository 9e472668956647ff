"""The contact models that ship with the package: one per environment, each with a manifest.

``torchcontact run ENV`` plans with ``ENV``'s shipped model unless told otherwise (``--stiffness
paper`` takes the paper's constant K). A model is a :mod:`torchcontact.checkpoint` file,
``torchcontact/assets/models/ENV.pt``; its manifest ``ENV.json`` beside it records the command
that made it, the dataset, the library versions, the file's SHA-256 and the validation figures.
``torchcontact learn-k --scene ENV ... --ship`` writes both (README, "Learning").
"""

from __future__ import annotations

import json
from pathlib import Path

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


def resolve_learned(learned: str | None, env: str) -> str | None:
    """A trial's ``learned`` as a file path: :data:`SHIPPED` ↦ ``env``'s shipped model."""
    return str(shipped_path(env)) if learned == SHIPPED else learned
