"""Fit the complementarity-free model, K(q), D(q) and optionally the system, to data.

The model is the scene's :class:`~torchcontact.model.ComplementarityFree` with learnable
sub-modules: K and D, and a :class:`~torchcontact.calibration.SystemCalibration` (the robot's
command gain and stiffness, the object metric ε, μ, optionally the object's momentum) when one
is fitted. The loss is the object pose error against MuJoCo, weighted as in the MPC's final
cost, ``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)`` (the paper's w_p = 500 or 100, w_q = 5): after one
step, or the mean over H steps rolled out with the contacts frozen at each window's first
state, as the MPC plans (:class:`StepData` holds the windows), or re-evaluated at every
predicted state by each object's torch contact geometry
(:class:`~torchcontact.geometry.SceneGeometry`, ``FitConfig.loss_contacts="geometry"``).
Adam on mini-batches, early stopping on a validation set, the best state kept. :func:`fit`
takes plain tensors; :func:`fit_steps` takes prepared windows. :mod:`torchcontact.checkpoint`
stores the fitted model with the :class:`~torchcontact.checkpoint.FitConfig` and dataset
metadata that rebuild it.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields

import torch
from tqdm.auto import tqdm

from torchcontact.checkpoint import FitConfig, build_model
from torchcontact.contacts import Contacts
from torchcontact.environments.costs import position_cost
from torchcontact.integrate import JOINT_SIZES, JointLayout, integrate, object_indices
from torchcontact.learn.data import Transitions, affine_system, system_header
from torchcontact.model import ComplementarityFree
from torchcontact.rotations import quaternion_error
from torchcontact.systems import QuasiDynamic, carry_momentum
from torchcontact.validation import check_shape, validate_args


def system_terms(meta: dict, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``Q (nv,)`` and ``b (..., nv) = b0 + B·u`` of the dataset's quasi-dynamic system."""
    system = meta["system"]
    kw = {"dtype": u.dtype, "device": u.device}
    B = torch.tensor(system["B"], **kw)
    b = torch.tensor(system["b0"], **kw) + u @ B.T
    return torch.tensor(system["Q"], **kw), b


