"""Collect MuJoCo transitions ``(q, u, Contacts(q), q_next)`` and store them on disk.

File format (version :data:`VERSION`): a dataset is a directory holding

``manifest.json``
    ``format`` (= :data:`FORMAT`), ``version``; what was collected: ``scene``, ``object``,
    ``task``, ``actions`` (``"random"``, ``"mpc"`` or ``"mixed"``), ``noise`` (exploration
    noise as a fraction of the control bound, null for the policy's default), ``steps`` (per
    trajectory), ``seed`` (trajectory ``i`` draws from seed ``seed + i``); the model it is
    fitted to: ``h`` [s], ``gamma``, ``facets``, ``paper_stiffness``, ``joints`` (the
    :class:`~torchcontact.integrate.JointLayout`), ``pose_weights`` (the MPC's position [1/m²]
    and orientation weights), ``system`` (the affine quasi-dynamic system ``Q (nv,)``,
    ``b0 (nv,)``, ``B (nv, nu)``: ``b(u) = b0 + B·u``), ``u_lower``, ``u_upper``; the sizes
    ``nq``, ``nv``, ``nu``, ``slots``; ``control_dt`` [s] simulated per step; the object's
    ``object_size`` [m] and ``object_mass`` [kg] (where the scene has an object) and, for a mesh
    file, ``object_sha256`` (its :func:`~torchcontact.digests.content_sha256`; null for a
    built-in or generated object), so data of a mesh since changed are refused; and
    ``trajectories``: one entry ``{"id", "file", "seed", "actions", "steps"}`` per finished
    trajectory.
``trajectory_00000.npz`` (one per trajectory, ``np.savez``, written atomically)
    ``q (T, nq)``, ``u (T, nu)``, ``q_next (T, nq)`` float64: the state, the applied control
    and the MuJoCo state one step later; ``step (T,)`` int64; the padded :class:`Contacts` at
    ``q`` as float32 ``phi (T, nc)`` [m], ``jac_normal (T, nc, nv)``, ``jac_tangent (T, nc, 2,
    nv)``, ``mu (T, nc)``, ``frame (T, nc, 3, 3)``, ``position (T, nc, 3)`` [m] and bool
    ``active (T, nc)``; and ``meta``, a JSON string ``{"format", "version", "scene",
    "object", "trajectory", "seed", "actions"}``.

:func:`collect` appends trajectories to a directory and resumes after an interruption (a
trajectory is either absent or complete); :func:`load` reads a dataset back as
:class:`Transitions`, raising :class:`DataFormatError` naming the file and what was expected
when a file is truncated, corrupted or does not match its manifest.
"""

from __future__ import annotations

import json
import math
import numbers
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from torchcontact.contacts import Contacts
from torchcontact.digests import content_sha256
from torchcontact.environments import ENVIRONMENTS
from torchcontact.integrate import JointLayout, difference
from torchcontact.learn.policies import ACTIONS, make_policy
from torchcontact.learn.scenes import BOX_PUSHING, BoxPushingScene, Scene, make_scene
from torchcontact.object_sources import mesh_file_of
from torchcontact.parallel import check_backend, parallel_map
from torchcontact.results import atomic_write, read_json, write_json
from torchcontact.systems import QuasiDynamic

FORMAT = "torchcontact.learn.transitions"
VERSION = 1
MANIFEST = "manifest.json"

STATE_ARRAYS = ("q", "u", "q_next")
CONTACT_ARRAYS = ("phi", "jac_normal", "jac_tangent", "mu", "active", "frame", "position")
FINITE_ARRAYS = ("q", "u", "q_next", "phi", "jac_normal", "jac_tangent", "mu")
"""Arrays that must hold finite numbers only (the model reads them)."""
REQUIRED = (
    *("format", "version", "scene", "object", "task", "actions", "steps", "seed"),
    *("h", "gamma", "facets", "paper_stiffness", "joints", "pose_weights", "system"),
    *("nq", "nv", "nu", "slots", "trajectories"),
)
"""Manifest keys the readers rely on."""


class DataFormatError(ValueError):
    """A dataset file is missing, truncated, corrupted or does not match its manifest."""


