"""The plot's data collector (the PNG itself is drawn in tests/test_replay.py)."""

from __future__ import annotations

import numpy as np
from test_replay_pacing import _batch


def test_plot_collector_keeps_first_and_final_pose_when_decimating(monkeypatch):
    """The plot marks start and end; decimation to bounded memory dropped the final
    window, so "end" was not where the replay ended."""
    from mousedom import plot

    monkeypatch.setattr(plot, "MAX_POINTS", 50)
    col = plot.PlotCollector()
    t = np.arange(1, 1001) * 0.01
    for k in range(0, 1000, 37):  # batches of odd sizes
        part = t[k : k + 37]
        b = _batch(part)
        b.x = part * 2.0
        col(b)
    data = col.data()
    assert len(data) <= 2 * 50 + 1  # bounded
    assert data[0, 0] == t[0] and data[-1, 0] == t[-1] and data[-1, 1] == 2.0 * t[-1]
    assert np.all(np.diff(data[:, 0]) > 0)
