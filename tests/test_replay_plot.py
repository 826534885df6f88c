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


def _collector(rig, trajectory):
    from mousedom import plot
    from mousedom.fusion import sim

    result = sim.simulate(rig, trajectory, seed=2)
    batch, _ = sim.run_tracker(result)
    col = plot.PlotCollector()
    col(batch)
    return col, batch


def _titles(fig):
    return [ax.get_title() for ax in fig.axes if ax.get_title()]


def test_the_figure_shows_time_direction_uncertainty_start_and_end():
    """Issue 14 item 6, checked on the figure's artists: the path is a LineCollection
    coloured by time; heading arrows; covariance ellipses; a start ring drawn above the end
    square (a closed square put the end marker over the start); the residual panel with
    each mouse's report rate."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Ellipse
    from matplotlib.quiver import Quiver

    from mousedom import plot
    from mousedom.fusion import sim

    rig = sim.three_mouse_rig()
    col, batch = _collector(rig, sim.umbmark_square(1.0))
    fig = plot.figure(col, ("front", "left", "right"), model="lsq",
                      rates={"front": 125.0, "left": 125.0, "right": 125.0})  # fmt: skip
    assert _titles(fig) == ["trajectory (odometry frame)", "per-mouse residual (rigidity check)"]
    ax = fig.axes[0]
    paths = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(paths) == 1
    times = paths[0].get_array()
    assert len(times) == len(batch) - 1 and np.all(np.diff(times) > 0)  # coloured by time
    assert any(isinstance(c, Quiver) for c in ax.collections)
    assert sum(isinstance(p, Ellipse) for p in ax.patches) >= 5
    marks = {ln.get_label(): ln for ln in ax.get_lines()}
    assert marks["start"].get_zorder() > marks["end"].get_zorder()
    assert marks["start"].get_markerfacecolor() == "none"  # a ring: the end shows through
    legend = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
    assert legend == ["front (125 Hz)", "left (125 Hz)", "right (125 Hz)"]


def test_one_mouse_gets_no_residual_panel():
    """With one mouse on diff-drive there is no redundant reading, so the residual is
    floating-point noise (1e-17 mm), not a rigidity check: no panel for it."""
    from mousedom import plot
    from mousedom.fusion import sim

    rig = sim.Rig((sim.SimMouse("m", 0.1, 0.0),), model="diff-drive")
    col, _ = _collector(rig, sim.sequence(sim.straight(0.3), sim.turn(1.0)))
    fig = plot.figure(col, ("m",), model="diff-drive", rates={"m": 125.0})
    assert _titles(fig) == ["trajectory (odometry frame)"]
    assert plot.redundancy("diff-drive", 1) == 0 and plot.redundancy("lsq", 2) == 1
    assert plot.redundancy("diff-drive", 2) == 2


def test_excluded_spans_are_shaded_per_mouse_even_when_decimated(monkeypatch):
    """Issue 16: --plot shades where the fault-tolerant fusion left a mouse out, in that
    mouse's colour, and a short exclusion survives decimation (the worst state of the
    rows a kept one stands for)."""
    import dataclasses

    from mousedom import plot
    from mousedom.fusion import sim

    monkeypatch.setattr(plot, "MAX_POINTS", 60)
    rig = sim.three_mouse_rig()
    lifted = dataclasses.replace(rig.mice[1], lost=((1.0, 1.3),))
    faulty = dataclasses.replace(rig, mice=(rig.mice[0], lifted, rig.mice[2]))
    result = sim.simulate(faulty, sim.straight(1.5, 0.3), seed=2)
    batch, _ = sim.run_tracker(result, sim.rig_config(rig))
    assert (batch.state[:, 1] == 2).any()
    col = plot.PlotCollector()
    for k in range(0, len(batch), 7):
        col(_slice(batch, k, k + 7))
    assert col.step > 1  # decimated
    fig = plot.figure(col, ("front", "left", "right"), model="lsq")
    spans = [p for p in fig.axes[1].patches if p.get_label() == "left excluded"]
    assert spans, [p.get_label() for p in fig.axes[1].patches]
    x0 = min(p.get_x() for p in spans)
    assert 0.95 < x0 < 1.2
    assert not [p for p in fig.axes[1].patches if "front" in str(p.get_label())]


def _slice(b, i, j):
    from mousedom.capture.pacing import slice_batch

    return slice_batch(b, i, j)


def _legend_clear_of_path(fig):
    """The legend's box on screen, and the path's points and the x label it must miss."""
    from matplotlib.collections import LineCollection

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    box = ax.get_legend().get_window_extent(renderer)
    (path,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    pts = np.concatenate([seg for seg in path.get_segments()])
    screen = ax.transData.transform(pts)
    inside = box.contains_points(screen) if hasattr(box, "contains_points") else None
    if inside is None:
        inside = (
            (screen[:, 0] >= box.x0) & (screen[:, 0] <= box.x1)
            & (screen[:, 1] >= box.y0) & (screen[:, 1] <= box.y1)
        )  # fmt: skip
    return box, inside, ax.xaxis.label.get_window_extent(renderer), fig.bbox


def test_the_legend_does_not_cover_the_path():
    """Issue 29 item 6: inside the axes, the legend sat on the path (a square fills the
    box, so loc="best" has nowhere to go).  Rendered: its box holds none of the path's
    points, misses the x label, and stays on the figure."""
    from mousedom import plot
    from mousedom.fusion import sim

    for rig, traj, names, model in (
        (sim.three_mouse_rig(), sim.umbmark_square(1.0), ("front", "left", "right"), "lsq"),
        (sim.Rig((sim.SimMouse("m", 0.1, 0.0),), model="diff-drive"),
         sim.sequence(sim.straight(0.3), sim.turn(1.0), sim.straight(0.3)), ("m",),
         "diff-drive"),
    ):  # fmt: skip
        col, _ = _collector(rig, traj)
        fig = plot.figure(col, names, model=model, rates={n: 125.0 for n in names})
        box, inside, xlabel, page = _legend_clear_of_path(fig)
        assert not inside.any(), (box, int(inside.sum()))
        assert not box.overlaps(xlabel), (box, xlabel)
        assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0, (box, page)
        texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert "start" in texts and "end" in texts