def trajectory_file(index: int) -> str:
    """File name of trajectory ``index``."""
    return f"trajectory_{index:05d}.npz"


def affine_system(system: QuasiDynamic) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``Q (nv,)``, ``b0 (nv,)`` and ``B (nv, nu)`` of ``system`` in float64:
    ``b(u) = b0 + B·u``. A system carrying momentum has no such form and is refused."""
    if getattr(system, "object_momentum", None) is not None:
        raise ValueError(
            "system must not carry object_momentum (its b depends on the object's last "
            "displacement): pass the system without it, a calibration adds it to the model"
        )
    u = torch.eye(system.n_robot, dtype=torch.float64)
    Q, b0 = system(torch.zeros_like(u[0]))
    _, b_unit = system(u)
    return Q, b0, (b_unit - b0).T


def system_header(system: QuasiDynamic) -> dict:
    """The affine system's manifest entry: :func:`affine_system` as lists."""
    Q, b0, B = affine_system(system)
    return {"Q": Q.tolist(), "b0": b0.tolist(), "B": B.tolist()}


def scene_header(scene: Scene | BoxPushingScene) -> dict:
    """The manifest entries that describe ``scene``'s plant and model (see module docstring)."""
    lower, upper = scene.control_bounds
    return {
        "h": scene.h,
        "gamma": scene.model.gamma,
        "facets": scene.model.facets,
        "paper_stiffness": scene.paper_stiffness,
        "joints": list(scene.layout.joints),
        "pose_weights": list(scene.pose_weights),
        "system": system_header(scene.system),
        "u_lower": lower.tolist(),
        "u_upper": upper.tolist(),
        "nq": scene.plant.nq,
        "nv": scene.plant.nv,
        "nu": scene.system.n_robot,
        "slots": scene.plant.detector.slots,
        "control_dt": scene.control_dt,
        **object_header(scene.plant),
    }


def object_header(plant) -> dict:
    """The manipulated object's size [m] and mass [kg], where the plant has one: data of a
    name whose shape has changed since (a generated object's family, a mesh file edited) are
    then refused on resume rather than mixed in."""
    obj = getattr(plant, "object", None)
    if obj is None:
        return {}
    return {"object_size": [round(float(x), 7) for x in obj.size], "object_mass": obj.mass}


def collect_trajectory(
    scene: Scene | BoxPushingScene, actions: str, seed: int, steps: int, noise=None
) -> dict:
    """Run one trajectory of ``steps`` steps from the scene's sampled pose of ``seed``.

    Returns the trajectory's arrays (the layout of a trajectory file, without ``meta``).
    """
    initial, target = scene.sample(seed)
    scene.plant.reset(initial, target)
    policy = make_policy(actions, scene, seed, target, noise)
    rows = {key: [] for key in (*STATE_ARRAYS, *CONTACT_ARRAYS)}
    q = scene.plant.state()
    for _ in range(steps):
        contacts = scene.plant.contacts(torch.float64)
        u = policy(q, contacts)
        q_next = scene.plant.step(u)
        for key, value in (("q", q), ("u", u), ("q_next", q_next)):
            rows[key].append(value)
        for key in CONTACT_ARRAYS:
            rows[key].append(getattr(contacts, key).numpy())
        q = q_next
    arrays = {key: np.stack(rows[key]) for key in rows}
    for key in STATE_ARRAYS:
        arrays[key] = arrays[key].astype(np.float64)
    for key in CONTACT_ARRAYS:
        if key != "active":
            arrays[key] = arrays[key].astype(np.float32)
    arrays["step"] = np.arange(steps, dtype=np.int64)
    return arrays


def _resume(path: Path, manifest: dict) -> list[dict]:
    """The finished trajectories listed at ``path``, checked to match ``manifest``."""
    existing = read_manifest(path.parent)
    keys = [key for key in manifest if key != "trajectories"]
    differ = {k: (existing.get(k), manifest[k]) for k in keys if existing.get(k) != manifest[k]}
    if differ:
        raise DataFormatError(
            f"{path}: holds data collected with other settings (found, asked): {differ}; "
            "use another directory"
        )
    for entry in existing["trajectories"]:
        _check_meta(path.parent / entry["file"], existing, entry["id"])
    return existing["trajectories"]


