"""Validation and conversion of mass vectors (solvers.validation)."""

from __future__ import annotations

import numpy as np
import pytest

from solvers.errors import InputError
from solvers.validation import (
    check_masses,
    check_weights,
    density_from_masses,
    masses_from_density,
    normalize_masses,
)


@pytest.mark.parametrize(
    ("values", "words"),
    [
        ([0.5, -0.1, 0.6], "negative"),
        ([0.5, np.nan, 0.5], "NaN"),
        ([0.5, np.inf, 0.5], "infinite"),
        ([0.0, 0.0, 0.0], "zero total"),
        ([0.5, 0.5], "length 3"),
        (np.ones((3, 2, 1)), "length 3"),
        (["a", "b", "c"], "numeric"),
        (np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 0.0]]), "zero total"),
    ],
)
def test_bad_masses_raise_input_error_naming_the_field(values, words):
    with pytest.raises(InputError) as info:
        check_masses(values, 3, field="mu0")
    assert info.value.field == "mu0"
    assert words.lower() in str(info.value).lower()
    assert "mu0" in str(info.value)


def test_negative_entry_is_located():
    with pytest.raises(InputError, match=r"mu\[2\] is negative"):
        check_masses([1.0, 1.0, -2.0, 1.0], 4, field="mu")
    with pytest.raises(InputError, match=r"mus\[1\] is NaN"):
        check_masses(np.array([[1.0, 1.0], [1.0, np.nan]]), 2, field="mus")


def test_normalize_and_convert():
    x = normalize_masses(np.array([[1.0, 2.0], [3.0, 2.0]]), 2)
    np.testing.assert_allclose(x.sum(axis=0), 1.0)
    np.testing.assert_allclose(x[:, 0], [0.25, 0.75])
    areas = np.array([0.2, 0.8])
    mu = density_from_masses(x, areas)
    np.testing.assert_allclose(areas @ mu, [1.0, 1.0])
    np.testing.assert_allclose(masses_from_density(mu, areas), x)
    np.testing.assert_allclose(density_from_masses(x[:, 1], areas), x[:, 1] / areas)


@pytest.mark.parametrize(
    ("weights", "words"),
    [
        ([1e308, 1e308, 0.0], "float range"),  # each finite, the sum inf
        ([10**400, 1, 1], "numbers"),  # an int beyond float64
        ([0.5, np.inf, 0.5], "finite"),
        ([0.0, 0.0, 0.0], "positive sum"),
    ],
)
def test_bad_weights_raise_input_error_naming_the_field(weights, words):
    """An overflowing sum would normalize to zeros: refused, for every caller."""
    with pytest.raises(InputError) as info:
        check_weights(weights, 3, field="weights[2]")
    assert info.value.field == "weights[2]" and "weights[2]" in str(info.value)
    assert words in str(info.value)


def test_weights_near_the_float_limit_whose_sum_is_finite_are_kept():
    w = check_weights([1e307, 1e307, 0.0], 3)
    np.testing.assert_allclose(w, [0.5, 0.5, 0.0], rtol=1e-15)


@pytest.mark.parametrize("peak", [1.7e308, np.finfo(float).max, 5e-324])
def test_masses_whose_sum_overflows_or_is_subnormal_normalize_exactly(peak):
    """Finite masses are valid however large or small: the sum is taken after scaling by
    the largest value, so [1.7e308, 1.7e308] is [0.5, 0.5] (dividing by the inf sum gave
    zeros, which crashed the LP downstream) and subnormals keep their ratios."""
    x = normalize_masses(np.array([peak, peak, 0.0, peak]), 4, field="mu0")
    np.testing.assert_array_equal(x, [1 / 3, 1 / 3, 0.0, 1 / 3])
    block = normalize_masses(np.array([[peak, 1.0], [peak, 3.0]]), 2)
    np.testing.assert_array_equal(block, [[0.5, 0.25], [0.5, 0.75]])
    assert np.all(np.isfinite(normalize_masses(np.full(10_000, peak), 10_000)))
