"""Input checks shared by the public entry points, in one place.

Checks that read tensor values (NaN, signs, positive definiteness) cost a device sync, so they
can be switched off for hot loops with :func:`set_validate_args`, as ``torch.distributions``
does. Shape checks are free and always run. Nothing is checked while ``torch.compile`` traces.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch

_VALIDATE = True


def set_validate_args(value: bool) -> None:
    """Turn value checks (NaN/Inf, signs, SPD) on or off globally."""
    global _VALIDATE
    _VALIDATE = bool(value)


@contextlib.contextmanager
def validate_args(value: bool) -> Iterator[None]:
    """Context manager form of :func:`set_validate_args`."""
    previous = _VALIDATE
    set_validate_args(value)
    try:
        yield
    finally:
        set_validate_args(previous)


def checking_values() -> bool:
    """Whether value checks run now: not while compiling, nor under ``torch.func`` transforms
    (vmap), whose batched tensors cannot be read on the host."""
    return (
        _VALIDATE
        and not torch.compiler.is_compiling()
        and torch._C._functorch.maybe_current_level() is None
    )


def _values(x: torch.Tensor | float) -> torch.Tensor:
    return x.detach() if isinstance(x, torch.Tensor) else torch.tensor(float(x))


def check_finite(name: str, x: torch.Tensor | float) -> None:
    """Raise ``ValueError`` naming ``name`` when ``x`` holds NaN or Inf."""
    if checking_values() and not bool(torch.isfinite(_values(x)).all()):
        raise ValueError(f"{name} must be finite, got NaN or Inf")


def check_nonnegative(name: str, x: torch.Tensor | float) -> None:
    """Raise ``ValueError`` naming ``name`` when ``x`` is NaN, Inf or negative."""
    check_finite(name, x)
    values = _values(x)
    if checking_values() and values.numel() and bool((values < 0).any()):
        raise ValueError(f"{name} must be non-negative, got a minimum of {float(values.min()):g}")


def check_positive(name: str, x: torch.Tensor | float) -> None:
    """Raise ``ValueError`` naming ``name`` unless every value of ``x`` is finite and > 0."""
    check_finite(name, x)
    values = _values(x)
    if checking_values() and values.numel() and not bool((values > 0).all()):
        raise ValueError(f"{name} must be positive, got a minimum of {float(values.min()):g}")


def check_shape(name: str, x: torch.Tensor, expected: str, ok: bool) -> None:
    """Raise ``ValueError`` naming ``name`` and the expected shape when ``ok`` is false."""
    if not ok:
        raise ValueError(f"{name} must have shape {expected}, got {tuple(x.shape)}")


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
