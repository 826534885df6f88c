"""mousedom.capture.fixedpoint and the replay CSV it writes: the same text as Python's
``"%.<d>f" % x``, digit for digit, for every double it takes."""

import io
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.capture.fixedpoint import fixed_bytes, rounded_decimals
from mousedom.capture.replay import CsvSink
from mousedom.capture.scientific import scientific_bytes
from mousedom.fusion.posebatch import PoseBatch


def text_of(values, digits, sep=b","):
    out = fixed_bytes(np.asarray(values, dtype=float), np.asarray(digits), sep)
    assert out is not None
    data, keep = out
    return data[keep].tobytes().decode("ascii")


def python_text(values, digits, sep=","):
    return "".join(
        "".join(f"%.{d}f{sep}" % v for v, d in zip(row, digits, strict=True)) for row in values
    )


finite = st.floats(min_value=-9.99e9, max_value=9.99e9, allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=40),
    st.tuples(*[st.integers(1, 9)] * 3),
)
def test_any_double_reads_as_python_writes_it(rows, digits):
    assert text_of(rows, digits) == python_text(rows, digits)


def test_exact_ties_go_to_the_even_digit():
    """Doubles half-way between two d-decimal numbers (k / 2**m with a 5 just past the
    d-th decimal) round half to even on the exact value, as Python does; near-ties on
    either side round by the bits a float64 product of f * 10**d would lose."""
    ties = np.arange(-5000, 5000) / 1024.0  # 10 decimals, the 10th a 5
    near = np.nextafter(ties, np.inf), np.nextafter(ties, -np.inf)
    for values in (ties, *near, np.arange(-3000, 3000) / 2.0**20):
        rows = values.reshape(-1, 2)
        for digits in ((9, 9), (6, 7), (1, 2), (3, 4)):
            assert text_of(rows, digits) == python_text(rows, digits)


def test_carries_signs_and_lengths():
    values = [
        [0.9999999995, 0.99999999949999, 9.9999995],
        [-0.0, -1e-12, 0.0],
        [9999999999.0, 123456789.5, 1e-300],
        [-0.0000000005, -0.5, 1.0],
    ]
    for digits in ((9, 9, 6), (6, 6, 1), (1, 1, 9)):
        assert text_of(values, digits) == python_text(values, digits)
    assert text_of([[1.5, -2.25]], (1, 2), sep=b"") == "1.5-2.25"


def test_what_it_cannot_write_exactly_is_refused():
    for bad in (math.nan, math.inf, -math.inf, 1e10, -1e10, 1e300):
        assert fixed_bytes(np.array([[1.0, bad]]), np.array([6, 6])) is None
    # rounds up to 11 integer digits
    assert fixed_bytes(np.array([[9999999999.97]]), np.array([1])) is None
    assert fixed_bytes(np.array([[9999999999.94]]), np.array([1])) is not None


def test_rounded_decimals_is_exact_where_the_float_product_is_not():
    """0.1234567895 * 1e9 in float64 is 123456789.5 exactly, a tie that rint sends to
    ...790; the double's exact value is below the tie, so Python writes ...789."""
    x = 0.1234567895
    assert "%.9f" % x == "0.123456789"  # noqa: UP031 - the %-format is what is matched
    assert np.rint(x * 1e9) == 123456790.0
    whole, dec = rounded_decimals(np.array([x]), np.array([9]))
    assert (int(whole[0]), int(dec[0])) == (0, 123456789)


def sci_text(values, digits):
    out = scientific_bytes(np.asarray(values, dtype=float), digits)
    assert out is not None
    data, keep = out
    return data[keep].tobytes().decode("ascii")


# exponents within +-300 (beyond: None, the caller's per-row path)
sci_finite = st.one_of(
    st.floats(min_value=1e-300, max_value=9.99e299),
    st.floats(min_value=-9.99e299, max_value=-1e-300),
    st.sampled_from([0.0, -0.0, 9.9999995, 9.99999949999, 1.25, 0.125, 2.5e-8, 1e22, 1e23]),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(sci_finite, sci_finite), min_size=1, max_size=40), st.integers(1, 9))
