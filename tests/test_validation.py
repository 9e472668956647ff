"""The shared input checks: they skip meta tensors and transforms, and name what they check."""

import math

import pytest
import torch

from torchcontact.validation import (
    check_broadcasts_to,
    check_finite,
    check_nonnegative,
    check_positive,
    check_same_kind,
    checking_values,
    validate_args,
)


def test_value_checks_skip_meta_tensors():
    meta = torch.empty(3, device="meta")
    assert checking_values() and checking_values(torch.ones(2))
    assert not checking_values(torch.ones(2), meta)
    for check in (check_finite, check_nonnegative, check_positive):
        check("x", meta)  # no Tensor.item() on a meta tensor
        with pytest.raises(ValueError, match="^x must"):
            check("x", torch.tensor([1.0, math.nan]))
    with validate_args(False):
        assert not checking_values(torch.ones(2))


def test_value_checks_skip_themselves_under_vmap():
    def f(x):
        assert not checking_values(x)
        check_positive("x", x)
        return 2 * x

    with validate_args(True):
        torch.testing.assert_close(torch.func.vmap(f)(torch.ones(3, 2)), 2 * torch.ones(3, 2))


@pytest.mark.parametrize(
    "shape, target, ok",
    [
        ((), (4,), True),
        ((4,), (4,), True),
        ((1,), (2, 4), True),
        ((2, 1), (2, 4), True),
        ((4, 1), (4,), False),  # would give (4, 4)
        ((3,), (), False),  # would add a dimension
        ((5, 2, 4), (2, 4), False),
        ((3,), (4,), False),  # does not broadcast at all
    ],
)
def test_broadcasting_to_a_shape_may_not_enlarge_it(shape, target, ok):
    x = torch.zeros(shape)
    if ok:
        check_broadcasts_to("h", x, target, "the batch shape")
    else:
        match = rf"^h must broadcast to {tuple(target)!s}".replace("(", r"\(").replace(")", r"\)")
        with pytest.raises(ValueError, match=match):
            check_broadcasts_to("h", x, target, "the batch shape")


def test_dtypes_and_devices_must_match_the_reference():
    b = torch.zeros(2, dtype=torch.float64)
    check_same_kind("b", {"b": b, "jac": torch.ones(3, dtype=torch.float64), "h": 0.1})
    with pytest.raises(ValueError, match=r"^jac must have the dtype of b \(torch.float64\)"):
        check_same_kind("b", {"b": b, "jac": torch.ones(3)})
    check_same_kind("b", {"b": b, "K": torch.ones(3)}, dtype=False)
    with pytest.raises(ValueError, match=r"^K must be on the device of b \(cpu\), got meta"):
        check_same_kind("b", {"b": b, "K": torch.ones(3, device="meta")}, dtype=False)