def _save_trajectory(directory: Path, manifest: dict, index: int, kind: str, arrays: dict):
    """Write trajectory ``index`` atomically, then list it in the manifest (atomically)."""
    seed = manifest["seed"] + index
    meta = {key: manifest[key] for key in ("format", "version", "scene", "object")}
    meta.update(trajectory=index, seed=seed, actions=kind)
    file = trajectory_file(index)
    atomic_write(
        directory / file,
        lambda f: np.savez(f, meta=json.dumps(meta), **arrays),
        binary=True,
    )
    entries = manifest["trajectories"]
    entries.append(
        {"id": index, "file": file, "seed": seed, "actions": kind, "steps": len(arrays["q"])}
    )
    entries.sort(key=lambda entry: entry["id"])
    write_json(directory / MANIFEST, manifest)


def collect(
    directory: str | Path,
    scene: str,
    obj: str = "cube",
    trajectories: int = 20,
    steps: int = 50,
    actions: str = "random",
    seed: int = 0,
    task: str | None = None,
    noise: float | None = None,
    progress: bool = True,
    planner: Callable[[Scene], object] | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
) -> Path:
    """Collect trajectories ``0 … trajectories−1`` into ``directory``; returns the manifest.

    Trajectories already in the directory are kept (a rerun after an interruption collects
    only the missing ones, with the same results as an uninterrupted run; a larger
    ``trajectories`` appends). The directory must hold data of the same scene, object, task,
    action source, noise, steps, seed and model, else :class:`DataFormatError` says what
    differs.

    Args:
        directory: the dataset directory (created if needed).
        scene, obj, task: the scene, its object and the task whose sampler gives each
            trajectory's initial (and, for MPC actions, target) pose; see :func:`make_scene`.
        trajectories: number of trajectories; steps: transitions per trajectory.
        actions: ``"random"`` (:class:`~torchcontact.learn.policies.ReachPolicy`, for box
            pushing :class:`~torchcontact.learn.policies.PushPolicy`), ``"mpc"``
            (:class:`~torchcontact.learn.policies.MPCPolicy`) or ``"mixed"`` (random for
            even trajectory ids, MPC for odd ones); box pushing takes ``"random"`` only.
        seed: trajectory ``i`` uses seed ``seed + i``.
        noise: exploration noise as a fraction of the control bound (None: each policy's
            default, 0.3 random and 0.1 MPC).
        progress: show a tqdm bar.
        planner: ``scene ↦`` what plans the MPC actions of a scene (e.g. the environment's
            :class:`~torchcontact.mpc.controller.ContactImplicitMPC`); required by ``"mpc"``
            and ``"mixed"`` actions (picklable for more than one worker).
        workers, backend, address: where trajectories run, as
            :func:`~torchcontact.parallel.parallel_map` (``"local"`` processes or ``"ray"``
            tasks); each is saved here as it arrives, the same as a serial run's.
    """
    _check_collect(scene, trajectories, steps, actions, seed, noise, planner)
    check_backend(workers, backend, address)
    directory = Path(directory)
    built = make_scene(scene, obj, task)
    manifest = _new_manifest(built, scene, obj, actions, noise, steps, seed)
    path = directory / MANIFEST
    if path.exists():
        manifest["trajectories"] = _resume(path, manifest)
    else:
        write_json(path, manifest)
    done = {entry["id"] for entry in manifest["trajectories"]}
    jobs = [
        _CollectJob(scene, obj, built.task, _kind(actions, i), seed + i, steps, noise, planner, i)
        for i in range(trajectories)
        if i not in done
    ]
    _SCENES.clear()
    _SCENES[scene, obj, built.task] = built  # the serial run reuses the manifest's scene
    with tqdm(
        total=trajectories,
        initial=trajectories - len(jobs),
        desc=f"{scene} {obj}",
        unit="traj",
        disable=not progress,
    ) as bar:
        for index, arrays in parallel_map(_collect_job, jobs, workers, backend, address):
            _save_trajectory(directory, manifest, jobs[index].index, jobs[index].kind, arrays)
            bar.update()
    return path


