"""Student's t without scipy (fusion/student.py): the closed forms against printed tables
and against the cases known in elementary functions."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.fusion import student

# Two-sided quantiles t with P(|T| < t) = p, from the standard tables (e.g. Abramowitz &
# Stegun Table 26.10, as 1 - Q/2 upper points), to the digits printed there.
TABLE = [
    (0.95, 1, 12.706),
    (0.95, 2, 4.303),
    (0.95, 3, 3.182),
    (0.95, 5, 2.571),
    (0.95, 10, 2.228),
    (0.95, 30, 2.042),
    (0.99, 1, 63.657),
    (0.99, 2, 9.925),
    (0.99, 4, 4.604),
    (0.99, 9, 3.250),
    (0.99, 20, 2.845),
]


@pytest.mark.parametrize("p, dof, t", TABLE)
def test_quantiles_match_the_tables(p, dof, t):
    assert student.quantile(p, dof) == pytest.approx(t, abs=6e-4)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1e6, allow_nan=False), st.integers(1, 3))
def test_the_cases_in_elementary_functions(t, dof):
    """1 degree: Cauchy, 2/pi atan t; 2: t / sqrt(2 + t^2); 3: 2/pi (theta + sin theta
    cos theta), theta = atan(t / sqrt 3)."""
    theta = math.atan(t / math.sqrt(dof))
    want = {
        1: 2.0 / math.pi * math.atan(t),
        2: t / math.sqrt(2.0 + t * t),
        3: 2.0 / math.pi * (theta + math.sin(theta) * math.cos(theta)),
    }[dof]
    assert student.two_sided(t, dof) == pytest.approx(want, abs=1e-14)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.01, 0.9999), st.integers(1, 200))
def test_quantile_inverts_the_distribution(p, dof):
    t = student.quantile(p, dof)
    assert student.two_sided(t, dof) == pytest.approx(p, abs=1e-11)
    # and lies beyond the normal's: t has heavier tails, tending to it
    z = math.sqrt(2.0) * _erfinv(p)
    assert t >= z - 1e-9


def test_many_degrees_tend_to_the_normal():
    assert student.quantile(math.erf(3.0 / math.sqrt(2.0)), 100_000) == pytest.approx(3.0, abs=1e-3)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError):
        student.two_sided(1.0, 0)
    with pytest.raises(ValueError):
        student.quantile(1.0, 3)


def _erfinv(p: float) -> float:
    lo, hi = 0.0, 10.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if math.erf(mid) < p else (lo, mid)
    return hi
