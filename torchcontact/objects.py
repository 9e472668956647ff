"""Which object a scene holds: a built-in name or one of a registered source (a generated
name, a mesh file, a user's prefix: :mod:`torchcontact.object_sources`), and the user's choice
of its size, mass, friction and, for an object from a mesh file, its pose.

No MuJoCo here: :func:`resolve` returns the :class:`~torchcontact.shapes.ObjectMesh` a plant
turns into a body. The same options reach it from the CLI (``--object-size``,
``--object-scale``, ``--object-mass``, ``--object-friction``) and from Python::

    plant = env.make_plant("scan.stl", options=ObjectOptions(mass=0.05))
"""

from __future__ import annotations

from dataclasses import dataclass, field

from torchcontact.object_sources import mesh_file_of, object_source, sources_about
from torchcontact.resting import Rest, rest_on_stable_face
from torchcontact.shapes import (
    COLLISIONS,
    DEFAULT_MASS,
    MAX_MESH_EXTENT,
    OBJECT_SIZES,
    ObjectMesh,
    load_object,
    make_object,
)
from torchcontact.validation import is_finite_number

POSES = ("stable", "as-is")
"""How a mesh file's object is posed: ``"stable"`` turned onto its stable face from its centre
of mass, as generated objects are (:func:`~torchcontact.resting.rest_on_stable_face`);
``"as-is"`` as the file has it, its z axis up."""


@dataclass(frozen=True)
class ObjectOptions:
    """A user's settings of the object; None keeps the scene's own.

    Attributes:
        size: largest extent [m] the object is scaled to, uniformly (a mesh file is used at
            its own size in metres otherwise; a built-in or generated object at its listed or
            drawn size).
        scale: factor on that own size (0.001 for a mesh file in millimetres); not with
            ``size``.
        mass: total mass [kg] (the scene's default otherwise: the paper's).
        friction: the object's sliding friction coefficient.
        pose: how a mesh file's object is posed, one of :data:`POSES` (built-in and generated
            objects rest as they are made).
    """

    size: float | None = field(
        default=None, metadata={"help": "(hands, custom) largest extent [m] to scale it to"}
    )
    scale: float | None = field(
        default=None, metadata={"help": "factor on its own size (0.001 for a mesh file in mm)"}
    )
    mass: float | None = field(default=None, metadata={"help": "[kg]; the MPC models it"})
    friction: float | None = field(default=None, metadata={"help": "its sliding μ"})
    pose: str = field(
        default="stable",
        metadata={
            "help": "(a mesh file) stable: turned onto its stable face from its centre of "
            "mass, as generated objects are (default); as-is: as the file has it",
            "choices": POSES,
        },
    )

    def __post_init__(self):
        for name in ("size", "scale", "mass"):
            value = getattr(self, name)
            if value is not None and not _positive(value):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        friction = self.friction
        if friction is not None and not (is_finite_number(friction) and friction >= 0):
            raise ValueError(
                f"friction must be a non-negative finite number, got {self.friction!r}"
            )
        if self.size is not None and self.scale is not None:
            raise ValueError("size and scale both set the object's size: give one of them")
        if self.pose not in POSES:
            raise ValueError(f"pose must be one of {POSES}, got {self.pose!r}")

    @property
    def is_default(self) -> bool:
        """Whether nothing is set."""
        return self == ObjectOptions()


