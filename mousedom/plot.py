"""``--plot``: a replay's trajectory (coloured by time, with heading arrows, covariance
ellipses, start and end) and, where the rig has redundant readings, each mouse's residual.

matplotlib is an optional extra (``pip install 'mousedom[plot]'``); ``require()`` checks
for it before a long replay starts, so a missing extra costs no time.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import cast

import numpy as np

from mousedom.errors import UserError
from mousedom.fusion.tracker import PoseBatch
from mousedom.safewrite import replace_file

INSTALL_HINT = (
    "--plot needs matplotlib, which is not installed: "
    "pip install 'mousedom[plot]' (or: pip install matplotlib, or apt install "
    "python3-matplotlib)"
)
MAX_POINTS = 200_000  # enough for any screen; longer replays are decimated as they stream


def require() -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise UserError(INSTALL_HINT) from None


# Columns the collector keeps per window: time, pose, the pose covariance's xy block, then
# each mouse's |residual|, then each mouse's health (fusion.robust.STATES index; where
# rows are decimated, the worst state of the rows a kept one stands for).
T, X, Y, THETA, CXX, CXY, CYY, RES = range(8)


class PlotCollector:
    """A replay sink that keeps what the plot needs, decimated to bounded memory."""

    def __init__(self) -> None:
        self.step = 1
        self._parts: list[np.ndarray] = []
        self._n = 0
        self._skip = 0
        self._last: np.ndarray | None = None
        # the gyro's bias and its sigma (rad/s) at the rows kept, where the rig has one
        self._gyro: list[np.ndarray] = []

    def __call__(self, b: PoseBatch) -> None:
        if not len(b):
            return
        res = np.linalg.norm(b.residual, axis=2)  # (n, N) metres
        cov = b.cov
        state = _worst(b.state)
        rows = np.column_stack(
            [b.t, b.x, b.y, b.theta, cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1], res, state]
        )
        self._last = rows[-1]  # the final pose is marked "end": never decimated away
        idx = np.arange(self._skip, len(b), self.step)
        kept = rows[idx]
        if b.gyro is not None:
            self._gyro.append(np.column_stack([b.t, b.gyro[:, 1], b.gyro[:, 2]])[idx])
        if len(idx) and self.step > 1:
            nm = state.shape[1]
            kept[:, kept.shape[1] - nm :] = np.maximum.reduceat(state, idx, axis=0)
        self._skip = (self._skip - len(b)) % self.step
        self._parts.append(kept)
        self._n += len(kept)
        if self._n > MAX_POINTS:  # halve the resolution of what was kept and of what comes
            data = np.concatenate(self._parts)
            nm = state.shape[1]
            worst = np.maximum.reduceat(data[:, data.shape[1] - nm :], np.arange(0, len(data), 2))
            data = data[::2]
            data[:, data.shape[1] - nm :] = worst
            self._parts, self._n = [data], len(data)
            if self._gyro:
                self._gyro = [np.concatenate(self._gyro)[::2]]
            self.step *= 2

    def gyro(self) -> np.ndarray:
        """(t, bias, bias sigma) of the rows kept, (0, 3) without a gyro."""
        return np.concatenate(self._gyro) if self._gyro else np.zeros((0, 3))

    def data(self) -> np.ndarray:
        last = self._last  # set with the first part
        if not self._parts or last is None:
            return np.zeros((0, RES))
        data = np.concatenate(self._parts)
        if data[-1, 0] != last[0]:
            data = np.vstack([data, last])
        return data


def _worst(state: np.ndarray) -> np.ndarray:
    """Health codes ordered by how bad they are for shading: excluded (2) above suspect
    (1) above tracking (0); missing (3) is not the engine's verdict, shown as tracking."""
    s = np.asarray(state, dtype=float)
    return np.where(s == 3, 0.0, s)


def redundancy(model: str, n_mice: int) -> int:
    """Readings beyond what the model's unknowns need: the residual's degrees of freedom.
    Zero (one mouse on diff-drive or lsq: no reading to spare) means there
    is no residual to show, only floating-point noise."""
    unknowns = 2 if model == "diff-drive" else 3
    return max(0, 2 * n_mice - unknowns)


