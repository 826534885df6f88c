"""The compiled core's window functions (csrc/knots.c, csrc/onewindow.c) equal their Python
reference bit for bit: a window's counts out of a count function's knots
(``countfunction.close_knots``), the body-frame counts, the linear solve, and the pose and
covariance carried over a window (``onewindow.body_counts``, ``linear``, ``advance``); where
they cannot do exactly what the Python does they decline (None), and the Python runs.

The byte-level and hostile-input side (AddressSanitizer, UBSan) is scripts/fuzz_core.py,
which drives these functions too (tests/test_core_sanitized.py)."""

from __future__ import annotations

import math
import struct

import cores
import numpy as np
import pytest
from batches import assert_same_batches
from hypothesis import event, given, settings
from hypothesis import strategies as st
from test_core import needs_core
from test_onewindow import run

from mousedom import core
from mousedom.fusion import integrate, onewindow, shortfall, sim, steady
from mousedom.fusion.countfunction import close_knots
from mousedom.fusion.noisemodel import _MEDIAN_CHI2_2
from mousedom.fusion.tracker import PoseBatch, Tracker

# A NaN is compared as NaN, not by its bits: IEEE 754 leaves which operand's sign and
# payload a NaN result carries unspecified, and the compiler may swap the operands of a
# commutative operation (a * b as b * a), which is exact for every other value.
NAN_BITS = "any NaN"


def bits(v: object) -> object:
    """Floats as their bytes (-0.0 and every last bit compared; NaN see NAN_BITS),
    containers inside out."""
    if isinstance(v, float):  # any NaN as NaN (see NAN_BITS)
        return "nan" if v != v else struct.pack("<d", v)
    if isinstance(v, (list, tuple)):
        return type(v)(bits(x) for x in v)
    return v


def both(fn, *args):
    """``fn(*args)`` on each core: (compiled, Python), each on its own copy of the lists;
    the compiled one must not decline (these tests draw what the Python is handed), so
    that the two are compared, not the Python with itself."""
    native_fn = getattr(core.native, fn.__name__)
    if fn.__name__ == "steady_window" and len(args) == 8:
        args = (*args, None)  # (its spans: none cut)
    extra = {"advance": (onewindow._SINC, onewindow._DSINC, onewindow._SWITCH),
             "steady_window": (_MEDIAN_CHI2_2,)}.get(fn.__name__, ())  # fmt: skip
    declined = native_fn(*[_copy(a) for a in args], *extra)
    assert declined is not (False if fn.__name__ == "steady_window" else None), fn.__name__
    out = []
    for name in ("c", "python"):
        with cores.using(name):
            out.append(fn(*[_copy(a) for a in args]))
    return out


def _copy(a: object) -> object:
    return [_copy(x) for x in a] if isinstance(a, list) else a


# Stamps on a coarse grid collide (knots on the edge, reports with one stamp); counts are
# whole or fractional (a fractional anchor), and sometimes huge.
stamps = st.integers(-40, 40).map(lambda k: k * 0.0025) | st.floats(-0.2, 0.2)
levels = st.integers(-300, 300).map(float) | st.floats(-1e6, 1e6) | st.sampled_from([1e300])


@st.composite
def knot_lists(draw):
    n = draw(st.integers(1, 80))
    kt = sorted(draw(st.lists(stamps, min_size=n, max_size=n)))
    kx = draw(st.lists(levels, min_size=n, max_size=n))
    ky = draw(st.lists(levels, min_size=n, max_size=n))
    return kt, kx, ky


@needs_core
@settings(max_examples=400, deadline=None)
@given(
    knot_lists(),
    stamps | st.sampled_from([math.inf, -math.inf, math.nan]),
    st.sampled_from([math.nan, -0.1, 0.0]) | stamps,
)
def test_close_knots_is_the_python_bit_for_bit(knots, end, cut_from):
    """Edges before, on, between and after the knots (NaN too), spans the anchor cut or
    not, more knots than the core's stack buffer; the input lists are not changed."""
    kt, kx, ky = knots
    before = bits([kt, kx, ky])
    c, py = both(close_knots, end, kt, kx, ky, cut_from)
    assert bits(c) == bits(py)
    assert bits([kt, kx, ky]) == before
    assert all(type(v) is float for lst in c[4:] for v in lst)


