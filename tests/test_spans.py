"""The long report spans a window's edges cut (CountFunction: ``close``'s ``spans``,
``close_one``'s ``window_span``) and the noise they add (NoiseModel.gran2_for): issue 31,
item 1 (a USB catch-up's counts are spread over the time they were measured in, and a
window that takes a share of them is allowed the error of that share)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.fusion.countfunction import CountFunction
from mousedom.fusion.noisemodel import NoiseModel

PERIOD = 0.008
WINDOW = 0.01


def _mouse(t: list[float], dx: list[int]) -> CountFunction:
    cf = CountFunction(PERIOD, bridge=0.1)
    cf.queue(list(t), list(dx), [0] * len(dx), max(t))
    cf.complete_to(math.inf)
    return cf


reports = st.lists(
    st.tuples(st.floats(0.0005, 0.09), st.integers(-40, 40)), min_size=1, max_size=40
)


@settings(max_examples=200, deadline=None)
@given(reports, st.integers(1, 40))
def test_the_array_and_float_paths_give_the_same_spans(steps, n_windows):
    """close (arrays) and close_one (floats, window by window) see the same spans."""
    t = np.cumsum([s for s, _ in steps]).tolist()
    dx = [c for _, c in steps]
    edges = np.arange(n_windows + 1) * WINDOW
    a = _mouse(t, dx)
    a.ingest(-math.inf)
    spans = np.zeros(n_windows)
    a.close(edges, spans=spans)
    b = _mouse(t, dx)
    b.ingest_small(-math.inf)
    b.anchor_span = 0.0
    one = []
    for end in edges[1:]:
        b.close_one(float(end))
        one.append(b.window_span)
    assert spans.tolist() == one
    assert a.anchor_span == b.anchor_span


def test_a_catch_up_report_marks_the_windows_it_spans():
    """Reports every 8 ms, then one 48 ms after the last (a USB stall), holding its counts:
    the windows whose edges fall inside that report's span carry its length; the others,
    whose spans are one period, none."""
    t = [0.008 * k for k in range(1, 6)] + [0.088, 0.096, 0.104]  # 0.040 -> 0.088
    cf = _mouse(t, [5] * len(t))
    cf.ingest(-math.inf)
    edges = np.arange(12) * WINDOW
    spans = np.zeros(11)
    cf.close(edges, spans=spans)
    cut = (edges[:-1] < 0.088) & (edges[1:] > 0.040)  # windows overlapping (0.040, 0.088)
    inside = [0.040 < e < 0.088 for e in edges]
    touched = [inside[k] or inside[k + 1] for k in range(11)]
    assert touched == (cut & ~((edges[:-1] <= 0.040) & (edges[1:] <= 0.040))).tolist()
    assert spans[touched] == pytest.approx(0.048)
    assert not spans[[not v for v in touched]].any()


def test_a_flat_stretch_is_not_a_span():
    """A mouse that stops (no counts in a long gap, then a report after the bridge) has no
    long rising span: nothing is spread over the silence."""
    cf = _mouse([0.008, 0.016, 0.5, 0.508], [3, 3, 0, 3])
    cf.ingest(-math.inf)
    spans = np.zeros(60)
    cf.close(np.arange(61) * WINDOW, spans=spans)
    assert not spans.any()


def test_the_granularity_term_grows_with_the_span():
    """(L/T)^2 / 8 of the change of motion where that exceeds the mouse's own quarter of
    P/T, squared."""
    nm = NoiseModel(np.full(2, 1e-5), 0.05, np.array([0.008, 0.001]), WINDOW)
    assert nm.gran2_for(None) is None
    own = nm.gran2_for(np.zeros(2))
    assert own == pytest.approx(nm.gran2)
    g = nm.gran2_for(np.array([0.05, 0.0]))
    assert g[0] == pytest.approx(((0.05 / WINDOW) ** 2 / 8) ** 2)
    assert g[1] == nm.gran2[1]