def test_any_double_reads_as_python_writes_it_in_exponent_form(rows, digits):
    assert sci_text(rows, digits) == "".join(f"%.{digits}e," % v for r in rows for v in r)


def test_exponent_form_of_many_decimals_and_ties():
    """Decimal fractions (ties of the half-way rule among them) over many decades."""
    rng = np.random.default_rng(3)
    v = rng.integers(0, 10**8, 20000) / 10.0 ** rng.integers(0, 14, 20000)
    v = np.concatenate([v, -v, rng.normal(size=20000) * 10.0 ** rng.integers(-290, 290, 20000)])
    for digits in (1, 4, 6, 9):
        assert sci_text(v[:, None], digits) == "".join(f"%.{digits}e," % x for x in v)
    for bad in (math.nan, math.inf, 1e-320, 1e305):
        assert scientific_bytes(np.array([[1.0, bad]]), 6) is None


def _batch(n, rng, values=None, scale=None):
    spread = {"t": 1e3, "x": 3, "y": 3, "theta": 9, "vx": 0.2, "vy": 0.2, "omega": 1.0}
    cols = {k: rng.normal(0, s, n) for k, s in spread.items()}
    if values is not None:
        cols.update(values)
    root = rng.normal(0, 1, (n, 3, 3)) * 10.0 ** rng.integers(-8, 1, (n, 1, 1))
    return PoseBatch(
        **cols,
        cov=root @ root.transpose(0, 2, 1),
        scale=scale,
        used=rng.integers(0, 3, n),
        ok=rng.random(n) < 0.9,
        residual=np.zeros((n, 2, 2)),
        counts=np.zeros((n, 2, 2)),
        state=rng.integers(0, 4, (n, 2)).astype(np.int8),
        reason=rng.integers(0, 5, (n, 2)).astype(np.int8),
        consistent=rng.random(n) < 0.95,
        qcov=np.zeros((n, 3, 3)),
    )


def _rows(b):
    out = []
    for i in range(len(b)):
        floats = [b.t[i], b.x[i], b.y[i], b.theta[i], b.vx[i], b.vy[i], b.omega[i]]
        ints = [b.used[i], int(b.ok[i]), int(b.consistent[i])]
        for m in range(b.state.shape[1]):
            ints += [b.state[i, m], b.reason[i, m]]
        cov = [b.cov[i, j, k] for j, k in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
        scales = b.scales()[i].ravel().tolist()
        out.append(
            "%.6f,%.9f,%.9f,%.9f,%.6f,%.6f,%.6f," % tuple(floats)  # noqa: UP031 - as before
            + ",".join(map(str, ints))
            + "".join(",%.6e" % v for v in cov)  # noqa: UP031
            + "".join(",%.6f" % v for v in scales)  # noqa: UP031
        )
    return out


def test_csv_rows_are_the_per_row_format_with_and_without_the_array_path():
    """The array path (finite values) and the per-row fallback (a NaN in the batch) write
    what a %-format per row writes."""
    rng = np.random.default_rng(7)
    learnt = 1 + rng.normal(0, 0.03, (500, 2, 2))
    batches = [_batch(500, rng, scale=learnt), _batch(1, rng)]
    batches.append(_batch(3, rng, {"vx": np.array([1, math.nan, 2])}))
    batches.append(_batch(2, rng, {"x": np.array([-0.0, 2e10])}))
    buf = io.StringIO()
    sink = CsvSink(buf, ("a", "b"))
    for b in batches:
        sink(b)
    lines = buf.getvalue().splitlines()
    assert lines[0].endswith(
        "state_a,reason_a,state_b,reason_b,cov_xx,cov_xy,cov_xt,cov_yy,cov_yt,cov_tt,"
        "scale_x_a,scale_y_a,scale_x_b,scale_y_b"
    )
    assert lines[1:] == [r for b in batches for r in _rows(b)]
    assert "nan" in lines[503] and "20000000000.000000000" in lines[506]
    assert sink.rows == 506
