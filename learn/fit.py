"""Fit the contact stiffness K(q) and damping D(q) of the complementarity-free model to data.

The model is the scene's :class:`~torchcontact.model.ComplementarityFree` with learnable
sub-modules; the loss is the one-step object pose error against MuJoCo, weighted as in the
MPC's final cost, ``w_p‖p − p*‖² + w_q(1 − ⟨q, q*⟩²)`` (the paper's w_p = 500 or 100,
w_q = 5). Only λ depends on K and D, so everything else of the step is computed once
(:class:`StepData`): per transition the row gaps ``J̃Q⁻¹b``, the row distances φ̃, the
contact-free object velocity ``(Q⁻¹b)ₒ/h`` and the object rows of ``Q⁻¹J̃ᵀ/h``; a training
step is then ``λ = softplus_γ(−K(J̃Q⁻¹b + φ̃) − D·J̃Q⁻¹b/h)``, ``vₒ = (Q⁻¹b)ₒ/h + (Q⁻¹J̃ᵀ)ₒλ/h``
and the object's pose update, on float32 mini-batches (Adam, early stopping on a validation
split, the best state kept). :mod:`torchcontact.checkpoint` stores the fitted model with the
:class:`~torchcontact.checkpoint.FitConfig` and dataset metadata that rebuild it.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, fields

import torch
from tqdm.auto import tqdm

from torchcontact.checkpoint import FitConfig
from torchcontact.contacts import Contacts
from torchcontact.environments.costs import position_cost
from torchcontact.functional import softplus
from torchcontact.integrate import JOINT_SIZES, JointLayout, integrate
from torchcontact.learn.data import Transitions
from torchcontact.model import ComplementarityFree
from torchcontact.rotations import quaternion_error
from torchcontact.systems import QuasiDynamic
from torchcontact.validation import validate_args


def system_terms(meta: dict, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``Q (nv,)`` and ``b (..., nv) = b0 + B·u`` of the dataset's quasi-dynamic system."""
    system = meta["system"]
    kw = {"dtype": u.dtype, "device": u.device}
    B = torch.tensor(system["B"], **kw)
    b = torch.tensor(system["b0"], **kw) + u @ B.T
    return torch.tensor(system["Q"], **kw), b


def object_indices(joints: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices ``(n_obj, 7)`` in q and ``(n_obj, 6)`` in v of the free joints (the objects)."""
    iq = iv = 0
    q_index, v_index = [], []
    for joint in JointLayout(joints).joints:
        if joint == "free":
            q_index.append(list(range(iq, iq + 7)))
            v_index.append(list(range(iv, iv + 6)))
        iq, iv = iq + JOINT_SIZES[joint][0], iv + JOINT_SIZES[joint][1]
    if not q_index:
        raise ValueError(f"joints must include a free joint (the object), got {joints}")
    return torch.tensor(q_index), torch.tensor(v_index)


@dataclass
class StepData:
    """The K-independent pieces of the CF step for N transitions (row ``i`` = one step).

    Attributes:
        q: ``(N, nq)`` state, for state-dependent K.
        contacts: :class:`Contacts` ``(N, ...)``, for contact-dependent K.
        gap: ``(N, m)`` J̃Q⁻¹b, each row's distance change without contact [m].
        phi: ``(N, m)`` row distances φ̃ [m].
        free: ``(N, n_obj·6)`` object velocity without contact ``(Q⁻¹b)ₒ/h``.
        response: ``(N, n_obj·6, m)`` ``(Q⁻¹J̃ᵀ)ₒ/h``: object velocity per unit λ.
        pose: ``(N, n_obj, 7)`` object poses at q; target: ``(N, n_obj, 7)`` recorded next.
        h: the model's time step [s].
    """

    q: torch.Tensor
    contacts: Contacts
    gap: torch.Tensor
    phi: torch.Tensor
    free: torch.Tensor
    response: torch.Tensor
    pose: torch.Tensor
    target: torch.Tensor
    h: float

    @classmethod
    def from_transitions(
        cls, transitions: Transitions, facets: int, dtype: torch.dtype = torch.float32
    ) -> StepData:
        """Precompute from :class:`~torchcontact.learn.data.Transitions` (in float64, then
        stored as ``dtype``)."""
        meta = transitions.meta
        Q, b = system_terms(meta, transitions.u.to(torch.float64))
        rows = (transitions.q, transitions.q_next, transitions.contacts)
        return cls._precompute(*rows, Q, b, float(meta["h"]), meta["joints"], facets, dtype)

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
        facets: int = 4,
        dtype: torch.dtype = torch.float32,
    ) -> StepData:
        """Precompute from plain tensors: no dataset folder or manifest.

        Args:
            q: ``(N, nq)`` states; u: ``(N, n_robot)`` controls; q_next: ``(N, nq)`` the
                states one step of ``h`` [s] later (all in the layout of ``joints``).
            contacts: :class:`Contacts` ``(N, ...)`` detected at ``q``.
            system: the quasi-dynamic system ``u ↦ (Q, b)`` of the model.
            joints: joint types of q (``"free"`` for the object, see
                :class:`~torchcontact.integrate.JointLayout`).
            facets: facets of the model's friction cones.
        """
        n = q.shape[0]
        for name, value in (("u", u), ("q_next", q_next)):
            if value.shape[0] != n:
                raise ValueError(f"{name} must have {n} rows like q, got {tuple(value.shape)}")
        if contacts.phi.shape[0] != n:
            raise ValueError(f"contacts must have {n} rows like q, got {contacts.phi.shape[0]}")
        Q, b = system(u.to(torch.float64))
        rows = (q, q_next, contacts)
        return cls._precompute(*rows, Q.to(torch.float64), b, h, joints, facets, dtype)

    @classmethod
    def _precompute(cls, q, q_next, contacts, Q, b, h, joints, facets: int, dtype) -> StepData:
        """The pieces of :class:`StepData` from the rows ``q``, ``q_next`` and ``contacts``,
        ``Q (nv,)`` and ``b (N, nv)`` in float64."""
        q_index, v_index = object_indices(joints)
        with validate_args(False):
            jac, phi, _ = contacts.to(torch.float64).dual_rows(facets)
        free = b / Q  # Q⁻¹b (N, nv)
        gap = (jac @ free.unsqueeze(-1)).squeeze(-1)
        rows = v_index.flatten()
        response = jac[..., rows].mT / Q[rows, None] / h
        return cls(
            q=q.to(dtype),
            contacts=contacts.to(dtype),
            gap=gap.to(dtype),
            phi=phi.to(dtype),
            free=(free[:, rows] / h).to(dtype),
            response=response.to(dtype),
            pose=q[:, q_index].to(dtype),
            target=q_next[:, q_index].to(dtype),
            h=float(h),
        )

    def __len__(self) -> int:
        return self.q.shape[0]

    def select(self, index: torch.Tensor) -> StepData:
        """Rows ``index`` (long indices or a bool mask)."""
        tensors = {
            f.name: getattr(self, f.name)[index]
            for f in fields(self)
            if f.name not in ("contacts", "h")
        }
        return StepData(contacts=self.contacts[index], h=self.h, **tensors)


def fit_tensors(
    model: ComplementarityFree,
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
) -> FitResult:
    """Fit ``model`` to transitions given as plain tensors (see :meth:`StepData.from_tensors`
    for the arguments), holding out a random ``val_fraction`` of the rows (seeded by
    ``config.seed``) for early stopping; ``weights``: the pose loss's (w_p, w_q)."""
    config = FitConfig() if config is None else config
    if not 0 < val_fraction < 1:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction!r}")
    data = StepData.from_tensors(q, u, q_next, contacts, system, h, joints, model.facets)
    order = torch.randperm(len(data), generator=torch.Generator().manual_seed(config.seed))
    held = max(1, int(round(val_fraction * len(data))))
    if held >= len(data):
        raise ValueError(f"q must have at least 2 rows to split, got {len(data)}")
    train, val = data.select(order[held:]), data.select(order[:held])
    return fit(model, train, val, weights, config, progress)


