"""What an input file is, by content: the SHA-256 of the file and of every file its loader reads.

A robot's MJCF may ``<include>`` other MJCF files and name mesh and height-field files; a
``.gltf`` mesh keeps its geometry in ``.bin`` buffers beside it. A result made from such a file
depends on all of them, so its identity (:func:`content_sha256`) covers them all: the files
:func:`loaded_files` finds the way MuJoCo and trimesh resolve them. Textures and materials,
which change no contact, are left out (a height field is geometry, whatever its format).
"""

from __future__ import annotations

import hashlib
import json
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from urllib.parse import unquote

MJCF_GEOMETRY = ("mesh", "hfield", "skin")
"""MJCF asset elements whose ``file`` is geometry, found under the compiler's ``meshdir``."""


def file_sha256(path: str | Path) -> str:
    """The SHA-256 hex digest (64 characters) of the content of the file at ``path``."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def loaded_files(path: str | Path) -> list[Path]:
    """The files besides ``path`` that loading it reads, in the order it names them: for an
    MJCF (``.xml``) its included files (recursively) and the geometry files of
    :data:`MJCF_GEOMETRY`; for a ``.gltf`` its external buffers; none for other files. Files
    named but missing, and files that do not parse, are left to the loader to report."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".xml":
        return _mjcf_files(path)
    if suffix == ".gltf":
        try:
            buffers = json.loads(path.read_text()).get("buffers") or []
        except (OSError, ValueError, AttributeError):
            return []
        uris = [b.get("uri") for b in buffers if isinstance(b, dict)]
        local = [unquote(uri) for uri in uris if isinstance(uri, str)]
        return [path.parent / uri for uri in local if not uri.startswith("data:")]
    return []


def _mjcf_files(path: Path) -> list[Path]:
    """The files the MJCF at ``path`` includes (recursively) and the geometry files they name,
    MuJoCo's way: paths relative to ``path``'s folder, geometry under the compiler's
    ``meshdir`` (else ``assetdir``) wherever the compiler element is."""
    root, trees, includes = path.parent, [], []
    pending, seen = [path], {path.resolve()}
    while pending:
        try:
            tree = ElementTree.parse(pending.pop(0))
        except (OSError, ElementTree.ParseError):
            continue
        trees.append(tree)
        for element in tree.iter("include"):
            file = root / element.get("file", "")
            if element.get("file") and file.resolve() not in seen:
                seen.add(file.resolve())
                includes.append(file)
                pending.append(file)
    meshdir = ""
    for tree in trees:
        for compiler in tree.iter("compiler"):
            meshdir = compiler.get("meshdir") or compiler.get("assetdir") or meshdir
    geometry = dict.fromkeys(
        root / meshdir / element.get("file")
        for tree in trees
        for element in tree.iter()
        if element.tag in MJCF_GEOMETRY and element.get("file")
    )
    return includes + [file for file in geometry if file.resolve() not in seen]


def content_sha256(path: str | Path, hashes: dict[str, str] | None = None) -> str:
    """The identity of the input at ``path``: its :func:`file_sha256` when loading it reads no
    other file, else the SHA-256 of its digest and of each of its :func:`loaded_files`' (name
    relative to ``path``'s folder, and digest; a missing one as ``missing``). ``hashes``
    (resolved path → file digest) caches the digests and is filled here."""
    hashes = {} if hashes is None else hashes

    def digest(file: Path) -> str:
        key = str(file.resolve())
        if key not in hashes:
            hashes[key] = file_sha256(key) if file.is_file() else "missing"
        return hashes[key]

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path must be an existing file, got {str(path)!r}")
    others = loaded_files(path)
    if not others:
        return digest(path)
    combined = hashlib.sha256(digest(path).encode())
    for file in others:
        name = Path(file).relative_to(path.parent) if file.is_relative_to(path.parent) else file
        combined.update(f"\n{name.as_posix()} {digest(file)}".encode())
    return combined.hexdigest()