@needs_core
@pytest.mark.parametrize(
    "knots",
    [
        ([0.0, 1], [0.0, 2.0], [0.0, 3.0]),  # an int time
        ([0.0, 1.0], [0.0, 2], [0.0, 3.0]),  # an int count
        ([0.0, 1.0], [0.0], [0.0, 3.0]),  # lengths differ
        ([], [], []),  # no knot (close_one handles it before)
        ([0.0, np.float64(1.0)], [0.0, 2.0], [0.0, 3.0]),  # a float subclass
    ],
)
def test_close_knots_declines_what_it_cannot_do_exactly(knots):
    assert core.native.close_knots(0.5, *knots, math.nan) is None


@needs_core
@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 8).flatmap(
        lambda n: st.tuples(
            st.lists(st.lists(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2),
                              min_size=2, max_size=2), min_size=n, max_size=n),
            st.lists(st.tuples(st.floats(-1e9, 1e9), st.floats(-1e9, 1e9)), min_size=n,
                     max_size=n),
        )
    )
)  # fmt: skip
def test_body_counts_is_the_python_bit_for_bit(case):
    to_body, counts = case
    c, py = both(onewindow.body_counts, to_body, counts)
    assert bits(c) == bits(py)


# Values whose sums cancel: where builtin sum compensates (Python 3.12 on) and where it
# does not, the core must add as the Python it runs under does.
terms = st.floats(-1e3, 1e3) | st.sampled_from([1e16, -1e16, 1.0, 3e-17, 0.1, -0.0])


@needs_core
@settings(max_examples=400, deadline=None)
@given(st.integers(1, 8), st.integers(1, 3), st.data())
def test_linear_is_the_python_bit_for_bit(m, k, data):
    """q = B d and the residual d - A q, for every number of live mice and of columns."""
    d = data.draw(st.lists(terms, min_size=2 * m, max_size=2 * m))
    b_rows = data.draw(st.lists(st.lists(terms, min_size=2 * m, max_size=2 * m),
                                min_size=k, max_size=k))  # fmt: skip
    a_rows = data.draw(st.lists(st.lists(terms, min_size=k, max_size=k),
                                min_size=2 * m, max_size=2 * m))  # fmt: skip
    c, py = both(onewindow.linear, d, a_rows, b_rows)
    assert bits(c) == bits(py)


@needs_core
def test_linear_and_body_counts_decline_other_shapes_and_types():
    native = core.native
    assert native.linear([1.0, 2.0], [[1.0], [1.0]], [[1.0, 2.0, 3.0]]) is None  # B's width
    assert native.linear([1.0, 2.0], [[1.0]], [[1.0, 2.0]]) is None  # A's height
    assert native.linear([1, 2.0], [[1.0], [1.0]], [[1.0, 2.0]]) is None  # an int
    assert native.body_counts([[[1.0, 0.0], [0.0, 1.0]]], [(1, 2.0)]) is None
    assert native.body_counts([[[1.0, 0.0], [0.0, 1.0]]], []) is None
    assert native.body_counts([[[1.0, 0.0]]], [(1.0, 2.0)]) is None


angles = st.floats(-8.0, 8.0) | st.floats(-1e-9, 1e-9) | st.sampled_from([0.0, -0.0, 1.0, 2.0])
small = st.floats(-1e3, 1e3)


def matrix3(elements=small):
    return st.lists(st.lists(elements, min_size=3, max_size=3), min_size=3, max_size=3)