@dataclass
class StepData:
    """N windows of H consecutive transitions (H = 1: single steps), the inputs of the loss.

    Each window starts at a recorded state with its recorded contacts; the model rolls out
    the recorded controls for H steps with those contacts frozen (as the MPC plans), and its
    object poses are compared with MuJoCo's after every step.

    Attributes:
        q: ``(N, nq)`` the windows' first states, for state-dependent K.
        contacts: :class:`Contacts` ``(N, ...)`` detected at ``q``.
        u: ``(N, H, nu)`` the recorded controls.
        metric: ``(N, nv)`` Q and bias: ``(N, nv)`` b0 of each window's object's system,
            with B: ``(nv, nu)``, ``b(u) = b0 + B·u``.
        pose: ``(N, n_obj, 7)`` object poses at q; target: ``(N, H, n_obj, 7)`` recorded after
            each step.
        displacement: ``(N, n_obj·6)`` the objects' displacement over the step before q [m,
            rad] (:meth:`~torchcontact.learn.data.Transitions.previous_displacement`), for a
            model whose calibration carries momentum.
        robot: ``(N, n_r)`` the robot's coordinates at q [m or rad]; robot_target:
            ``(N, H, n_r)`` recorded after each step.
        object_rows: ``(n_obj·6,)`` the objects' indices in v; robot_rows: ``(n_r,)`` the
            robot's (one coordinate per velocity: hinge and slide joints).
        objects: ``(N,)`` each window's object, an index into ``meta["objects"]`` (0 for
            plain tensors): which object's geometry sees its predicted states.
        object_q: ``(n_obj·7,)`` the objects' poses' indices in q; robot_q: ``(n_r,)`` the
            robot's coordinates'.
        h: the model's time step [s].
    """

    q: torch.Tensor
    contacts: Contacts
    u: torch.Tensor
    metric: torch.Tensor
    bias: torch.Tensor
    B: torch.Tensor
    pose: torch.Tensor
    target: torch.Tensor
    displacement: torch.Tensor
    robot: torch.Tensor
    robot_target: torch.Tensor
    object_rows: torch.Tensor
    robot_rows: torch.Tensor
    objects: torch.Tensor
    object_q: torch.Tensor
    robot_q: torch.Tensor
    h: float

    @classmethod
    def from_transitions(
        cls,
        transitions: Transitions,
        horizon: int = 1,
        dtype: torch.dtype = torch.float32,
        stride: int = 1,
    ) -> StepData:
        """Windows of ``horizon`` steps starting every ``stride`` steps of each trajectory;
        each transition's system is its object's (``meta["systems"]``)."""
        meta = transitions.meta
        windows = transitions.windows(horizon, stride)
        first = windows[:, 0]
        systems = meta["systems"]
        metric = torch.tensor([s["Q"] for s in systems], dtype=torch.float64)
        bias = torch.tensor([s["b0"] for s in systems], dtype=torch.float64)
        objects = transitions.object[first]
        _, v_index = object_indices(meta["joints"])
        moved = transitions.previous_displacement()[first][:, v_index.flatten()]
        return cls._build(
            transitions.q[first],
            transitions.contacts[first],
            transitions.u[windows],
            transitions.q_next[windows],
            metric[objects],
            bias[objects],
            torch.tensor(meta["system"]["B"], dtype=torch.float64),
            float(meta["h"]),
            meta["joints"],
            dtype,
            moved,
            objects,
        )

    @classmethod
    def from_tensors(
        cls,
        q: torch.Tensor,
        u: torch.Tensor,
        q_next: torch.Tensor,
        contacts: Contacts,
        system: QuasiDynamic,
        h: float,
        joints: list[str],
        dtype: torch.dtype = torch.float32,
        displacement: torch.Tensor | None = None,
    ) -> StepData:
        """Single steps from plain tensors: no dataset folder or manifest.

        Args:
            q: ``(N, nq)`` states; u: ``(N, n_robot)`` controls; q_next: ``(N, nq)`` the
                states one step of ``h`` [s] later (all in the layout of ``joints``).
            contacts: :class:`Contacts` ``(N, ...)`` detected at ``q``.
            system: the quasi-dynamic system ``u ↦ (Q, b)`` of the model.
            joints: joint types of q (``"free"`` for the object, see
                :class:`~torchcontact.integrate.JointLayout`).
            displacement: ``(N, nv)`` each state's displacement over the step before it [m,
                rad] (``h`` times :func:`~torchcontact.integrate.difference`), for a model
                that carries the object's momentum; None: every state at rest.
        """
        n = q.shape[0]
        for name, value in (("u", u), ("q_next", q_next)):
            if value.shape[0] != n:
                raise ValueError(f"{name} must have {n} rows like q, got {tuple(value.shape)}")
        if contacts.phi.shape[0] != n:
            raise ValueError(f"contacts must have {n} rows like q, got {contacts.phi.shape[0]}")
        _, v_index = object_indices(joints)
        if displacement is None:
            moved = q.new_zeros(n, v_index.numel())
        else:
            nv = JointLayout(joints).nv
            check_shape("displacement", displacement, f"({n}, {nv})", displacement.shape == (n, nv))
            moved = displacement[:, v_index.flatten()]
        Q, b0, B = affine_system(system)  # float64 whatever the system's dtype
        rows = (q, contacts, u[:, None], q_next[:, None], Q.expand(n, -1), b0.expand(n, -1), B)
        objects = torch.zeros(n, dtype=torch.long)
        return cls._build(*rows, float(h), joints, dtype, moved, objects)

    @classmethod
    def _build(
        cls, q, contacts, u, q_next, metric, bias, B, h, joints, dtype, displacement, objects
    ) -> StepData:
        q_index, v_index = object_indices(joints)
        layout = JointLayout(joints)
        if any(j != "free" and JOINT_SIZES[j][0] != JOINT_SIZES[j][1] for j in layout.joints):
            raise ValueError(f"joints: the robot's must be hinge or slide joints, got {joints}")
        robot_q = _complement(q_index.flatten(), layout.nq)
        return cls(
            q=q.to(dtype),
            contacts=contacts.to(dtype),
            u=u.to(dtype),
            metric=metric.to(dtype),
            bias=bias.to(dtype),
            B=B.to(dtype),
            pose=q[:, q_index].to(dtype),
            target=q_next[:, :, q_index].to(dtype),
            displacement=displacement.to(dtype),
            robot=q[:, robot_q].to(dtype),
            robot_target=q_next[:, :, robot_q].to(dtype),
            object_rows=v_index.flatten(),
            robot_rows=_complement(v_index.flatten(), layout.nv),
            objects=objects.to(device=q.device, dtype=torch.long),
            object_q=q_index.flatten(),
            robot_q=robot_q,
            h=h,
        )

    def __len__(self) -> int:
        return self.q.shape[0]

    @property
    def horizon(self) -> int:
        return self.u.shape[1]

    def select(self, index: torch.Tensor) -> StepData:
        """Windows ``index`` (long indices or a bool mask)."""
        shared = ("contacts", "h", "B", "object_rows", "robot_rows", "object_q", "robot_q")
        tensors = {
            f.name: getattr(self, f.name)[index] for f in fields(self) if f.name not in shared
        }
        return StepData(
            contacts=self.contacts[index],
            h=self.h,
            **{name: getattr(self, name) for name in shared[2:]},
            **tensors,
        )

    def first_steps(self) -> StepData:
        """The windows cut to their first step."""
        return dataclasses.replace(
            self, u=self.u[:, :1], target=self.target[:, :1], robot_target=self.robot_target[:, :1]
        )

    def to(self, device: torch.device | str) -> StepData:
        """The windows on ``device``."""
        moved = {
            f.name: getattr(self, f.name).to(device)
            for f in fields(self)
            if f.name not in ("contacts", "h")
        }
        return StepData(contacts=self.contacts.to(device), h=self.h, **moved)


