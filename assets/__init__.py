"""Robot models written for this project (MJCF), installed as ``torchcontact.assets``."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def asset_path(name: str) -> Path:
    """Path of the bundled asset file ``name`` (e.g. ``"trifinger.xml"``)."""
    path = Path(str(files(__name__) / name))
    if not path.is_file():
        available = sorted(p.name for p in path.parent.glob("*.xml"))
        raise ValueError(f"name must be one of the bundled assets {available}, got {name!r}")
    return path