@needs_core
@settings(max_examples=400, deadline=None)
@given(
    st.tuples(small, small, angles).map(list),
    matrix3(),
    st.tuples(small, small).map(list),
    st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), angles).map(list),
    angles,
    matrix3(st.floats(0.0, 1e-3)),
    st.sampled_from(integrate.INTEGRATORS),
)
def test_advance_is_the_python_bit_for_bit(pose, cov, at, q, owed, c3, method):
    """Every integrator, both sides of the series' switch (a/2 below and above 1)."""
    c, py = both(onewindow.advance, pose, cov, at, q, owed, c3, method)
    assert bits(c) == bits(py)


@needs_core
def test_advance_declines_an_unknown_method_and_the_python_says_so():
    args = ([0.0] * 3, [[0.0] * 3] * 3, [0.0] * 2, [0.0] * 3, 0.0, [[0.0] * 3] * 3)
    assert core.native.advance(*args, "rk4", onewindow._SINC, onewindow._DSINC, 1.0) is None
    with pytest.raises(ValueError, match="rk4"):
        onewindow.advance(*args, "rk4")


@needs_core
@settings(max_examples=25, deadline=None)
@given(
    st.sampled_from(["lsq", "diff-drive"]),
    st.sampled_from(integrate.INTEGRATORS),
    st.lists(
        st.tuples(st.integers(0, 2), st.floats(0.0, 0.25, allow_nan=False),
                  st.integers(-127, 127), st.integers(-127, 127)),
        max_size=120,
    ),
    st.lists(st.tuples(st.integers(0, 2), st.floats(0.001, 0.25), st.booleans()), max_size=6),
    st.sampled_from([50.0, 100.0, 333.0]),
)  # fmt: skip
def test_the_tracker_gives_the_same_windows_on_either_core(
    model, integrator, reports, deaths, rate_hz
):
    """The daemon's one-window path end to end: every field of every window (poses,
    covariances, residuals, counts, health) identical, bit for bit, with mice dying and
    coming back, reports out of order and late."""
    out = {}
    for name in ("c", "python"):
        with cores.using(name):
            *batches, stats, counts_in = run(model, integrator, reports, deaths, 1, rate_hz)
        out[name] = (PoseBatch.concat(batches, 3), stats, counts_in)
    (a, sa, ia), (b, sb, ib) = out["c"], out["python"]
    assert sa == sb and np.array_equal(ia, ib)
    assert_same_batches(a, b)