def model_terms(
    model: ComplementarityFree, Q: torch.Tensor, b0: torch.Tensor, B: torch.Tensor, u, object_rows
) -> tuple[torch.Tensor, torch.Tensor]:
    """``Q`` and ``b = b0 + B·u`` of an affine system (``Q, b0 (..., nv)``, ``B (nv, nu)``,
    ``u (..., nu)``), through the model's calibration when it has one (differentiable in its
    factors; ``object_rows``: the objects' indices in v)."""
    if model.calibration is None:
        return Q, b0 + u @ B.mT
    return model.calibration.terms(Q, b0, B, u, object_rows)


def carried(model: ComplementarityFree, Q, b, displacement, object_rows):
    """``Q, b`` with the object's momentum carried (:func:`~torchcontact.systems.carry_momentum`)
    when the model's calibration has it, else as they are."""
    momentum = None if model.calibration is None else model.calibration.momentum
    if momentum is None:
        return Q, b
    return carry_momentum(Q, b, displacement, momentum.to(Q.dtype), object_rows)


def step_terms(model: ComplementarityFree, data: StepData) -> tuple[torch.Tensor, torch.Tensor]:
    """``Q (N, 1, nv)`` and ``b (N, H, nv)`` of the windows (:func:`model_terms`)."""
    metric, bias = data.metric[:, None], data.bias[:, None]
    return model_terms(model, metric, bias, data.B, data.u, data.object_rows)


Geometry = Callable[[torch.Tensor], Contacts]
"""An object's contact geometry: ``q (..., nq) ↦`` :class:`Contacts` of batch shape ``...``,
differentiable in q (a :class:`~torchcontact.geometry.SceneGeometry`)."""

Geometries = Sequence[Geometry] | Mapping[int, Geometry]
"""Each object's geometry by its index in ``meta["objects"]`` (:attr:`StepData.objects`)."""


