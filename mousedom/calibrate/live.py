"""Interactive runs from live mice: Enter starts a run, Enter stops it.

Prompts and the live counts go to ``out`` (stderr), so that stdout carries only the
report or the JSON.  Every report that arrives between the two Enters belongs to the
run (by arrival, not by stamp, so a mouse whose clock is odd cannot leak into the next
run); motion between runs is counted and shown, not used.  At the stop the sources are
drained, so reports already in the kernel's buffer still count.  ``q`` or the end of
input finishes; a run in progress is closed first.
"""

from __future__ import annotations

import os
import selectors
import time
from collections.abc import Callable, Sequence
from typing import TextIO

import numpy as np

from mousedom.calibrate.runs import Run, in_time_order
from mousedom.errors import UserError
from mousedom.sources.base import Reports, Source, SourceGone, SourceUnavailable

REFRESH = 0.1  # seconds between live count updates


class _Collector:
    def __init__(self, names: Sequence[str]) -> None:
        self.parts: dict[str, list[Reports]] = {n: [] for n in names}
        self.current: dict[str, np.ndarray] = {n: np.zeros(2) for n in names}
        self.between = 0  # counts seen while no run was open
        self.active = False
        self.runs: list[Run] = []
        self._stamps: list[float] = []

    def add(self, batch: Reports) -> None:
        if not len(batch):
            return
        if not self.active:
            self.between += int(np.abs(batch.dx).sum() + np.abs(batch.dy).sum())
            return
        self.parts[batch.mouse].append(batch)
        self.current[batch.mouse] += [batch.dx.sum(), batch.dy.sum()]
        self._stamps += [float(batch.t[0]), float(batch.t[-1])]

    def start(self) -> None:
        self.active = True
        self._stamps = []
        for n in self.current:
            self.current[n] = np.zeros(2)

    def stop(self) -> bool:
        """Close the run; False when nothing moved (the run is not kept)."""
        self.active = False
        if not self._stamps:
            return False
        self.runs.append(Run(min(self._stamps), max(self._stamps)))
        return True

    def recording(self) -> dict[str, Reports]:
        return {
            n: in_time_order(n, [p.t for p in ps], [p.dx for p in ps], [p.dy for p in ps])
            for n, ps in self.parts.items()
        }

    def status(self) -> str:
        return "  ".join(f"{n}: x {c[0]:+.0f} y {c[1]:+.0f}" for n, c in self.current.items())


def collect_runs(
    sources: Sequence[Source],
    stdin_fd: int,
    out: TextIO,
    max_runs: int | None = None,
    what: str = "run",
    clock: Callable[[], float] = time.monotonic,
) -> tuple[dict[str, Reports], list[Run]]:
    """Run the prompt loop until ``max_runs`` runs, ``q`` or end of input."""
    for s in sources:
        try:
            s.open()
        except SourceUnavailable as e:
            text = str(e).removeprefix(f"{s.name}: ")  # sources name their mouse already
            raise UserError(f"mouse {s.name}: {text}") from None
    col = _Collector([s.name for s in sources])
    sel = selectors.DefaultSelector()
    for s in sources:
        sel.register(s.fileno(), selectors.EVENT_READ, s)
    sel.register(stdin_fd, selectors.EVENT_READ, None)
    pending = b""
    last_show = 0.0
    tty = out.isatty()  # live counts redraw one line: only on a terminal

    def drain(source: Source) -> None:
        try:
            while True:
                batches = source.read(clock())
                if not batches:
                    return
                for b in batches:
                    col.add(b)
        except SourceGone as e:
            raise UserError(f"mouse {source.name} went away: {e}") from None

    def prompt() -> None:
        k = len(col.runs) + 1
        out.write(f"{what} {k}: press Enter to start (q and Enter, or end of input, to finish)\n")
        out.flush()

    prompt()
    try:
        while max_runs is None or len(col.runs) < max_runs:
            for key, _ in sel.select(timeout=REFRESH):
                if key.data is not None:
                    drain(key.data)
            if tty and col.active and clock() - last_show >= REFRESH:
                out.write("\r" + col.status())
                out.flush()
                last_show = clock()
            line = None
            if any(k.data is None for k, _ in sel.select(timeout=0)):
                chunk = os.read(stdin_fd, 4096)
                if not chunk:
                    line = b"q"
                else:
                    pending += chunk
            if line is None and b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
            if line is None:
                continue
            quit_ = line.strip().lower() in (b"q", b"quit")
            if col.active:
                for s in sources:
                    drain(s)
                kept = col.stop()
                out.write(("\r" if tty else "") + col.status() + "\n")
                out.write(
                    f"{what} {len(col.runs)} recorded\n"
                    if kept
                    else "nothing moved: run not kept\n"
                )
                if quit_:
                    break
                if max_runs is None or len(col.runs) < max_runs:
                    prompt()
            elif quit_:
                break
            else:
                col.start()
                out.write("moving... press Enter to stop\n")
                last_show = 0.0
            out.flush()
    finally:
        sel.close()
        for s in sources:
            s.close()
    if col.between:
        out.write(f"{col.between} counts arrived between runs and were not used\n")
        out.flush()
    return col.recording(), col.runs
