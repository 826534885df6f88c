"""``--plot``: the trajectory and the per-mouse residuals of a replay, as a PNG.

matplotlib is an optional extra (``pip install 'mousedom[plot]'``); ``require()`` checks
for it before a long replay starts, so a missing extra costs no time.
"""

from __future__ import annotations

import os

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


class PlotCollector:
    """A replay sink that keeps what the plot needs, decimated to bounded memory."""

    def __init__(self) -> None:
        self.step = 1
        self._parts: list[np.ndarray] = []  # rows: t, x, y, residual per mouse ...
        self._n = 0
        self._skip = 0
        self._last: np.ndarray | None = None

    def __call__(self, b: PoseBatch) -> None:
        if not len(b):
            return
        res = np.linalg.norm(b.residual, axis=2)  # (n, N) metres
        rows = np.column_stack([b.t, b.x, b.y, res])
        self._last = rows[-1]  # the final pose is marked "end": never decimated away
        rows = rows[self._skip :: self.step]
        self._skip = (self._skip - len(b)) % self.step
        self._parts.append(rows)
        self._n += len(rows)
        if self._n > MAX_POINTS:  # halve the resolution of what was kept and of what comes
            data = np.concatenate(self._parts)[::2]
            self._parts, self._n = [data], len(data)
            self.step *= 2

    def data(self) -> np.ndarray:
        if not self._parts:
            return np.zeros((0, 3))
        data = np.concatenate(self._parts)
        if data[-1, 0] != self._last[0]:
            data = np.vstack([data, self._last])
        return data


def save(collector: PlotCollector, names: tuple[str, ...], path: str, title: str = "") -> None:
    require()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = collector.data()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.5))
    ax1.plot(data[:, 1], data[:, 2], lw=1.0)
    if len(data):
        ax1.plot(data[0, 1], data[0, 2], "go", label="start")
        ax1.plot(data[-1, 1], data[-1, 2], "rs", label="end")
        ax1.legend(loc="best")
    ax1.set_xlabel("x (m)")
    ax1.set_ylabel("y (m)")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_title("trajectory (odometry frame)")
    ax1.grid(True, alpha=0.3)
    for i, name in enumerate(names):
        if data.shape[1] > 3 + i:
            ax2.plot(data[:, 0], data[:, 3 + i] * 1000.0, lw=0.8, label=name)
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("|residual| (mm per window)")
    ax2.set_title("per-mouse residual (rigidity check)")
    ax2.grid(True, alpha=0.3)
    if names:
        ax2.legend(loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    kind = os.path.splitext(path)[1].lstrip(".").lower() or "png"
    try:
        # A temporary file beside the target, renamed over it: no link followed.
        replace_file(path, lambda tmp: fig.savefig(tmp, dpi=110, format=kind))
    except ValueError as e:  # a file ending matplotlib cannot write
        raise UserError(f"{path}: cannot write the plot: {e}") from None
    finally:
        plt.close(fig)