@st.composite
def steady_cases(draw):
    """A rig of 1-8 mice, a live pattern, readings near the rigid prediction or far off,
    noise parts that make either factor tell (or both, or neither), speed limits that
    saturate now and then, every number of degrees of freedom."""
    n = draw(st.integers(1, 8))
    pos = st.floats(-0.3, 0.3)
    step = st.floats(-0.02, 0.02) | st.sampled_from([0.0, -0.0])
    var = st.floats(1e-12, 1e-6) | st.sampled_from([0.0])
    pairs = st.lists(st.tuples(step, step).map(list), min_size=n, max_size=n)
    rig = steady.Rig(
        xy=draw(st.lists(st.tuples(pos, pos).map(list), min_size=n, max_size=n)),
        max2=draw(st.lists(st.floats(1e-6, 1e-3) | st.just(math.inf), min_size=n, max_size=n)),
        prev=draw(pairs),
        floor=draw(st.lists(st.floats(1e-12, 1e-6), min_size=n, max_size=n)),
        rho2=draw(st.lists(var, min_size=n, max_size=n)),
        gran2=draw(st.lists(var, min_size=n, max_size=n)),
        sig2=draw(st.lists(st.floats(1e-12, 1e-6), min_size=n, max_size=n)),
        lam_r=draw(st.lists(st.floats(0.1, 10.0), min_size=n, max_size=n)),
    )
    live = tuple(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    d = draw(st.lists(step, min_size=2 * n, max_size=2 * n))
    q = [draw(step), draw(step), draw(st.floats(-0.5, 0.5))]
    dof = draw(st.integers(-3, 2 * n))
    threshold = draw(st.floats(0.0, 50.0) | st.just(math.inf) | st.just(math.inf))
    # as Screen.fast_one hands it: the leverage where there are degrees of freedom
    leverage = None
    if dof > 0:
        leverage = draw(st.lists(st.floats(0.0, 2.5), min_size=n, max_size=n))
    # others_gain_list's rows: (I - block)^-1, or zero where the others cannot say
    gain = st.tuples(*[st.floats(-3.0, 3.0)] * 4).map(list) | st.just([0.0] * 4)
    gains = draw(st.lists(gain, min_size=n, max_size=n))
    # the long report spans the edges cut (fast_one's): none, or some mice's (a NaN too)
    span = st.just(0.0) | st.floats(0.0, 0.05) | st.just(math.nan)
    spans = draw(st.none() | st.lists(span, min_size=n, max_size=n))
    return d, q, live, rig, threshold, dof, leverage, gains, spans


@needs_core
@settings(max_examples=500, deadline=None)
@given(steady_cases())
def test_steady_window_is_the_python_bit_for_bit(case):
    """Accepted, saturated and over the threshold alike; the samples taken in order."""
    c, py = both(steady.steady_window, *case)
    assert bits(c) == bits(py)
    event("decide" if py is None else "samples" if py[1] or py[2] else "accepted")
    if py is not None:
        event(f"heard {sum(py[3])} of {len(py[3])}")


@needs_core
def test_steady_window_declines_what_the_python_would_refuse():
    """Other types, other lengths, and a zero divisor (the Python raises) go to the Python."""
    rig = steady.Rig([[0.1, 0.0]], [math.inf], [[0.0, 0.0]], [1e-8], [1e-4], [0.0], [1e-8],
                     [1.0])  # fmt: skip
    args = ([0.001, 0.0], [0.001, 0.0, 0.0], (True,), rig, 5.0, 1, [0.5], [[0.0] * 4], None,
            1.386)  # fmt: skip
    native = core.native
    assert native.steady_window(*args) is not False
    assert native.steady_window([1, 0.0], *args[1:]) is False  # an int
    assert native.steady_window(*args[:2], (1,), *args[3:]) is False  # not a bool
    assert native.steady_window(*args[:3], rig._replace(max2=[]), *args[4:]) is False
    assert native.steady_window(*args[:3], rig[:7], *args[4:]) is False  # not a Rig
    assert native.steady_window(*args[:7], [[0.0] * 3], *args[8:]) is False  # not four gains
    assert native.steady_window(*args[:7], [(0.0,) * 4] * 2, *args[8:]) is False  # two mice
    assert native.steady_window(*args[:7], ([0.0] * 4,), *args[8:]) is False  # a tuple
    assert native.steady_window(*args[:8], [1], args[9]) is False  # a span not a float
    assert native.steady_window(*args[:8], [0.0, 0.0], args[9]) is False  # two spans
    zero = rig._replace(floor=[0.0], rho2=[0.0])
    assert native.steady_window(args[0], [0.0, 0.0, 0.0], args[2], zero, *args[4:]) is False
    with pytest.raises(ZeroDivisionError):
        with cores.using("python"):
            steady.steady_window(args[0], [0.0, 0.0, 0.0], args[2], zero, *args[4:8])


@needs_core
@pytest.mark.parametrize("ratio", [0.25, 4.0, 1.0])
@pytest.mark.parametrize("ux", [0.003, 0.0125, 1e-5])
def test_steady_window_samples_at_the_quarter_boundaries(ratio, ux):
    """A factor is sampled where its part is at least a quarter of the other: exactly a
    quarter (and exactly equal) on both cores alike."""
    rho2 = 1e-3
    prop = rho2 * (ux * ux) + 0.0 * 0.0  # as the test computes it: m2 = ux^2, no change
    rig = steady.Rig([[0.0, 0.0], [0.0, 0.1]], [math.inf] * 2, [[ux, 0.0], [ux, 0.0]],
                     [prop * ratio] * 2, [rho2] * 2, [0.0] * 2, [1e-12] * 2, [1.0] * 2)  # fmt: skip
    d = [ux, 0.0, ux + 1e-4, 0.0]
    c, py = both(steady.steady_window, d, [ux, 0.0, 0.0], (True, True), rig, math.inf, 1,
                 [0.5, 0.5], [[0.0] * 4] * 2)  # fmt: skip
    assert bits(c) == bits(py)
    assert py[1] and py[2] if ratio == 1.0 else py[1] or py[2]


class _Counting:
    """The compiled core, counting the calls of each function that do not decline."""

    def __init__(self, native) -> None:
        self._native = native
        self.calls: dict[str, int] = {}

    def __getattr__(self, name: str):
        fn = getattr(self._native, name)

        def counted(*args):
            out = fn(*args)
            if out is not None and out is not False:
                self.calls[name] = self.calls.get(name, 0) + 1
            return out

        return counted


@needs_core
@pytest.mark.parametrize(
    ("x", "gain", "short"),
    [
        # not used by the others' word (no gain): short under SHORT_ALONE of the solve
        (shortfall.SHORT_ALONE, 0.0, False),
        (math.nextafter(shortfall.SHORT_ALONE, 0.0), 0.0, True),
        # gain 1: what the others moved it is exactly the solve, 1, so the ratio is x
        (shortfall.SHORT, 1.0, False),
        (math.nextafter(shortfall.SHORT, 0.0), 1.0, True),
        # gain 6: the others' word is 1.5 (a ratio of 0.6), and the solve's SHORT_OF_ALL
        (shortfall.SHORT_OF_ALL, 6.0, False),
        (math.nextafter(shortfall.SHORT_OF_ALL, 0.0), 6.0, True),
    ],
)
def test_steady_window_leaves_a_shortfall_at_its_boundaries_to_the_decision(x, gain, short):
    """The common case hands a window with a mouse short of its motion to the decision
    (``shortfall.reads_short``) exactly where the Python does, at each of the rule's
    three boundaries, on either core: the compiled constants are the Python's."""
    rig = steady.Rig([[0.0, 0.0]], [math.inf], [[1.0, 0.0]], [1e-8], [0.0], [0.0], [1e-12],
                     [1.0])  # fmt: skip
    args = ([x, 0.0], [1.0, 0.0, 0.0], (True,), rig, math.inf, -1, None,
            [[gain, 0.0, 0.0, gain]])  # fmt: skip
    c, py = both(steady.steady_window, *args)
    assert bits(c) == bits(py)
    assert (py is None) == short
    assert shortfall.reads_short(args[0], [[1.0, 0.0]], args[7], [True], [gain != 0.0]) == [short]


@needs_core
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("model", ["lsq", "diff-drive"])
def test_a_simulated_drive_gives_the_same_windows_on_either_core(seed, model):
    """A realistic drive (three mice at 125 Hz, straights, turns and arcs, the simulator's
    timing noise) fed as the daemon feeds it, report by report with a poll after each:
    every window the same bit for bit on both cores, and the compiled core did the steady
    windows (the screen's common case included), not only declined."""
    rig = sim.three_mouse_rig()
    drive = sim.sequence(sim.pause(0.3), sim.straight(0.3), sim.turn(1.2), sim.arc(0.4, 1.0),
                         sim.sideways(0.1), sim.pause(0.2))  # fmt: skip
    result = sim.simulate(rig, drive, seed=seed)
    cfg = sim.rig_config(rig)
    out, counting = {}, _Counting(core.native)
    for name in ("c", "python"):
        with cores.using(name):
            if name == "c":
                core.native = counting
            tracker = Tracker(cfg, t0=float(result.motion.starts[0]), model=model)
            batches = sim.run_tracker_live(result, tracker)
        out[name] = PoseBatch.concat(batches, 3)
    a, b = out["c"], out["python"]
    assert len(a) > 100
    assert_same_batches(a, b)
    for fn in ("close_knots", "body_counts", "linear", "advance", "steady_window"):
        assert counting.calls.get(fn, 0) > len(a) // 2, (fn, counting.calls)