def _new_manifest(built, scene: str, obj: str, actions: str, noise, steps: int, seed: int):
    """The manifest of a dataset of ``built`` without trajectories (see the module docstring)."""
    mesh = mesh_file_of(obj)
    return {
        "format": FORMAT,
        "version": VERSION,
        "scene": scene,
        "object": obj,
        "task": built.task,
        "actions": actions,
        "noise": noise,
        "steps": steps,
        "seed": seed,
        "object_sha256": None if mesh is None else content_sha256(mesh),
        **scene_header(built),
        "trajectories": [],
    }


def _check_collect(scene, trajectories, steps, actions, seed, noise, planner) -> None:
    """``ValueError`` naming the first argument of :func:`collect` that is out of range."""
    if scene != BOX_PUSHING and scene not in ENVIRONMENTS:  # registered ones included
        raise ValueError(f"scene must be one of {(*ENVIRONMENTS, BOX_PUSHING)}, got {scene!r}")
    if actions not in ACTIONS:
        raise ValueError(f"actions must be one of {ACTIONS}, got {actions!r}")
    if scene == BOX_PUSHING and actions != "random":
        raise ValueError(f"box_pushing has no MPC task: actions must be 'random', got {actions!r}")
    for name, value in (("trajectories", trajectories), ("steps", steps)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if noise is not None and (
        isinstance(noise, bool)
        or not isinstance(noise, numbers.Real)
        or not (math.isfinite(noise) and noise >= 0)
    ):
        raise ValueError(f"noise must be a non-negative finite number or None, got {noise!r}")
    if actions != "random" and planner is None:
        raise ValueError(f"planner is required by actions={actions!r}")


def _kind(actions: str, index: int) -> str:
    """The action source of trajectory ``index``: ``"mixed"`` alternates random and MPC."""
    return actions if actions != "mixed" else ("random", "mpc")[index % 2]


@dataclass(frozen=True)
class _CollectJob:
    """One trajectory to collect (picklable, for worker processes)."""

    scene: str
    obj: str
    task: str
    kind: str
    seed: int
    steps: int
    noise: float | None
    planner: Callable[[Scene], object] | None
    index: int


_SCENES: dict = {}  # per process: the scene of the last job, planner attached once needed


def _collect_job(job: _CollectJob) -> dict:
    """The arrays of ``job``'s trajectory, in a scene built once per process."""
    torch.set_num_threads(1)
    key = (job.scene, job.obj, job.task)
    if key not in _SCENES:
        _SCENES.clear()
        _SCENES[key] = make_scene(job.scene, job.obj, job.task)
    built = _SCENES[key]
    if job.kind == "mpc" and built.planner is None:
        built.planner = job.planner(built)
    return collect_trajectory(built, job.kind, job.seed, job.steps, job.noise)


def read_manifest(directory: str | Path) -> dict:
    """The manifest of the dataset in ``directory``, checked for format and version."""
    path = Path(directory) / MANIFEST
    if not path.is_file():
        raise DataFormatError(f"{path}: no dataset manifest here (expected {MANIFEST})")
    try:
        manifest = read_json(path)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise DataFormatError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        found = manifest.get("format") if isinstance(manifest, dict) else type(manifest).__name__
        raise DataFormatError(f"{path}: expected format {FORMAT!r}, found {found!r}")
    if manifest.get("version") != VERSION:
        raise DataFormatError(
            f"{path}: expected format version {VERSION}, found {manifest.get('version')!r}"
        )
    missing = [key for key in REQUIRED if key not in manifest]
    if missing:
        raise DataFormatError(f"{path}: manifest lacks {missing}")
    return manifest


def _open(path: Path):
    if not path.is_file():
        raise DataFormatError(f"{path}: trajectory file missing")
    try:
        return np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
        raise DataFormatError(f"{path}: truncated or not an .npz file ({error})") from None


def _check_meta(path: Path, manifest: dict, index: int) -> None:
    """Check the ``meta`` entry of a trajectory file against the manifest."""
    with _open(path) as archive:
        try:
            meta = json.loads(str(archive["meta"]))
        except (KeyError, zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
            raise DataFormatError(f"{path}: unreadable meta entry ({error})") from None
    expected = {
        "format": FORMAT,
        "version": VERSION,
        "scene": manifest["scene"],
        "object": manifest["object"],
        "trajectory": index,
    }
    wrong = {k: (meta.get(k), v) for k, v in expected.items() if meta.get(k) != v}
    if wrong:
        raise DataFormatError(f"{path}: does not match its manifest (found, expected): {wrong}")


def _expected_shapes(manifest: dict, steps: int) -> dict[str, tuple[tuple[int, ...], str]]:
    nq, nv, nu, nc = (manifest[k] for k in ("nq", "nv", "nu", "slots"))
    return {
        "q": ((steps, nq), "f8"),
        "u": ((steps, nu), "f8"),
        "q_next": ((steps, nq), "f8"),
        "step": ((steps,), "i8"),
        "phi": ((steps, nc), "f4"),
        "jac_normal": ((steps, nc, nv), "f4"),
        "jac_tangent": ((steps, nc, 2, nv), "f4"),
        "mu": ((steps, nc), "f4"),
        "active": ((steps, nc), "b1"),
        "frame": ((steps, nc, 3, 3), "f4"),
        "position": ((steps, nc, 3), "f4"),
    }


def read_trajectory(directory: str | Path, manifest: dict, entry: dict) -> dict[str, np.ndarray]:
    """The arrays of the manifest's trajectory ``entry``, checked against the manifest."""
    path = Path(directory) / entry["file"]
    _check_meta(path, manifest, entry["id"])
    arrays = {}
    with _open(path) as archive:
        for key, (shape, dtype) in _expected_shapes(manifest, entry["steps"]).items():
            try:
                value = archive[key]
            except KeyError:
                raise DataFormatError(f"{path}: lacks the array {key!r}") from None
            except (zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
                raise DataFormatError(f"{path}: array {key!r} unreadable ({error})") from None
            if value.shape != shape or value.dtype != np.dtype(dtype):
                raise DataFormatError(
                    f"{path}: array {key!r} should be {np.dtype(dtype)} of shape {shape} "
                    f"(manifest nq, nv, nu, slots = {manifest['nq']}, {manifest['nv']}, "
                    f"{manifest['nu']}, {manifest['slots']}), found {value.dtype} {value.shape}"
                )
            if key in FINITE_ARRAYS and not np.isfinite(value).all():
                raise DataFormatError(f"{path}: array {key!r} holds NaN or Inf values")
            arrays[key] = value
    return arrays


@dataclass
class Transitions:
    """Stacked transitions of a dataset: N rows, from several trajectories.

    Attributes:
        q: ``(N, nq)`` state (object position [m], quaternion, robot coordinates), float64.
        u: ``(N, nu)`` applied control, float64.
        q_next: ``(N, nq)`` MuJoCo state one step later, float64.
        contacts: :class:`Contacts` at ``q`` with batch shape ``(N,)`` (float32 geometry).
        trajectory: ``(N,)`` trajectory id (unique across objects); step: ``(N,)`` step
            index within it.
        meta: the dataset manifest (without the trajectory list), with ``objects`` (the
            objects' names) and ``systems`` (each object's affine system, as ``system``).
        object: ``(N,)`` index into ``meta["objects"]`` (None: all zeros, one object).
    """

    q: torch.Tensor
    u: torch.Tensor
    q_next: torch.Tensor
    contacts: Contacts
    trajectory: torch.Tensor
    step: torch.Tensor
    meta: dict
    object: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.object is None:
            self.object = torch.zeros(len(self.q), dtype=torch.long)
        self.meta.setdefault("objects", [self.meta.get("object")])
        self.meta.setdefault("systems", [self.meta["system"]])

    def __len__(self) -> int:
        return self.q.shape[0]

    def select(self, index: torch.Tensor) -> Transitions:
        """The rows ``index`` (a long index or bool mask ``(N,)``)."""
        return Transitions(
            self.q[index],
            self.u[index],
            self.q_next[index],
            self.contacts[index],
            self.trajectory[index],
            self.step[index],
            self.meta,
            self.object[index],
        )

    def object_ids(self) -> list[int]:
        """The object indices present, sorted."""
        return sorted(set(self.object.tolist()))

    def split_objects(
        self, fractions: tuple[float, float, float] = (0.6, 0.2, 0.2), seed: int = 0
    ) -> tuple[Transitions, Transitions, Transitions]:
        """Train, validation and test sets by whole objects (shuffled with ``seed``): no object
        is in two sets. Each set gets at least one object; three or more are needed."""
        return self._split(self.object, self.object_ids(), "objects", fractions, seed)

    def trajectory_ids(self) -> list[int]:
        """The trajectory ids present, sorted."""
        return sorted(set(self.trajectory.tolist()))

    def split(
        self, fractions: tuple[float, float, float] = (0.7, 0.15, 0.15), seed: int = 0
    ) -> tuple[Transitions, Transitions, Transitions]:
        """Train, validation and test sets by whole trajectories (shuffled with ``seed``).

        Each set gets at least one trajectory when there are three or more.
        """
        return self._split(self.trajectory, self.trajectory_ids(), "trajectories", fractions, seed)

    def _split(self, key: torch.Tensor, ids: list[int], what: str, fractions, seed: int):
        """Rows grouped by ``key``'s values ``ids``, the groups shuffled and dealt in
        ``fractions``."""
        if len(fractions) != 3 or any(f < 0 for f in fractions) or not sum(fractions) > 0:
            raise ValueError(f"fractions must be three non-negative numbers, got {fractions!r}")
        ids = np.array(ids)
        if len(ids) < 3:
            raise ValueError(f"splitting needs at least 3 {what}, got {len(ids)}")
        ids = ids[np.random.default_rng(seed).permutation(len(ids))]
        total = sum(fractions)
        n_val = max(1, round(len(ids) * fractions[1] / total))
        n_test = max(1, round(len(ids) * fractions[2] / total))
        n_train = len(ids) - n_val - n_test
        if n_train < 1:
            raise ValueError(f"fractions {fractions} leave no training {what[:-1]} of {len(ids)}")
        groups = (ids[:n_train], ids[n_train : n_train + n_val], ids[n_train + n_val :])
        return tuple(self.select(torch.isin(key, torch.as_tensor(g))) for g in groups)

    def previous_displacement(self) -> torch.Tensor:
        """``(N, nv)`` each row's displacement over the step before it [m, rad]: ``h·v`` with
        ``v`` the velocity that takes the previous row's state to this one's
        (:func:`~torchcontact.integrate.difference`); zero at a trajectory's first step, or
        where the previous step is not among the rows (the plants start at rest)."""
        layout = JointLayout(self.meta["joints"])
        displacement = torch.zeros(len(self), layout.nv, dtype=self.q.dtype)
        if len(self) < 2:
            return displacement
        order = torch.argsort(self.trajectory * (int(self.step.max()) + 1) + self.step)
        traj, step = self.trajectory[order], self.step[order]
        follows = (traj[1:] == traj[:-1]) & (step[1:] - step[:-1] == 1)
        rows, previous = order[1:][follows], order[:-1][follows]
        displacement[rows] = difference(self.q[previous], self.q[rows], 1.0, layout)
        return displacement

    def windows(self, horizon: int, stride: int = 1) -> torch.Tensor:
        """``(W, horizon)`` row indices of consecutive steps of one trajectory each, starting
        every ``stride`` steps: the inputs of ``horizon``-step rollouts."""
        if not isinstance(horizon, int) or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if not isinstance(stride, int) or stride < 1:
            raise ValueError(f"stride must be a positive integer, got {stride!r}")
        if len(self) < horizon:
            return torch.zeros((0, horizon), dtype=torch.long)
        order = torch.argsort(self.trajectory * (int(self.step.max()) + 1) + self.step)
        traj, step = self.trajectory[order], self.step[order]
        end = horizon - 1
        last = len(order) - end
        starts = torch.nonzero(
            (traj[:last] == traj[end:])
            & (step[end:] - step[:last] == end)
            & (step[:last] % stride == 0)
        ).squeeze(-1)
        return order[starts[:, None] + torch.arange(horizon)]


def load(directory: str | Path, trajectories: int | None = None) -> Transitions:
    """Read the dataset in ``directory`` (see the module docstring) as :class:`Transitions`.

    ``trajectories``: read only trajectories ``0 … trajectories−1`` (all must be present);
    None reads every trajectory of the manifest.
    """
    directory = Path(directory)
    manifest = read_manifest(directory)
    entries = manifest["trajectories"]
    if trajectories is not None:
        entries = [entry for entry in entries if entry["id"] < trajectories]
        if len(entries) < trajectories:
            raise DataFormatError(
                f"{directory / MANIFEST}: holds {len(entries)} of trajectories "
                f"0…{trajectories - 1}; collect them first"
            )
    if not entries:
        raise DataFormatError(f"{directory / MANIFEST}: the dataset has no trajectory yet")
    parts = {key: [] for key in (*STATE_ARRAYS, *CONTACT_ARRAYS, "step", "trajectory")}
    for entry in entries:
        arrays = read_trajectory(directory, manifest, entry)
        for key, value in arrays.items():
            parts[key].append(value)
        parts["trajectory"].append(np.full(entry["steps"], entry["id"], dtype=np.int64))
    stacked = {key: torch.from_numpy(np.concatenate(value)) for key, value in parts.items()}
    meta = {k: v for k, v in manifest.items() if k != "trajectories"}
    return Transitions(
        q=stacked["q"],
        u=stacked["u"],
        q_next=stacked["q_next"],
        contacts=Contacts(**{key: stacked[key] for key in CONTACT_ARRAYS}),
        trajectory=stacked["trajectory"],
        step=stacked["step"],
        meta=meta,
    )


SHARED = ("scene", "h", "gamma", "facets", "paper_stiffness", "joints", "pose_weights")
SHARED += ("nq", "nv", "nu", "control_dt")
"""Manifest keys every dataset of a multi-object set must agree on."""


def load_objects(directories, trajectories: int | None = None) -> Transitions:
    """The datasets in ``directories`` (one object each, one scene) as one
    :class:`Transitions`: ``object`` indexes ``meta["objects"]`` in the order given, each
    object keeps its own system (``meta["systems"]``), trajectory ids are renumbered to be
    unique and the contacts are padded to the most slots of any (``meta["slots"]``).
    ``trajectories``: read trajectories ``0 … trajectories−1`` of each.

    Raises :class:`DataFormatError` naming a dataset whose scene, model or sizes differ from
    the first's, or an object given twice."""
    directories = [Path(d) for d in directories]
    if not directories:
        raise ValueError("directories must name at least one dataset")
    parts = [load(directory, trajectories) for directory in directories]
    first = parts[0].meta
    for directory, part in zip(directories, parts, strict=True):
        for key in (*SHARED, "B"):
            mine = part.meta["system"]["B"] if key == "B" else part.meta.get(key)
            theirs = first["system"]["B"] if key == "B" else first.get(key)
            if mine != theirs:
                raise DataFormatError(
                    f"{directory / MANIFEST}: {key} differs from {directories[0]}'s "
                    f"({mine!r} against {theirs!r}); a multi-object set needs one scene"
                )
    objects = [part.meta["object"] for part in parts]
    if len(set(objects)) != len(objects):
        raise DataFormatError(f"each object must come once, got {objects}")
    span = 1 + max(int(part.trajectory.max()) for part in parts)
    slots = max(part.meta["slots"] for part in parts)  # objects of more parts have more
    meta = {
        **first,
        "object": None,
        "slots": slots,
        "objects": objects,
        "systems": [part.meta["system"] for part in parts],
    }
    return Transitions(
        q=torch.cat([part.q for part in parts]),
        u=torch.cat([part.u for part in parts]),
        q_next=torch.cat([part.q_next for part in parts]),
        contacts=Contacts.cat([part.contacts.padded(slots) for part in parts]),
        trajectory=torch.cat([i * span + part.trajectory for i, part in enumerate(parts)]),
        step=torch.cat([part.step for part in parts]),
        meta=meta,
        object=torch.cat([torch.full((len(part),), i) for i, part in enumerate(parts)]),
    )