def resolve(
    obj,
    options: ObjectOptions | None = None,
    mass: float = 0.01,
    listed_size: tuple[float, float, float] | None = None,
    collision: str = "auto",
) -> ObjectMesh:
    """The :class:`ObjectMesh` of ``obj`` under ``options``.

    Args:
        obj: a built-in name (:data:`~torchcontact.shapes.OBJECT_SIZES`), an object of a
            registered source (:mod:`torchcontact.object_sources`: ``"random-SEED"``, a mesh
            file, ``"PREFIX:NAME"``) or an :class:`ObjectMesh` (used as it is; ``options``
            must then be empty).
        options: the user's size, scale and mass (friction is the plant's to apply).
        mass: the scene's mass [kg] where ``options.mass`` is None.
        listed_size: a built-in object's box (x, y, z) [m] in this scene (default its listed).
        collision: how it collides, see :func:`~torchcontact.shapes.make_object`; for a mesh
            file's object ``"hull"`` keeps its convex hull and the others its default
            decomposition.
    """
    if collision not in COLLISIONS:
        raise ValueError(f"collision must be one of {COLLISIONS}, got {collision!r}")
    options = ObjectOptions() if options is None else options
    mass = mass if options.mass is None else options.mass
    if isinstance(obj, ObjectMesh):
        if not options.is_default:
            raise ValueError("options must be empty for an ObjectMesh, which is used as it is")
        return obj
    path = mesh_file_of(obj)
    if options.pose != "stable" and path is None:
        raise ValueError(f"object pose {options.pose!r} is for a mesh file, got {obj!r}")
    if isinstance(obj, str) and obj in OBJECT_SIZES:
        box = OBJECT_SIZES[obj] if listed_size is None else listed_size
        factor = _factor(options, max(box))
        size = box if factor is None else tuple(side * factor for side in box)
        _check_extent(obj, max(size))
        return make_object(obj, mass=mass, size=size, collision=collision)
    source = object_source(obj)
    if source is not None and source.make is not None:
        made = source.make(obj, mass, options.size, options.scale, collision)
        _check_extent(obj, float(max(made.size)))
        return made
    if path is not None:
        decomposition = "hull" if collision == "hull" else "auto"
        # named apart from the built-in objects, whose names key the paper's scene facts
        name = f"mesh_{path.stem}"
        loaded = load_object(path, options.size, mass, decomposition, name, options.scale)
        return loaded if options.pose == "as-is" else mesh_rest(loaded).obj
    raise ValueError(
        f"obj must be a built-in object among {tuple(OBJECT_SIZES)}, {sources_about()}, or "
        f"an ObjectMesh, got {obj!r}"
    )


def mesh_rest(obj: ObjectMesh) -> Rest:
    """A mesh file's object on its stable face; ``ValueError`` where none has its centre of
    mass over it (then only ``pose="as-is"`` places it)."""
    try:
        return rest_on_stable_face(obj)
    except RuntimeError as error:
        raise ValueError(
            f"{error}: give pose 'as-is' (--object-pose as-is) to keep its file's"
        ) from None


def describe_pose(obj, options: ObjectOptions | None = None, collision: str = "auto") -> str:
    """How :func:`resolve` poses ``obj`` under ``options``, in words (for a run's header)."""
    options = ObjectOptions() if options is None else options
    path = mesh_file_of(obj)
    if path is None:
        return "rests as made"
    if options.pose == "as-is":
        return "posed as in its file"
    decomposition = "hull" if collision == "hull" else "auto"
    loaded = load_object(path, options.size, DEFAULT_MASS, decomposition, scale=options.scale)
    return mesh_rest(loaded).describe()


def _check_extent(obj: str, extent: float) -> None:
    """Refuse a built-in or generated object scaled past :data:`~torchcontact.shapes
    .MAX_MESH_EXTENT`, as a mesh file is."""
    if extent > MAX_MESH_EXTENT:
        raise ValueError(
            f"object {obj!r} would be {extent:g} m across, more than {MAX_MESH_EXTENT:g} m, the "
            "most an object may be: give a smaller size (size=, --object-size) or scale"
        )


def _factor(options: ObjectOptions, extent: float) -> float | None:
    """The uniform scale ``options`` asks of an object of largest extent ``extent``."""
    if options.size is not None:
        return options.size / extent
    return options.scale


def _positive(value) -> bool:
    return is_finite_number(value) and value > 0
