"""The kinds of object a scene may hold beyond its built-in ones, by name: one registry.

A string names a built-in object (the scene's list) or an object of a registered source:

- ``generated``: ``"random-SEED"``, one generated object, and the sets ``"random:N"`` and
  ``"random:A-B"`` (:mod:`torchcontact.generated`);
- ``mesh``: a mesh file, a path with a suffix (``"scan.stl"``);
- a user's own prefix, ``"PREFIX:NAME"``, registered with :func:`register_object_source`: its
  function maps ``NAME`` to the mesh file that holds the object, which is then used as a mesh
  file is (scaled, turned onto its stable face, hashed into its trials' records)::

      register_object_source("ycb", lambda name: f"/data/ycb/{name}/google_16k/textured.obj")
      plant = env.make_plant("ycb:025_mug")

Every layer that takes an object's string (a plant, a trial, ``torchcontact run --object``,
``learn-k``) asks this registry what it is; none parses it itself.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from torchcontact import generated
from torchcontact.shapes import ObjectMesh
from torchcontact.validation import register


@dataclass(frozen=True)
class ObjectSource:
    """A kind of object named by a string.

    Attributes:
        name: its registered name.
        claims: ``obj ↦`` whether the string ``obj`` names an object (or a set) of this source.
        expand: ``obj ↦`` the object names it stands for (one, or a set's members);
            ``ValueError`` naming what is wrong with it.
        mesh_file: ``obj ↦`` the mesh file holding the object, None for an object made from
            its name (a generated one).
        make: ``(obj, mass [kg], size [m] or None, scale or None, collision) ↦`` the
            :class:`~torchcontact.shapes.ObjectMesh` of an object made from its name; None
            for a source of mesh files.
        canonical: ``obj ↦`` the one spelling of ``obj`` a run records (a mesh path made
            absolute, so that one file has one record name however it was typed).
        stem: ``obj ↦`` the object's part of its trials' record names, safe in a file name
            and apart from every other object's.
        about: the form of its names, for ``--help`` and errors.
    """

    name: str
    claims: Callable[[str], bool]
    expand: Callable[[str], list[str]]
    mesh_file: Callable[[str], Path | None] = field(default=lambda obj: None)
    make: Callable[..., ObjectMesh] | None = None
    canonical: Callable[[str], str] = field(default=lambda obj: obj)
    stem: Callable[[str], str] = field(default=lambda obj: obj)
    about: str = ""


OBJECT_SOURCES: dict[str, ObjectSource] = {}
"""The registered object sources by name, in the order they are asked."""


def is_mesh_file(obj: object) -> bool:
    """Whether ``obj`` names a mesh file (a path with a suffix; object names have none)."""
    return isinstance(obj, (str, Path)) and bool(Path(obj).suffix)


def _generated_objects(obj: str) -> list[str]:
    return [obj] if generated.is_generated(obj) else generated.expand(obj)


def _mesh_stem(obj: str) -> str:
    """A mesh path's file stem, ``-mesh-`` and 8 hex digits of the SHA-256 of the path as given
    (``cube-mesh-1a2b3c4d``): never a built-in object's name, nor another folder's mesh of the
    same file name."""
    return f"{Path(obj).stem}-mesh-{hashlib.sha256(obj.encode()).hexdigest()[:8]}"


def _make_generated(obj: str, mass: float, size, scale, collision: str) -> ObjectMesh:
    seed = generated.seed_of(obj)
    if seed is None:
        raise ValueError(f"obj {obj!r} names a set of objects: expand it (expand_objects) first")
    return generated.generate(seed, mass, size, scale, collision)


def _mesh_files(obj: str) -> list[str]:
    if not Path(obj).is_file():
        raise ValueError(f"object must be an existing mesh file, got {obj!r}")
    return [obj]


def _is_source(entry) -> bool:
    return isinstance(entry, ObjectSource)


register(
    OBJECT_SOURCES,
    "generated",
    ObjectSource(
        "generated",
        lambda obj: generated.is_generated(obj) or generated.is_set(obj),
        _generated_objects,
        make=_make_generated,
        about="a generated object random-SEED, or a set of them: random:N or random:A-B",
    ),
    "object source",
    _is_source,
)
register(
    OBJECT_SOURCES,
    "mesh",
    ObjectSource(
        "mesh",
        is_mesh_file,
        _mesh_files,
        Path,
        canonical=lambda obj: str(Path(obj).resolve()),
        stem=_mesh_stem,
        about="a mesh file in metres",
    ),
    "object source",
    _is_source,
)

_PREFIX = re.compile(r"^[a-z][a-z0-9_]*$")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def register_object_source(
    prefix: str, mesh_file: Callable[[str], str | Path], about: str | None = None
) -> ObjectSource:
    """Register the objects ``"PREFIX:NAME"``, each the mesh file ``mesh_file(NAME)`` (a
    function of the name alone, as every process that runs a trial calls it again: register it
    in a module that ``torchcontact run --import MODULE`` names). Returns the source.
    ``ValueError`` when ``prefix`` is not a new lower-case name (letters, digits, ``_``)."""
    if not isinstance(prefix, str) or not _PREFIX.match(prefix):
        raise ValueError(f"prefix must be a lower-case name (a-z, 0-9, _), got {prefix!r}")
    if prefix in OBJECT_SOURCES or prefix == generated.PREFIX:
        raise ValueError(f"prefix must be a new object source's, got {prefix!r}")
    if not callable(mesh_file):
        raise ValueError(f"mesh_file must be a function of the name, got {mesh_file!r}")
    head = f"{prefix}:"

    def file_of(obj: str) -> Path:
        name = obj[len(head) :]
        path = Path(mesh_file(name))
        if not (is_mesh_file(path) and path.is_file()):
            raise ValueError(f"object {obj!r} must name an existing mesh file, got {str(path)!r}")
        return path

    def expand(obj: str) -> list[str]:
        if not obj[len(head) :]:
            raise ValueError(f"objects of {prefix!r} are named '{head}NAME', got {obj!r}")
        file_of(obj)
        return [obj]

    source = ObjectSource(
        prefix,
        lambda obj: obj.startswith(head),
        expand,
        file_of,
        stem=lambda obj: f"{prefix}-{_UNSAFE.sub('_', obj[len(head) :])}",
        about=about or f"{head}NAME, an object of source {prefix!r}",
    )
    register(OBJECT_SOURCES, prefix, source, "object source", _is_source)
    return source


def object_source(obj: object) -> ObjectSource | None:
    """The registered source of ``obj``; None for a built-in name or an unknown string."""
    if isinstance(obj, Path):
        obj = str(obj)
    if not isinstance(obj, str):
        return None
    return next((s for s in OBJECT_SOURCES.values() if s.claims(obj)), None)


def expand_objects(obj: str) -> list[str] | None:
    """The objects ``obj`` names through its source (``ValueError`` naming what is wrong);
    None where no source claims it."""
    source = object_source(obj)
    return None if source is None else source.expand(obj)


def mesh_file_of(obj: object) -> Path | None:
    """The mesh file holding ``obj`` (a mesh path, or a user source's file); None for a
    built-in or generated object."""
    source = object_source(obj)
    return None if source is None else source.mesh_file(str(obj))


def canonical_object(obj: str) -> str:
    """The one spelling of ``obj`` a run records (:attr:`ObjectSource.canonical`)."""
    source = object_source(obj)
    return obj if source is None else source.canonical(obj)


def record_stem(obj: str) -> str:
    """``obj``'s part of its trials' record names (:attr:`ObjectSource.stem`; a built-in name
    as it is)."""
    source = object_source(obj)
    return obj if source is None else source.stem(obj)


def sources_about() -> str:
    """The forms of the registered sources' names, for ``--help`` and errors."""
    return "; ".join(source.about for source in OBJECT_SOURCES.values())