def figure(
    collector: PlotCollector,
    names: tuple[str, ...],
    *,
    model: str = "lsq",
    rates: dict[str, float] | None = None,
    title: str = "",
):
    """The matplotlib Figure of a replay (tests look at its artists)."""
    require()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Ellipse

    data = collector.data()
    residual = redundancy(model, len(names)) > 0 and data.shape[1] > RES
    gyro = collector.gyro()
    panels = 1 + residual + (len(gyro) > 0)
    fig, axes = plt.subplots(1, panels, figsize=(7 + 5 * (panels - 1), 5.5), squeeze=False)
    ax1 = axes[0][0]
    ax1.set_xlabel("x (m)")
    ax1.set_ylabel("y (m)")
    ax1.set_title("trajectory (odometry frame)")
    ax1.grid(True, alpha=0.3)
    ax1.set_aspect("equal", adjustable="datalim")
    if len(data) >= 2:
        # The path coloured by time: where the robot was when.
        pts = data[:, [X, Y]]
        segs = np.stack([pts[:-1], pts[1:]], axis=1)
        # (The stubs ask for a Sequence of segments: an (n, 2, 2) array is one.)
        line = LineCollection(
            cast(Sequence[np.ndarray], segs), cmap="viridis", linewidths=1.5, zorder=2
        )
        line.set_array(data[1:, T] - data[0, T])
        ax1.add_collection(line)
        fig.colorbar(line, ax=ax1, label="t (s since the start)", shrink=0.8)
        _arrows(ax1, data)
        _ellipses(ax1, data, Ellipse)
        ax1.autoscale_view()
    if len(data):
        # Start: a large ring drawn over everything, so an end at the same place (a closed
        # square) cannot hide it; end: a smaller filled square under it.
        ax1.plot(data[-1, X], data[-1, Y], "s", color="tab:red", ms=7, zorder=4, label="end")
        ax1.plot(data[0, X], data[0, Y], "o", mfc="none", mec="tab:green", mew=2.0, ms=13,
                 zorder=5, label="start")  # fmt: skip
        # Below the axes, clear of the x label: inside them, even loc="best" lands on a
        # path that fills the box (a square, a loop), and the path is what the plot is for.
        ax1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=4, fontsize=8,
                   frameon=False)  # fmt: skip
    if len(gyro):
        _gyro_panel(axes[0][-1], gyro)
    if residual:
        ax2 = axes[0][1]
        health = data[:, RES + len(names) :]
        for i, name in enumerate(names):
            label = name if not rates or name not in rates else f"{name} ({rates[name]:.0f} Hz)"
            (curve,) = ax2.plot(data[:, T], data[:, RES + i] * 1000.0, lw=0.8, label=label)
            if health.shape[1] == len(names):
                _shade(ax2, data[:, T], health[:, i], curve.get_color(), name)
        ax2.set_xlabel("t (s)")
        ax2.set_ylabel("|residual| (mm per window)")
        ax2.set_title("per-mouse residual (rigidity check)")
        ax2.grid(True, alpha=0.3)
        if names:
            ax2.legend(loc="best", title="mouse (report rate)" if rates else None)
    elif rates:  # no residual panel: the rates go with the trajectory
        text = "report rate: " + ", ".join(f"{n} {r:.0f} Hz" for n, r in rates.items())
        ax1.text(0.01, 0.01, text, transform=ax1.transAxes, fontsize=8, color="0.3")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def _gyro_panel(ax, gyro: np.ndarray) -> None:
    """The gyro's learnt bias over time, with its one-sigma band (deg/s)."""
    t, bias, sigma = (np.degrees(gyro[:, k]) if k else gyro[:, k] for k in range(3))
    ok = np.isfinite(bias) & np.isfinite(sigma)
    ax.plot(t[ok], bias[ok], color="tab:purple", lw=1.0, label="bias")
    ax.fill_between(t[ok], bias[ok] - sigma[ok], bias[ok] + sigma[ok], color="tab:purple",
                    alpha=0.2, label="1 sigma")  # fmt: skip
    ax.set_xlabel("t (s)")
    ax.set_ylabel("gyro bias (deg/s)")
    ax.set_title("gyro bias (learnt online)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)


def _shade(ax, t: np.ndarray, state: np.ndarray, color: str, name: str) -> None:
    """Spans where the fault-tolerant fusion excluded the mouse (solid), doubted it
    (hatched) or held it out as late (dotted), in the mouse's colour."""
    names = {2: "excluded", 1: "suspect", 4: "late"}
    for code, style in ((2, {"alpha": 0.18}), (1, {"alpha": 0.08, "hatch": "//"}),
                        (4, {"alpha": 0.05, "hatch": ".."})):  # fmt: skip
        on = state == code
        if not on.any():
            continue
        edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
        label: str | None = f"{name} {names[code]}"
        for a, b in zip(edges[0::2], edges[1::2], strict=True):
            ax.axvspan(t[a], t[min(b, len(t) - 1)], color=color, lw=0, label=label, **style)
            label = None


def _arrows(ax, data: np.ndarray, count: int = 12) -> None:
    """Heading arrows at evenly spaced times: which way the robot faced, and went."""
    idx = np.unique(np.linspace(0, len(data) - 1, count).astype(int))
    span = max(np.ptp(data[:, X]), np.ptp(data[:, Y]), 1e-3)
    size = 0.04 * span
    th = data[idx, THETA]
    ax.quiver(data[idx, X], data[idx, Y], np.cos(th) * size, np.sin(th) * size,
              angles="xy", scale_units="xy", scale=1, width=0.004, color="0.25", zorder=3,
              label="heading")  # fmt: skip


def _ellipses(ax, data: np.ndarray, ellipse_class, count: int = 8) -> None:
    """3-sigma ellipses of the position covariance at evenly spaced times.  Odometry's
    uncertainty is often millimetres on a path of metres: then the ellipses are drawn
    magnified by a power of ten, and the legend says by how much."""
    idx = np.unique(np.linspace(0, len(data) - 1, count).astype(int))[1:]
    if not len(idx):
        return
    cov = np.stack(
        [[data[idx, CXX], data[idx, CXY]], [data[idx, CXY], data[idx, CYY]]], axis=-1
    ).transpose(1, 0, 2)  # (k, 2, 2)
    if not np.isfinite(cov).all():
        return
    vals, vecs = np.linalg.eigh(cov)
    radii = 3.0 * np.sqrt(np.clip(vals, 0.0, None))  # (k, 2)
    span = max(np.ptp(data[:, X]), np.ptp(data[:, Y]), 1e-3)
    largest = radii.max()
    if largest <= 0:
        return
    gain = 1.0
    while largest * gain < 0.02 * span:
        gain *= 10.0
    label = "3-sigma position" + ("" if gain == 1 else f" (x{gain:g})")
    for k, i in enumerate(idx):
        angle = np.degrees(np.arctan2(vecs[k, 1, 1], vecs[k, 0, 1]))
        ax.add_patch(ellipse_class(
            (data[i, X], data[i, Y]), 2 * radii[k, 1] * gain, 2 * radii[k, 0] * gain,
            angle=angle, fill=False, color="tab:orange", lw=1.0, zorder=3,
            label=label if k == 0 else None,
        ))  # fmt: skip


def save(
    collector: PlotCollector,
    names: tuple[str, ...],
    path: str,
    title: str = "",
    *,
    model: str = "lsq",
    rates: dict[str, float] | None = None,
    inputs: Sequence[str] = (),
) -> None:
    """Draw the run and write it to ``path`` (none of ``inputs``: see safewrite)."""
    import matplotlib.pyplot as plt

    fig = figure(collector, names, model=model, rates=rates, title=title)
    kind = os.path.splitext(path)[1].lstrip(".").lower() or "png"
    try:
        # A temporary file beside the target, renamed over it: no link followed.
        replace_file(path, lambda tmp: fig.savefig(tmp, dpi=110, format=kind), inputs)
    except ValueError as e:  # a file ending matplotlib cannot write
        raise UserError(f"{path}: cannot write the plot: {e}") from None
    finally:
        plt.close(fig)
