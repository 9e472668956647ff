"""Input checks shared by the public entry points, in one place.

Checks that read tensor values (NaN, signs, positive definiteness) cost a device sync, so they
can be switched off for hot loops with :func:`set_validate_args`, as ``torch.distributions``
does. Shape checks are free and always run. No value is read while ``torch.compile`` traces,
under ``torch.func`` transforms, nor of ``meta`` tensors.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Iterator

import torch

_VALIDATE = True
_LOCAL = threading.local()  # .value: the innermost validate_args of this thread, if any


def set_validate_args(value: bool) -> None:
    """Turn value checks (NaN/Inf, signs, SPD) on or off globally."""
    global _VALIDATE
    _VALIDATE = bool(value)


@contextlib.contextmanager
def validate_args(value: bool) -> Iterator[None]:
    """Turn value checks on or off in this thread inside the block (over
    :func:`set_validate_args`); other threads keep theirs."""
    previous = getattr(_LOCAL, "value", None)
    _LOCAL.value = bool(value)
    try:
        yield
    finally:
        _LOCAL.value = previous


def _validating() -> bool:
    local = getattr(_LOCAL, "value", None)
    return _VALIDATE if local is None else local


def checking_values(*tensors: object) -> bool:
    """Whether value checks run now: not while compiling, nor under ``torch.func`` transforms
    (vmap), whose batched tensors cannot be read on the host, nor when any of ``tensors`` is a
    ``meta`` tensor (shapes without values)."""
    return (
        not torch.compiler.is_compiling()  # first: no thread-local read while tracing
        and _validating()
        and torch._C._functorch.maybe_current_level() is None
        and not any(isinstance(x, torch.Tensor) and x.is_meta for x in tensors)
    )


def _values(x: torch.Tensor | float) -> torch.Tensor:
    return x.detach() if isinstance(x, torch.Tensor) else torch.tensor(float(x))


def check_finite(name: str, x: torch.Tensor | float) -> None:
    """Raise ``ValueError`` naming ``name`` when ``x`` holds NaN or Inf."""
    if checking_values(x):
        _check_finite(name, _values(x))


def _check_finite(name: str, values: torch.Tensor) -> None:
    if not bool(torch.isfinite(values).all()):
        raise ValueError(f"{name} must be finite, got NaN or Inf")


def check_nonnegative(name: str, x: torch.Tensor | float) -> None:
    """Raise ``ValueError`` naming ``name`` when ``x`` is NaN, Inf or negative."""
    if not checking_values(x):  # nothing built: called in hot loops with checks off
        return
    values = _values(x)
    _check_finite(name, values)
    if values.numel() and bool((values < 0).any()):
        raise ValueError(f"{name} must be non-negative, got a minimum of {float(values.min()):g}")


def check_positive(name: str, x: torch.Tensor | float) -> None:
    """Raise ``ValueError`` naming ``name`` unless every value of ``x`` is finite and > 0."""
    if not checking_values(x):
        return
    values = _values(x)
    _check_finite(name, values)
    if values.numel() and not bool((values > 0).all()):
        raise ValueError(f"{name} must be positive, got a minimum of {float(values.min()):g}")


def check_shape(name: str, x: torch.Tensor, expected: str, ok: bool) -> None:
    """Raise ``ValueError`` naming ``name`` and the expected shape when ``ok`` is false."""
    if not ok:
        raise ValueError(f"{name} must have shape {expected}, got {tuple(x.shape)}")


def check_broadcasts_to(name: str, x: torch.Tensor, target, what: str) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``x`` broadcasts to the shape ``target`` (that
    of ``what``) without enlarging it: it may not add batch dimensions, nor grow any."""
    target = torch.Size(target)
    try:
        ok = torch.broadcast_shapes(x.shape, target) == target
    except RuntimeError:
        ok = False
    if not ok:
        raise ValueError(
            f"{name} must broadcast to {tuple(target)} ({what}) without enlarging it, "
            f"got {tuple(x.shape)}"
        )


def check_same_kind(reference: str, tensors: dict[str, object], dtype: bool = True) -> None:
    """Raise ``ValueError`` naming the first tensor of ``tensors`` whose dtype (when ``dtype``)
    or device differs from that of ``tensors[reference]``; non-tensors are skipped."""
    ref = tensors[reference]
    for name, x in tensors.items():
        if not isinstance(x, torch.Tensor) or x is ref:
            continue
        if dtype and x.dtype != ref.dtype:
            raise ValueError(
                f"{name} must have the dtype of {reference} ({ref.dtype}), got {x.dtype}"
            )
        if x.device != ref.device:
            raise ValueError(
                f"{name} must be on the device of {reference} ({ref.device}), got {x.device}"
            )


def check_count(name: str, n: object, minimum: int = 1) -> int:
    """Return ``n`` if it is an integer (not a bool) >= ``minimum``, else raise ``ValueError``
    naming ``name``."""
    if isinstance(n, bool) or not isinstance(n, int) or n < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {n!r}")
    return n


def is_finite_number(value: object) -> bool:
    """Whether ``value`` is a finite Python number (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_number(name: str, x: object) -> None:
    """Raise ``TypeError`` naming ``name`` unless ``x`` is a number (not a bool) or a tensor."""
    if isinstance(x, bool) or not isinstance(x, (int, float, torch.Tensor)):
        raise TypeError(f"{name} must be a number or a torch.Tensor, got {x!r}")


def check_tensor(name: str, x: object) -> torch.Tensor:
    """Return ``x`` if it is a floating tensor, else raise ``TypeError`` naming ``name``."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if not x.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {x.dtype}")
    return x


def register(registry: dict, name: str, entry, kind: str, check=callable) -> None:
    """Add ``entry`` to ``registry`` under ``name``, which must be a new non-empty string, and
    ``entry`` must pass ``check``; errors name the ``kind`` of entry (a model, a planner...)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"name must be a non-empty string, got {name!r}")
    if name in registry:
        raise ValueError(
            f"name must be a new {kind} name, got {name!r} (taken: {sorted(registry)})"
        )
    if not check(entry):
        raise ValueError(f"{kind} {name!r} is not a valid {kind}: got {entry!r}")
    registry[name] = entry
