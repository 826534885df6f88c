"""A mouse a reload removes and a later reload adds back, against the same mouse unplugged
and plugged back without a reload: the daemon's loop on a simulated clock and drive.

A reload's new tracker starts its windows at the reload (or at the end of the window the
old one closed last, after it), and a mouse it opens then was live in it from the start:
its reports stamped before the new windows, and the period its first report reaches back,
were moved into the first window on top of that window's own motion.  Over the mouse's
lever arm that is a turn, up to 0.37 degrees a re-add here.  A mouse plugged back without
a reload is not used in the window it came back in, which takes what its first report
holds from before; a mouse a reload opens is now not used in the new tracker's first
window (``Tracker.set_live``), and a mouse a reload closes is in no window the new tracker
closes, the one still open at the reload among them.

The daemon runs its own loop's steps (``_start``, ``_plan``, ``_window``, the reloader)
on a simulated clock, its mice simulated sources with a descriptor, as evdev's.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from mousedom.config import load_config
from mousedom.fusion import scenarios, sim
from mousedom.fusion.drives import drive as turning_drive
from mousedom.service.daemon import Daemon
from mousedom.service.output import Output
from mousedom.sources.base import Reports, Source, SourceGone, SourceUnavailable

T_START = 100.0
CYCLES = 4  # remove and add back, or unplug and plug back, this many times
EVERY = 3.0  # seconds from one cycle to the next
GAP = 1.0  # seconds without the mouse
STEP = 0.001  # the simulated clock's step: the loop wakes when its plan says, to 1 ms


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


class SimSource(Source):
    """A simulated mouse as evdev gives it: a readable descriptor once a report has
    arrived (its stamp plus a USB delay), and, opened at t, nothing reported before t
    (the kernel keeps no events for a device nobody has open).  ``plugged``: whether
    the mouse is there (unplugged: the read that finds out raises SourceGone)."""

    kind = "sim"

    def __init__(self, name: str, rep: sim.SimReports, arrive: np.ndarray, clock: Clock,
                 plugged: dict[str, bool]) -> None:  # fmt: skip
        super().__init__(name)
        self.rep, self.arrive, self.clock, self.plugged = rep, arrive, clock, plugged
        self.next = 0
        self.r: int | None = None
        self.w: int | None = None

    def _open(self) -> None:
        if not self.plugged.get(self.name, True):
            raise SourceUnavailable(f"{self.name}: unplugged")
        self.next = int(np.searchsorted(self.rep.t, self.clock(), "right"))
        self.r, self.w = os.pipe()
        os.set_blocking(self.r, False)

    def fileno(self) -> int | None:
        return self.r

    def arrived(self, now: float) -> None:
        """Makes the descriptor readable if a report has arrived by ``now``."""
        if self.w is not None and self.next < len(self.arrive) and self.arrive[self.next] <= now:
            os.write(self.w, b"x")

    def _read(self, now: float) -> list[Reports]:
        assert self.r is not None
        try:
            os.read(self.r, 4096)
        except BlockingIOError:
            pass
        if not self.plugged.get(self.name, True):
            raise SourceGone(f"{self.name}: unplugged")
        a, b = self.next, int(np.searchsorted(self.arrive, now, "right"))
        if b <= a:
            return []
        self.next = b
        return [Reports(self.name, self.rep.t[a:b], self.rep.dx[a:b], self.rep.dy[a:b])]

    def close(self) -> None:
        for fd in (self.r, self.w):
            if fd is not None:
                os.close(fd)
        self.r = self.w = None


class Kept(Output):
    def __init__(self) -> None:
        self.rows: list = []

    def publish(self, row) -> None:
        self.rows.append(row)


def _rig(layout: str) -> sim.Rig:
    """Exact mice (no noise, no stamp delay): what differs between a reload and a replug
    is all there is to see."""
    if layout == "three-125":  # tests/test_daemon_e2e.py's rig: three mice at 125 Hz, 50 Hz
        return dataclasses.replace(sim.three_mouse_rig(), rate_hz=50.0)
    if layout == "triangle":  # 125, 500 and 1000 Hz
        return scenarios.rig("triangle", noise=0.0, stamp_delay=0.0)
    assert layout == "square-500", layout
    rig = scenarios.rig("square", noise=0.0, stamp_delay=0.0)  # four, all at 500 Hz here
    return dataclasses.replace(
        rig, mice=tuple(dataclasses.replace(m, report_hz=500.0) for m in rig.mice)
    )


def _config_text(rig: sim.Rig, names: list[str]) -> str:
    text = sim.rig_yaml(dataclasses.replace(rig, mice=tuple(m for m in rig.mice
                                                            if m.name in names)))  # fmt: skip
    lines = []
    for line in text.splitlines():
        lines.append(line)
        if line.startswith("  ") and not line.startswith("    ") and line.endswith(":"):
            lines.append("    evdev: {path: /dev/null}")
    return "\n".join(lines) + "\n"


def _readd_turns(tmp_path: Path, layout: str, drive: str, seed: int, mode: str) -> np.ndarray:
    """The heading error (degrees) each of CYCLES re-adds leaves: its change from just
    before the mouse comes back to half a second after.  ``mode``: "reload" (SIGHUP with
    the mouse left out, then with it back) or "replug" (the same mouse unplugged and
    plugged back, the config unchanged); the same drive and times either way."""
    rig = _rig(layout)
    names = [m.name for m in rig.mice]
    mouse = names[-1]  # off the rig's centre line in each layout: its counts turn the pose
    span = CYCLES * EVERY + 3.0
    if drive == "straight":
        path = sim.sequence(sim.pause(0.5), sim.straight(0.2 * span, 0.2), sim.pause(0.5))
    else:
        path = turning_drive(span, seed)
    result = sim.simulate(rig, path, seed=seed, t_start=T_START)
    rng = np.random.default_rng(seed)
    arrive = {n: np.maximum.accumulate(r.t + rng.uniform(2e-4, 1.5e-3, len(r.t)))
              for n, r in result.reports.items()}  # fmt: skip
    config = tmp_path / f"{mode}.yaml"
    config.write_text(_config_text(rig, names))
    clock, plugged, sources, kept = Clock(T_START), {}, [], Kept()

    def factory(m, c) -> SimSource:
        sources.append(SimSource(m.name, result.reports[m.name], arrive[m.name], c, plugged))
        return sources[-1]

    d = Daemon(load_config(config), str(tmp_path / f"{mode}.sock"), clock=clock,
               source_factory=factory, handle_signals=False, outputs=[kept])  # fmt: skip
    events = []  # (time, the mouse back?), at times that fall anywhere in a window
    for k in range(CYCLES):
        out = T_START + 1.0 + k * EVERY + float(rng.uniform(0, 0.05))
        events += [(out, False), (out + GAP + float(rng.uniform(0, 0.05)), True)]
    d._start()
    try:
        pending = list(events)
        while clock.t < T_START + result.duration:
            clock.t = round(clock.t + STEP, 9)
            for s in sources:
                s.arrived(clock.t)
            while pending and clock.t >= pending[0][0]:
                back = pending.pop(0)[1]
                if mode == "reload":
                    config.write_text(_config_text(rig, names if back else names[:-1]))
                    d.reloader.reload()
                else:
                    plugged[mouse] = back
            if clock.t >= d._plan(clock.t)[0]:  # as the loop: read and close what is due
                d._window(clock.t)
            if d.sensors.missing_names:
                d.sensors.retry(clock.t)
    finally:
        d._shutdown()
    t = np.array([r.t for r in kept.rows])
    theta = np.array([r.theta for r in kept.rows])
    err = np.degrees(np.angle(np.exp(1j * (theta - result.truth(t)[:, 2]))))
    at_back = [at for at, back in events if back]
    return np.array([np.interp(a + 0.5, t, err) - np.interp(a - 0.05, t, err) for a in at_back])


@pytest.mark.parametrize("layout", ["three-125", "triangle", "square-500"])
@pytest.mark.parametrize("drive", ["straight", "turning"])
@pytest.mark.parametrize("seed", [1, 2])
def test_a_mouse_added_back_by_a_reload_turns_the_pose_no_more_than_a_replug(
    tmp_path, layout, drive, seed
):
    """A reload that added a mouse back left up to 0.04-0.37 degrees of heading error
    at a re-add (0.01-1.2 degrees the four together; none of the 12 cases here within the
    bounds), where plugging the mouse back without a reload leaves at most 0.01."""
    reload = _readd_turns(tmp_path, layout, drive, seed, "reload")
    replug = _readd_turns(tmp_path, layout, drive, seed, "replug")
    assert np.abs(reload).max() <= np.abs(replug).max() + 0.015, (reload, replug)
    # ... and what they leave together after the cycles
    assert abs(reload.sum()) <= abs(replug.sum()) + 0.02, (reload.sum(), replug.sum())


def test_a_mouse_back_at_or_before_the_frontier_misses_the_first_window():
    """The tracker's rule alone: a mouse back from a dead span at or before the closed
    frontier (a new tracker's, opened at a reload: Sensors.replace) is not used in the
    first window still open, which takes what its first reports hold from before (here
    the reports stamped before the grid starts, and the period the first one reaches
    back); later windows use it.  A mouse never dead (the daemon's start) is used."""
    from mousedom.fusion.tracker import Tracker

    rig = scenarios.rig("triangle", noise=0.0, stamp_delay=0.0)
    result = sim.simulate(rig, sim.straight(0.1, 0.2), t_start=T_START)
    opened = T_START + 0.195
    for back, used in ((True, [2, 3, 3]), (False, [3, 3, 3])):
        tracker = Tracker(sim.rig_config(rig), t0=T_START + 0.2)
        if back:
            tracker.set_live("right", False, opened)
            tracker.set_live("right", True, opened)
        for name, r in result.reports.items():
            keep = r.t > opened
            tracker.push(name, r.t[keep], r.dx[keep], r.dy[keep])
        out = tracker.finish()
        assert [row.used for row in out.rows()[:3]] == used
        assert np.allclose(tracker.counts_out, tracker.counts_in)  # none lost, all closed


def test_a_mouse_a_reload_removes_is_not_used_in_the_window_still_open(tmp_path):
    """The old tracker closes the windows final at the reload, with every mouse; the new
    one goes on from there and closes the window holding the reload without the removed
    mouse, whose reports stop there."""
    rig = _rig("three-125")
    names = [m.name for m in rig.mice]
    result = sim.simulate(rig, sim.straight(0.6, 0.2), t_start=T_START)
    config = tmp_path / "rig.yaml"
    config.write_text(_config_text(rig, names))
    clock, kept = Clock(T_START), Kept()
    arrive = {n: r.t + 5e-4 for n, r in result.reports.items()}
    sources: list[SimSource] = []

    def factory(m, c) -> SimSource:
        sources.append(SimSource(m.name, result.reports[m.name], arrive[m.name], c, {}))
        return sources[-1]

    d = Daemon(load_config(config), str(tmp_path / "d.sock"), clock=clock,
               source_factory=factory, handle_signals=False, outputs=[kept])  # fmt: skip
    d._start()
    period = 1.0 / rig.rate_hz
    at = T_START + 1.0 + 0.3 * period  # inside a window
    try:
        while clock.t < at:
            clock.t = round(clock.t + STEP, 9)
            for s in sources:
                s.arrived(clock.t)
            if clock.t >= d._plan(clock.t)[0]:
                d._window(clock.t)
        config.write_text(_config_text(rig, names[:-1]))
        before = len(kept.rows)
        d.reloader.reload()
    finally:
        d._shutdown()
    last = [r for r in kept.rows[before:] if r.t - period < at < r.t + 1e-9]
    assert len(last) == 1 and last[0].used == len(names) - 1, last
    old = [r for r in kept.rows if len(r.counts) == len(names)]  # the old tracker's
    assert old and all(r.used == len(names) for r in old)
    assert d.tracker.t0 == old[-1].t < at
    assert all(r.used == len(names) - 1 for r in kept.rows[len(old) :])