def predict(
    model: ComplementarityFree, data: StepData, geometries: Geometries | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Object poses ``(N, H, n_obj, 7)`` and robot coordinates ``(N, H, n_r)`` after each
    step of ``data``'s windows under ``model``, contacts frozen at each window's first state.

    With ``geometries``, every step after a window's first sees the contacts of its object's
    geometry at the state predicted so far (the predicted object poses and robot coordinates
    put into the window's first q; differentiable through the geometry), padded to
    ``data``'s slots, with K and D at that state; the first step keeps the recorded contacts.
    """
    Q, b = step_terms(model, data)
    frozen = model.freeze(data.contacts, data.h, data.q, without_residual=True)
    residual = model.residual
    n_obj = data.pose.shape[-2]
    layout = JointLayout(["free"] * n_obj)
    pose, robot, poses, robots = data.pose.flatten(-2), data.robot, [], []
    moved, q = data.displacement, data.q
    groups = None if geometries is None else _object_groups(data, geometries)
    for t in range(data.horizon):
        terms = carried(model, Q[:, 0], b[:, t], moved, data.object_rows)
        if groups is None or t == 0:
            v = frozen.velocity(*terms)
        else:
            v = _geometry_velocity(model, data, groups, q, *terms)
        if residual is not None:  # the residual sees each step's state, the contacts stay
            v = residual(q, terms[1], v, data.h)
        moved = data.h * v[:, data.object_rows]
        pose = integrate(pose, v[:, data.object_rows], data.h, layout)
        robot = robot + data.h * v[:, data.robot_rows]
        if residual is not None:
            q = q.index_copy(-1, residual.object_q.flatten(), pose)
            q = q.index_copy(-1, residual.other_q, robot)
        elif groups is not None:
            q = q.index_copy(-1, data.object_q, pose).index_copy(-1, data.robot_q, robot)
        poses.append(pose.unflatten(-1, (n_obj, 7)))
        robots.append(robot)
    return torch.stack(poses, dim=1), torch.stack(robots, dim=1)


def _object_groups(data: StepData, geometries: Geometries) -> list[tuple[Geometry, torch.Tensor]]:
    """``(geometry, rows)`` per object among ``data``'s windows: its geometry and the indices
    of its windows."""
    groups = []
    for index in torch.unique(data.objects).tolist():
        rows = torch.nonzero(data.objects == index).flatten()
        groups.append((_geometry(geometries, index), rows))
    return groups


def _geometry(geometries: Geometries, index: int) -> Geometry:
    """Object ``index``'s geometry, or ``ValueError`` naming the missing object."""
    if isinstance(geometries, Mapping):
        if index not in geometries:
            raise ValueError(f"geometries must hold object {index}, got {sorted(geometries)}")
        return geometries[index]
    if not 0 <= index < len(geometries):
        raise ValueError(f"geometries must hold object {index}, got {len(geometries)} objects")
    return geometries[index]


def _geometry_velocity(model, data: StepData, groups, q, Q, b) -> torch.Tensor:
    """``v⁺ (N, nv)`` at states ``q (N, nq)``: per object, its geometry's contacts at its
    windows' states, the step frozen there, its velocity under ``Q, b (N, nv)``; the objects'
    velocities put back in the windows' order (each geometry has its own slot count)."""
    v = b.new_zeros(b.shape)
    Q = Q.expand(b.shape[0], *Q.shape[1:])
    for geometry, rows in groups:
        states = q[rows]
        contacts = geometry(states).padded(data.contacts.slots)
        step = model.freeze(contacts, data.h, states, without_residual=True)
        v = v.index_copy(0, rows, step.velocity(Q[rows], b[rows]))
    return v


def predict_poses(model: ComplementarityFree, data: StepData) -> torch.Tensor:
    """Object poses ``(N, H, n_obj, 7)`` of :func:`predict`."""
    return predict(model, data)[0]


def window_loss(
    model: ComplementarityFree,
    data: StepData,
    weights,
    robot_weight: float = 0.0,
    geometries: Geometries | None = None,
):
    """:func:`pose_loss` of the predicted objects, plus ``robot_weight`` times the mean squared
    error of the robot's coordinates [m² or rad²] (the only term that sees the robot's
    stiffness: unopposed by contact, its command gain alone moves it). ``geometries``: the
    contacts re-evaluated along the windows (:func:`predict`)."""
    poses, robot = predict(model, data, geometries)
    loss = pose_loss(poses, data.target, weights)
    if robot_weight:
        loss = loss + robot_weight * (robot - data.robot_target).square().sum(-1).mean()
    return loss


def _complement(index: torch.Tensor, size: int) -> torch.Tensor:
    """The indices of ``range(size)`` not in ``index``."""
    keep = torch.ones(size, dtype=torch.bool)
    keep[index] = False
    return torch.nonzero(keep).flatten()


def pose_errors(pose: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Position error ``‖p − p*‖`` [m] and quaternion error ``1 − ⟨q, q*⟩²`` of poses
    ``(..., 7)``, each ``(...)``."""
    position = position_cost(pose[..., :3], target[..., :3]).sqrt()
    return position, quaternion_error(pose[..., 3:], target[..., 3:]).clamp_min(0.0)


def pose_loss(pose: torch.Tensor, target: torch.Tensor, weights: tuple[float, float]):
    """Mean of ``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)`` over poses ``(..., 7)``: the MPC's final
    cost terms."""
    position = position_cost(pose[..., :3], target[..., :3])
    quaternion = quaternion_error(pose[..., 3:], target[..., 3:])
    return (weights[0] * position + weights[1] * quaternion).mean()


@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Attributes:
        model: the fitted model, holding the best validation state.
        history: per epoch ``{"epoch", "train_loss", "val_loss"}``.
        best_epoch: the epoch whose state was kept (0: the initial model).
        val_loss: its validation loss.
        seconds: wall time of the training loop.
        config: the fit's settings (:func:`fit`: those that rebuild ``model``).
        meta: what rebuilds ``model`` with ``config``
            (:func:`~torchcontact.checkpoint.build_model`), set by :func:`fit`; None from
            :func:`fit_steps`, whose windows carry their dataset's.
        manifest: the fit's record for :func:`~torchcontact.checkpoint.save_model`: data
            sizes, settings, validation figures (set by :func:`fit`).
    """

    model: ComplementarityFree
    history: list[dict]
    best_epoch: int
    val_loss: float
    seconds: float
    config: FitConfig | None = None
    meta: dict | None = None
    manifest: dict | None = None


def _evaluate_loss(
    model, data: StepData, weights, robot_weight, batch: int = 8192, geometries=None
) -> float:
    total = 0.0
    with torch.no_grad():
        for start in range(0, len(data), batch):
            part = data.select(torch.arange(start, min(start + batch, len(data))))
            loss = window_loss(model, part, weights, robot_weight, geometries)
            total += float(loss) * len(part)
    return total / max(len(data), 1)


def fit_steps(
    model: ComplementarityFree,
    train: StepData,
    val: StepData,
    weights: tuple[float, float],
    config: FitConfig,
    progress: bool = True,
    geometries: Geometries | None = None,
) -> FitResult:
    """Train ``model``'s parameters on ``train`` by Adam on :func:`window_loss` mini-batches,
    in ``train``'s dtype and on its device.

    Stops after ``config.epochs`` or ``config.patience`` epochs without a better loss on
    ``val``; the model is left holding its best validation state. ``geometries``: each
    object's contact geometry (by :attr:`StepData.objects`), required with
    ``config.loss_contacts == "geometry"`` and refused otherwise; those that are modules are
    moved to ``train``'s dtype and device.
    """
    if len(train) == 0 or len(val) == 0:
        raise ValueError(f"train and val must be non-empty, got {len(train)} and {len(val)}")
    parameters = [p for p in model.parameters() if p.requires_grad]
    if not parameters:
        raise ValueError("model has no learnable parameters")
    geometries = _fit_geometries(config, geometries, train, val)
    model = model.to(device=train.q.device, dtype=train.q.dtype)
    robot_weight = config.robot_weight
    with validate_args(False):
        return adam_with_early_stopping(
            model,
            torch.optim.Adam(parameters, lr=config.lr),
            len(train),
            lambda rows: window_loss(model, train.select(rows), weights, robot_weight, geometries),
            lambda: _evaluate_loss(model, val, weights, robot_weight, geometries=geometries),
            config,
            progress,
        )


def _fit_geometries(config: FitConfig, geometries, train: StepData, val: StepData):
    """``geometries`` checked against ``config.loss_contacts`` and the windows' objects, the
    modules among them in ``train``'s dtype and on its device (None for frozen contacts)."""
    if config.loss_contacts != "geometry":
        if geometries is not None:
            raise ValueError(
                f"geometries are used only with config.loss_contacts 'geometry', got "
                f"{config.loss_contacts!r}"
            )
        return None
    if geometries is None:
        raise ValueError(
            "config.loss_contacts is 'geometry': geometries must give each object's contact "
            "geometry"
        )
    kw = {"device": train.q.device, "dtype": train.q.dtype}
    items = geometries.items() if isinstance(geometries, Mapping) else enumerate(geometries)
    moved = {k: g.to(**kw) if isinstance(g, torch.nn.Module) else g for k, g in items}
    for data in (train, val):
        for index in torch.unique(data.objects).tolist():
            _geometry(moved, index)
    return moved


def adam_with_early_stopping(
    module: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    count: int,
    batch_loss,
    val_loss,
    config: FitConfig,
    progress: bool = True,
    batch_size: int | None = None,
    desc: str = "fit",
) -> FitResult:
    """The training loop of every fit: per epoch, ``optimizer`` steps on ``batch_loss(rows)``
    over ``count`` examples shuffled (seeded by ``config.seed``) in batches of ``batch_size``
    (default ``config.batch_size``); stops after ``config.epochs``, or ``config.patience``
    epochs without a lower ``val_loss()``, and leaves ``module`` in its best validation
    state. The result's ``model`` is ``module``."""
    batch_size = config.batch_size if batch_size is None else batch_size
    generator = torch.Generator().manual_seed(config.seed)
    start = time.perf_counter()
    best = val_loss()
    best_state, best_epoch, history = copy.deepcopy(module.state_dict()), 0, []
    bar = tqdm(range(1, config.epochs + 1), desc=desc, disable=not progress, unit="epoch")
    for epoch in bar:
        order = torch.randperm(count, generator=generator)
        running = 0.0
        for first in range(0, count, batch_size):
            rows = order[first : first + batch_size]
            loss = batch_loss(rows)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            running += loss.item() * len(rows)
        current = val_loss()
        history.append({"epoch": epoch, "train_loss": running / count, "val_loss": current})
        bar.set_postfix(train=f"{running / count:.3g}", val=f"{current:.3g}")
        if current < best:
            best, best_epoch = current, epoch
            best_state = copy.deepcopy(module.state_dict())
        elif epoch - best_epoch >= config.patience:
            break
    module.load_state_dict(best_state)
    seconds = time.perf_counter() - start
    return FitResult(module, history, best_epoch, best, seconds, config)


def tensor_meta(
    model: ComplementarityFree,
    contacts: Contacts,
    system: QuasiDynamic,
    h: float,
    joints: Sequence[str],
    weights: tuple[float, float] = (500.0, 5.0),
    scene: str | None = None,
    initial_stiffness: float = 1.0,
) -> dict:
    """The dataset ``meta`` of plain tensors (the keys of :data:`~torchcontact.checkpoint
    .META_KEYS` and the system's), what :func:`~torchcontact.checkpoint.build_model` rebuilds
    ``model`` from: γ and facets of ``model``, the slots of ``contacts``, the layout of
    ``joints``, ``system``'s Q, b0 and B, ``h`` [s]. ``scene``: the environment the data
    come from (None: a user's robot); ``initial_stiffness``: K [N/m] of a config naming none."""
    layout = JointLayout(joints)
    header = system_header(system)
    return {
        "scene": scene,
        "h": float(h),
        "gamma": model.gamma,
        "facets": model.facets,
        "paper_stiffness": float(initial_stiffness),
        "joints": list(layout.joints),
        "pose_weights": [float(w) for w in weights],
        "system": header,
        "nq": layout.nq,
        "nv": layout.nv,
        "nu": len(header["B"][0]),
        "slots": contacts.slots,
    }


def fit(
    model: ComplementarityFree | None,
    q: torch.Tensor,
    u: torch.Tensor,
    q_next: torch.Tensor,
    contacts: Contacts,
    system: QuasiDynamic,
    h: float,
    joints: list[str],
    config: FitConfig | None = None,
    weights: tuple[float, float] = (500.0, 5.0),
    val_fraction: float = 0.2,
    progress: bool = True,
    displacement: torch.Tensor | None = None,
    scene: str | None = None,
) -> FitResult:
    """Fit ``model`` to transitions given as plain tensors: no dataset folder or manifest.

    See :meth:`StepData.from_tensors` for the arguments (``displacement`` for a model whose
    calibration carries the object's momentum); a random ``val_fraction`` of the rows
    (seeded by ``config.seed``) is held out for early stopping; ``weights``: the pose loss's
    (w_p, w_q). The loss is one-step: a ``config.loss_horizon`` above 1 needs consecutive
    rows, :meth:`StepData.from_transitions` and :func:`fit_steps`.

    ``model`` None: built from ``config`` (:func:`~torchcontact.checkpoint.build_model`, K
    started at ``config.initial_stiffness``, else 1 N/m), so that the result saves with
    :func:`~torchcontact.checkpoint.save_model`; a given model saves only when ``config``
    rebuilds it. ``scene``: the environment whose ``--learned`` takes the saved model (None:
    a user's robot). The result's ``meta`` (:func:`tensor_meta`) and ``manifest`` (the data
    sizes, the settings and the validation figures: loss, mean one-step position error [mm]
    of the fitted model and of holding still) are what :func:`save_model` writes.
    """
    config = FitConfig() if config is None else config
    if not isinstance(config, FitConfig):
        raise TypeError(f"config must be a FitConfig, got {type(config).__name__}")
    if not 0 < val_fraction < 1:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction!r}")
    if config.loss_horizon != 1:
        raise ValueError(f"config.loss_horizon must be 1 for plain rows, got {config.loss_horizon}")
    if model is None:
        model = ComplementarityFree()  # only its γ and facets enter the meta
        meta = tensor_meta(model, contacts, system, h, joints, weights, scene)
        model = build_model(config, meta)
    elif isinstance(model, ComplementarityFree):
        meta = tensor_meta(model, contacts, system, h, joints, weights, scene, _start(model))
    else:
        raise TypeError(f"model must be a ComplementarityFree or None, got {type(model).__name__}")
    data = StepData.from_tensors(
        q, u, q_next, contacts, system, h, joints, displacement=displacement
    )
    order = torch.randperm(len(data), generator=torch.Generator().manual_seed(config.seed))
    held = max(1, int(round(val_fraction * len(data))))
    if held >= len(data):
        raise ValueError(f"q must have at least 2 rows to split, got {len(data)}")
    train, val = data.select(order[held:]), data.select(order[:held])
    result = fit_steps(model, train, val, weights, config, progress)
    result.meta = meta
    result.manifest = {
        "dataset": {"transitions": len(data), "train": len(train), "val": len(val)},
        "fit": {
            **dataclasses.asdict(config),
            "best_epoch": result.best_epoch,
            "epochs_run": len(result.history),
            "seconds": round(result.seconds, 3),
        },
        "validation": {"val_loss": result.val_loss, **_one_step_figures(result.model, val)},
    }
    return result


def _start(model: ComplementarityFree) -> float:
    """The K [N/m] a constant-K model holds (for the meta's initial K); 1 for others: a
    network's start does not enter its rebuilt architecture."""
    value = getattr(model.stiffness, "value", None)
    return float(value) if isinstance(value, (int, float)) and value > 0 else 1.0


def _one_step_figures(model: ComplementarityFree, data: StepData) -> dict:
    """Mean one-step object position error [mm] on ``data`` of ``model`` and of holding
    still (the pose unchanged), and the model's mean quaternion error ``1 − ⟨q, q*⟩²``."""
    with torch.no_grad():
        pose = predict_poses(model, data)[:, 0]
    position, quaternion = pose_errors(pose, data.target[:, 0])
    still, _ = pose_errors(data.pose, data.target[:, 0])
    return {
        "position_error_mm": 1000 * float(position.mean()),
        "quaternion_error": float(quaternion.mean()),
        "hold_still_position_error_mm": 1000 * float(still.mean()),
    }
