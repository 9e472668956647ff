"""Contact detection: MuJoCo collisions → :class:`~torchcontact.contacts.Contacts`."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import mujoco
import numpy as np
import torch

from torchcontact.contacts import PAD_DISTANCE, Contacts
from torchcontact.validation import checking_values

OVERFLOW_POLICIES = ("error", "deepest")


def _body_id(model: mujoco.MjModel, body: str | int) -> int:
    if isinstance(body, (int, np.integer)):
        if not 0 <= int(body) < model.nbody:
            raise ValueError(f"body id must be in [0, {model.nbody}), got {body}")
        return int(body)
    index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
    if index < 0:
        raise ValueError(f"no body named {body!r} in the model")
    return index


class ContactDetector:
    """Collision detection for the contact pairs a scene declares, at a fixed slot count.

    Keeps only contacts that involve one of ``bodies`` (e.g. the manipulated object against
    the robot and the ground; robot–robot contacts are dropped), minus ``exclude`` pairs.
    Detection runs on a private copy of the model whose relevant geoms get ``margin``, so
    contacts up to that distance are seen without changing the simulated plant.

    Every row's sign is fixed by MuJoCo's contact frame, whose normal points from geom1 to
    geom2: ``Jⁿ = nᵀ(J_geom2 − J_geom1)`` at the contact point, so ``Jⁿv > 0`` opens the gap
    whichever geom MuJoCo lists first.

    Args:
        model: the scene's ``MjModel`` (copied, not modified).
        bodies: names or ids of the bodies whose contacts are modelled; a single name (a
            string) or id stands for that one body.
        slots: contact slots nc in the output (padding marked inactive).
        mu: friction coefficient override; None takes MuJoCo's combined sliding friction.
        margin: detection distance [m] for the relevant geoms; None keeps the model's.
        exclude: pairs of body names/ids whose mutual contacts are dropped.
        per_pair: at most this many contacts per pair of bodies (None: all), chosen to span
            the contact patch: the deepest, then each time the one farthest from those kept.
            A convex-decomposed object resting on the ground touches it in dozens of points
            while a patch is spanned by four; every row carries a force (softplus floor, K per
            row), so without this the model's support force grows with the decomposition
            (36 ground contacts lift a resting 10 g cup 2 cm per 0.1 s step).
        overflow: ``"error"`` raises when more contacts than ``slots`` are found;
            ``"deepest"`` keeps the ``slots`` smallest distances (documented truncation).
        dtype, device: of the returned tensors.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        bodies: Sequence[str | int] | str | int,
        slots: int,
        mu: float | None = None,
        margin: float | None = None,
        exclude: Sequence[tuple[str | int, str | int]] = (),
        overflow: str = "error",
        per_pair: int | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ):
        if not isinstance(slots, int) or slots < 0:
            raise ValueError(f"slots must be a non-negative integer, got {slots!r}")
        if per_pair is not None and not (isinstance(per_pair, int) and per_pair >= 1):
            raise ValueError(f"per_pair must be a positive integer or None, got {per_pair!r}")
        if mu is not None and not (np.isfinite(mu) and mu >= 0):
            raise ValueError(f"mu must be a non-negative finite number or None, got {mu!r}")
        if margin is not None and not (np.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be a non-negative finite number or None, got {margin!r}")
        if overflow not in OVERFLOW_POLICIES:
            raise ValueError(f"overflow must be one of {OVERFLOW_POLICIES}, got {overflow!r}")
        if isinstance(bodies, (str, int, np.integer)):
            bodies = [bodies]
        if not bodies:
            raise ValueError("bodies must name at least one body whose contacts are modelled")
        self.model = copy.deepcopy(model)
        self.data = mujoco.MjData(self.model)
        self.bodies = frozenset(_body_id(model, b) for b in bodies)
        self.exclude = frozenset(
            frozenset((_body_id(model, a), _body_id(model, b))) for a, b in exclude
        )
        if margin is not None:
            relevant = np.isin(self.model.geom_bodyid, list(self.bodies))
            self.model.geom_margin[relevant] = margin
        self.slots, self.mu, self.overflow, self.per_pair = slots, mu, overflow, per_pair
        self.dtype = dtype or torch.get_default_dtype()
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        self._jacp = np.zeros((3, model.nv))
        self.found: int | np.ndarray = 0
        """Relevant contacts found by the last detection (after ``per_pair``, before any
        ``"deepest"`` truncation): an ``int`` for one state (``qpos (nq,)`` or
        :meth:`from_data`), an integer array of the batch shape ``...`` for ``qpos (..., nq)``
        (the count of each state, so ``found.max()`` is the most any state needs)."""

    def __call__(self, qpos) -> Contacts:
        """Contacts at ``qpos: (nq,)`` or a batch ``(..., nq)`` (array or tensor).

        Sets :attr:`found`. Raises ``ValueError`` naming ``qpos`` when its shape is wrong or,
        with value checks on (:func:`~torchcontact.validation.set_validate_args`), it holds NaN
        or Inf.
        """
        qpos = np.asarray(
            qpos.detach().cpu() if isinstance(qpos, torch.Tensor) else qpos, dtype=np.float64
        )
        if qpos.ndim == 0 or qpos.shape[-1] != self.model.nq:
            raise ValueError(f"qpos must have shape (..., {self.model.nq}), got {qpos.shape}")
        if checking_values() and not np.isfinite(qpos).all():
            raise ValueError("qpos must be finite, got NaN or Inf")
        flat = qpos.reshape(-1, self.model.nq)
        arrays, found = [], []
        for q in flat:
            arrays.append(self._detect(q))
            found.append(self.found)
        if qpos.ndim > 1:
            self.found = np.array(found, dtype=int).reshape(qpos.shape[:-1])
        padding = self._padding(self.model.nv)
        batched = {
            key: (np.stack([a[key] for a in arrays]) if arrays else value[None][:0]).reshape(
                *qpos.shape[:-1], *value.shape
            )
            for key, value in padding.items()
        }
        return self._to_contacts(batched)

    def _detect(self, qpos: np.ndarray) -> dict[str, np.ndarray]:
        m, d = self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_collision(m, d)
        return self._extract(m, d)

    def from_data(self, data: mujoco.MjData) -> Contacts:
        """Contacts from ``data`` whose collisions are already computed (``mj_forward``).

        Uses ``data``'s own contact list (and so the plant model's margins).
        """
        return self._to_contacts(self._extract(self.model, data))

    def _relevant(self, m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
        geoms = d.contact.geom[: d.ncon]
        body1 = m.geom_bodyid[geoms[:, 0]]
        body2 = m.geom_bodyid[geoms[:, 1]]
        keep = np.array(
            [
                (b1 in self.bodies or b2 in self.bodies) and frozenset((b1, b2)) not in self.exclude
                for b1, b2 in zip(body1, body2, strict=True)
            ],
            dtype=bool,
        )
        kept = np.flatnonzero(keep)
        if self.per_pair is None:
            return kept
        pairs = np.stack([np.minimum(body1, body2), np.maximum(body1, body2)], axis=1)[kept]
        chosen = [
            self._spanning(d, kept[(pairs == pair).all(axis=1)])
            for pair in np.unique(pairs, axis=0)
        ]
        return np.sort(np.concatenate(chosen)) if chosen else kept

    def _spanning(self, d: mujoco.MjData, indices: np.ndarray) -> np.ndarray:
        """At most :attr:`per_pair` of one body pair's contacts ``indices``: the deepest, then
        repeatedly the contact farthest from those already chosen (farthest-point sampling)."""
        if len(indices) <= self.per_pair:
            return indices
        points = d.contact.pos[indices]
        chosen = [int(np.argmin(d.contact.dist[indices]))]
        gap = np.linalg.norm(points - points[chosen[0]], axis=1)
        while len(chosen) < self.per_pair and gap.max() > 0:  # coincident points add nothing
            chosen.append(int(np.argmax(gap)))
            gap = np.minimum(gap, np.linalg.norm(points - points[chosen[-1]], axis=1))
        return indices[chosen]

    def _extract(self, m: mujoco.MjModel, d: mujoco.MjData) -> dict[str, np.ndarray]:
        kept = self._relevant(m, d)
        self.found = len(kept)
        if len(kept) > self.slots:
            if self.overflow == "error":
                raise ValueError(
                    f"{len(kept)} contacts found but slots={self.slots}: raise slots, or pass "
                    "overflow='deepest' to keep the deepest ones"
                )
            kept = kept[np.argsort(d.contact.dist[kept], kind="stable")[: self.slots]]
        out = self._padding(m.nv)
        for slot, i in enumerate(kept):
            contact = d.contact[i]
            frame = contact.frame.reshape(3, 3)  # rows: normal (geom1 → geom2), t₁, t₂
            relative = self._point_jacobian(
                m, d, contact.geom2, contact.pos
            ) - self._point_jacobian(m, d, contact.geom1, contact.pos)
            rows = frame @ relative
            out["phi"][slot] = contact.dist
            out["jac_normal"][slot] = rows[0]
            out["jac_tangent"][slot] = rows[1:]
            out["mu"][slot] = contact.friction[0] if self.mu is None else self.mu
            out["active"][slot] = True
            out["frame"][slot] = frame
            out["position"][slot] = contact.pos
            out["static"][slot] = self._is_static(m, contact.geom1) or self._is_static(
                m, contact.geom2
            )
        return out

    @staticmethod
    def _is_static(m: mujoco.MjModel, geom: int) -> bool:
        """Whether ``geom``'s body is welded to the world (no joint moves it)."""
        return bool(m.body_weldid[m.geom_bodyid[geom]] == 0)

    def _padding(self, nv: int) -> dict[str, np.ndarray]:
        """Arrays of ``slots`` empty slots (the layout of one state's contacts)."""
        nc = self.slots
        return {
            "phi": np.full(nc, PAD_DISTANCE),
            "jac_normal": np.zeros((nc, nv)),
            "jac_tangent": np.zeros((nc, 2, nv)),
            "mu": np.zeros(nc),
            "active": np.zeros(nc, dtype=bool),
            "frame": np.tile(np.eye(3), (nc, 1, 1)),
            "position": np.zeros((nc, 3)),
            "static": np.zeros(nc, dtype=bool),
        }

    def _point_jacobian(self, m, d, geom: int, point: np.ndarray) -> np.ndarray:
        mujoco.mj_jac(m, d, self._jacp, None, point, m.geom_bodyid[geom])
        return self._jacp.copy()

    def _to_contacts(self, arrays: dict[str, np.ndarray]) -> Contacts:
        def tensor(key):
            x = torch.from_numpy(np.ascontiguousarray(arrays[key]))
            if key in ("active", "static"):
                return x.to(self.device)
            return x.to(device=self.device, dtype=self.dtype)

        return Contacts(**{key: tensor(key) for key in arrays})