def predict_poses(model: ComplementarityFree, data: StepData) -> torch.Tensor:
    """Object poses ``(N, n_obj, 7)`` one step after ``data``'s states under ``model``."""
    K, D = model.coefficients(data.contacts, data.q)
    argument = -K * (data.gap + data.phi)
    if D is not None:
        argument = argument - D * data.gap / data.h
    lam = softplus(argument, model.gamma)
    velocity = data.free + (data.response @ lam.unsqueeze(-1)).squeeze(-1)
    n_obj = data.pose.shape[-2]
    layout = JointLayout(["free"] * n_obj)
    poses = integrate(data.pose.flatten(-2), velocity, data.h, layout)
    return poses.unflatten(-1, (n_obj, 7))


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
    """

    model: ComplementarityFree
    history: list[dict]
    best_epoch: int
    val_loss: float
    seconds: float


def _evaluate_loss(model, data: StepData, weights, batch: int = 8192) -> float:
    total = 0.0
    with torch.no_grad():
        for start in range(0, len(data), batch):
            part = data.select(torch.arange(start, min(start + batch, len(data))))
            total += float(pose_loss(predict_poses(model, part), part.target, weights)) * len(part)
    return total / max(len(data), 1)


def fit(
    model: ComplementarityFree,
    train: StepData,
    val: StepData,
    weights: tuple[float, float],
    config: FitConfig,
    progress: bool = True,
) -> FitResult:
    """Train ``model``'s parameters on ``train`` by Adam on :func:`pose_loss` mini-batches.

    Stops after ``config.epochs`` or ``config.patience`` epochs without a better loss on
    ``val``; the model is left holding its best validation state.
    """
    if len(train) == 0 or len(val) == 0:
        raise ValueError(f"train and val must be non-empty, got {len(train)} and {len(val)}")
    parameters = [p for p in model.parameters() if p.requires_grad]
    if not parameters:
        raise ValueError("model has no learnable parameters")
    dtype = train.gap.dtype
    model = model.to(dtype)
    optimizer = torch.optim.Adam(parameters, lr=config.lr)
    generator = torch.Generator().manual_seed(config.seed)
    start = time.perf_counter()
    with validate_args(False):
        best = _evaluate_loss(model, val, weights)
        best_state, best_epoch, history = copy.deepcopy(model.state_dict()), 0, []
        bar = tqdm(range(1, config.epochs + 1), desc="fit", disable=not progress, unit="epoch")
        for epoch in bar:
            order = torch.randperm(len(train), generator=generator)
            running = 0.0
            for first in range(0, len(train), config.batch_size):
                batch = train.select(order[first : first + config.batch_size])
                loss = pose_loss(predict_poses(model, batch), batch.target, weights)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                running += loss.item() * len(batch)
            val_loss = _evaluate_loss(model, val, weights)
            history.append(
                {"epoch": epoch, "train_loss": running / len(train), "val_loss": val_loss}
            )
            bar.set_postfix(train=f"{running / len(train):.3g}", val=f"{val_loss:.3g}")
            if val_loss < best:
                best, best_epoch = val_loss, epoch
                best_state = copy.deepcopy(model.state_dict())
            elif epoch - best_epoch >= config.patience:
                break
    model.load_state_dict(best_state)
    return FitResult(model, history, best_epoch, best, time.perf_counter() - start)
