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
import stat
import time
from collections.abc import Callable, Sequence
from typing import TextIO

import numpy as np

from mousedom.calibrate.runs import Run, in_time_order
from mousedom.errors import UserError
from mousedom.sources.base import Reports, Source, SourceGone, SourceUnavailable

REFRESH = 0.1  # seconds between live count updates
# After a redraw of the counts line: the rest of the old one cleared (ECMA-48 EL), or a
# count that got shorter (-1000 to -999) showed the old one's last digit (-9990)
CLEAR_TO_EOL = "\x1b[K"


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


def _check_stdin(fd: int) -> None:
    """UserError unless ``fd`` can be waited on for Enter presses: a terminal or a pipe
    (or a socket).  /dev/null and regular files cannot be (epoll refuses them: a traceback
    before), nor a closed stdin."""
    try:
        mode = os.fstat(fd).st_mode
    except OSError:
        raise UserError(
            "live calibration reads Enter presses on stdin, which is closed: "
            "run it at a terminal, or give the runs with --capture"
        ) from None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode) or fd < 0:
        what = "a file"
    elif stat.S_ISCHR(mode) and not os.isatty(fd):
        what = "a device that is no terminal (/dev/null?)"
    else:
        return
    raise UserError(f"live calibration reads Enter presses on stdin, which is {what}: run it "
                    "at a terminal or pipe the Enter presses in, or give the runs with "
                    "--capture")  # fmt: skip


def collect_runs(
    sources: Sequence[Source],
    stdin_fd: int,
    out: TextIO,
    max_runs: int | None = None,
    what: str = "run",
    clock: Callable[[], float] = time.monotonic,
) -> tuple[dict[str, Reports], list[Run]]:
    """Run the prompt loop until ``max_runs`` runs, ``q`` or end of input."""
    _check_stdin(stdin_fd)
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
    session = _Session(sources, sel, stdin_fd, out, col, max_runs, what, clock)
    session.prompt()
    try:
        session.loop()
    finally:
        sel.close()
        for s in sources:
            s.close()
    if col.between:
        out.write(f"{col.between} counts arrived between runs and were not used\n")
        out.flush()
    return col.recording(), col.runs


class _Session:
    """The prompt loop of ``collect_runs``: the mice read as they report, the live counts
    shown, and each line of input starting or stopping a run."""

    def __init__(
        self,
        sources: Sequence[Source],
        sel: selectors.BaseSelector,
        stdin_fd: int,
        out: TextIO,
        col: _Collector,
        max_runs: int | None,
        what: str,
        clock: Callable[[], float],
    ) -> None:
        self.sources, self.sel, self.stdin_fd, self.out = sources, sel, stdin_fd, out
        self.col, self.max_runs, self.what, self.clock = col, max_runs, what, clock
        self.pending = b""  # input read but not yet a whole line
        self.last_show = 0.0
        self.tty = out.isatty()  # live counts redraw one line: only on a terminal

    def loop(self) -> None:
        while self.more_runs():
            for key, _ in self.sel.select(timeout=REFRESH):
                if key.data is not None:
                    self.drain(key.data)
            self.show_counts()
            line = self.next_line()
            if line is None:
                continue
            if self.answer(line):
                break
            self.out.flush()

    def more_runs(self) -> bool:
        return self.max_runs is None or len(self.col.runs) < self.max_runs

    def drain(self, source: Source) -> None:
        try:
            while True:
                batches = source.read(self.clock())
                if not batches:
                    return
                for b in batches:
                    self.col.add(b)
        except SourceGone as e:
            text = str(e).removeprefix(f"{source.name}: ")  # (sources name their mouse)
            raise UserError(f"mouse {source.name} went away: {text}") from None

    def prompt(self) -> None:
        k = len(self.col.runs) + 1
        self.out.write(
            f"{self.what} {k}: press Enter to start (q and Enter, or end of input, to finish)\n"
        )
        self.out.flush()

    def show_counts(self) -> None:
        if self.tty and self.col.active and self.clock() - self.last_show >= REFRESH:
            self.out.write("\r" + self.col.status() + CLEAR_TO_EOL)
            self.out.flush()
            self.last_show = self.clock()

    def next_line(self) -> bytes | None:
        """A whole line of input if there is one (``q`` at the end of input), else None."""
        if any(k.data is None for k, _ in self.sel.select(timeout=0)):
            chunk = os.read(self.stdin_fd, 4096)
            if not chunk:
                return b"q"
            self.pending += chunk
        if b"\n" in self.pending:
            line, self.pending = self.pending.split(b"\n", 1)
            return line
        return None

    def answer(self, line: bytes) -> bool:
        """Start or stop a run; True when the user is done."""
        quit_ = line.strip().lower() in (b"q", b"quit")
        col, out = self.col, self.out
        if col.active:
            for s in self.sources:
                self.drain(s)
            kept = col.stop()
            out.write(("\r" + col.status() + CLEAR_TO_EOL if self.tty else col.status()) + "\n")
            out.write(
                f"{self.what} {len(col.runs)} recorded\n"
                if kept
                else "nothing moved: run not kept\n"
            )
            if quit_:
                return True
            if self.more_runs():
                self.prompt()
        elif quit_:
            return True
        else:
            col.start()
            out.write("moving... press Enter to stop\n")
            self.last_show = 0.0
        return False
