"""A window whose edges cut a long report span is the common case too (issue 28).

A mouse reports only when it has counts, so at a slow speed a 1 kHz mouse's reports come
several milliseconds apart, and a window's edge then cuts a span longer than 1.5 report
periods (``CountFunction._cut_spans``); the noise model's granularity term grows for it,
its change of motion taken from what the others moved the mouse (``Screen._span_p``).  On
the named layouts (mice at 125-1000 Hz) half the windows of an ordinary drive cut one.
They all went to ``Screen.decide``, a few hundred microseconds each in the daemon and
two thirds of replay's time; the common case (``steady.steady_window`` in the daemon,
``screenbatch._fast_rows`` in replay, csrc/steady.c) now takes them with the same term.

Here, on generated rigs and drives, window by window as the daemon closes them: every
window the common case accepts with a cut span, ``decide`` (on a copy of the screen as it
stood) accepts alike, with the same mice, health, predictions and noise samples; replay
decides every window as the daemon does; and a healthy drive leaves the decision almost
no window."""

from __future__ import annotations

import copy
import re
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO
from layouts import random_layout
from live_drive import live_windows

from mousedom.fusion import conditions, robust, scenarios, sim

LAYOUTS = ("triangle", "square", "pentagon", "wide", "kite", "offset-ring")


def _random_rig(seed: int) -> sim.Rig:
    """3-6 mice anywhere, each at its own rate and CPI (one at 1 kHz and 400 CPI), stamps a
    little late."""
    rng = np.random.default_rng((2817, seed))
    n = int(rng.integers(3, 7))
    xy = random_layout(rng, n, str(rng.choice(["ring", "scatter", "bunched"])))
    hz = rng.choice([125.0, 250.0, 500.0, 1000.0], n)
    cpi = rng.choice([400.0, 800.0, 1000.0, 1600.0], n)
    # one at 1 kHz and 400 CPI at least: a fast mouse of few counts is the one whose reports
    # come apart when the robot is slow (without one, a drive here may cut a span in a few
    # windows or none)
    fast = int(rng.integers(n))
    hz[fast], cpi[fast] = 1000.0, 400.0
    mice = tuple(
        sim.SimMouse(
            f"m{k}",
            float(xy[k, 0]),
            float(xy[k, 1]),
            yaw=float(rng.uniform(-180, 180)),
            cpi_x=float(cpi[k]),
            cpi_y=float(cpi[k]),
            report_hz=float(hz[k]),
            phase=float(rng.uniform(0, 1 / hz[k])),
            noise=0.3,
            stamp_delay=float(rng.uniform(0.0, 0.002)),
        )  # fmt: skip
        for k in range(n)
    )
    return sim.Rig(mice)


def _rig(case: str) -> tuple[sim.Rig, object]:
    """The case's rig, and the config it is run with."""
    kind, _, seed = case.partition(":")
    if kind == "gaps":  # USB gaps and late stamps on a named layout: silences, catch-ups
        layout, _, k = seed.partition("-")
        base = scenarios.rig(layout)
        cond = conditions.condition("usb-gaps+late-stamps", int(k))
        return conditions.apply_condition(base, cond, 8.0), conditions.condition_config(base, cond)
    rig = _random_rig(int(seed)) if kind == "random" else scenarios.rig(kind)
    return rig, sim.rig_config(rig)


CASES = [*(f"{name}:0" for name in LAYOUTS), *(f"random:{s}" for s in range(6)),
         "gaps:triangle-12", "gaps:square-7", "gaps:pentagon-3"]  # fmt: skip


class _Twin:
    """Screen.fast_one, checked: each window it accepts with a cut span is decided again
    by ``decide`` on a copy of the screen made before it, and the two compared."""

    def __init__(self) -> None:
        self.cut = 0  # windows handed to fast_one with a cut span
        self.accepted = 0  # of which it accepted
        self.fast_one = robust.Screen.fast_one
        self.decide = robust.Screen.decide
        self.decided = 0  # windows with a cut span decided (either path's)
        self.silent_cut = 0  # of which a live mouse read nothing (a silence may open)

    def install(self, monkeypatch: pytest.MonkeyPatch) -> None:
        twin = self

        def fast_one(self, d, q, live, evidence, defer_block_end=False, spans=None):
            cut = spans is not None and not evidence and any(s > 0 for s in spans)
            before = copy.deepcopy(self) if cut else None
            ok = twin.fast_one(self, d, q, live, evidence, defer_block_end, spans)
            if cut:
                twin.cut += 1
            if ok and before is not None:
                twin.accepted += 1
                twin.compare(self, before, d, live, spans, defer_block_end)
            return ok

        def decide(self, d, live, squal_scale=None, low_quality=None, spans=None,
                   defer_block_end=False):  # fmt: skip
            if spans is not None and np.any(np.asarray(live) & (np.asarray(spans) > 0)):
                twin.decided += 1
                reads = np.asarray(d, dtype=float).reshape(-1, 2)
                quiet = np.sum(reads * reads, axis=1) <= 1e-6 * self.noise.sig2
                twin.silent_cut += bool(np.any(np.asarray(live) & quiet))
            return twin.decide(self, d, live, squal_scale, low_quality, spans, defer_block_end)

        monkeypatch.setattr(robust.Screen, "fast_one", fast_one)
        monkeypatch.setattr(robust.Screen, "decide", decide)

    def compare(self, fast: robust.Screen, other: robust.Screen, d, live, spans, defer) -> None:
        dec = self.decide(other, np.array(d, dtype=float).reshape(-1, 2),
                          np.array(live, dtype=bool), spans=np.array(spans, dtype=float),
                          defer_block_end=defer)  # fmt: skip
        assert dec.used.tolist() == list(live)
        assert dec.consistent and dec.inflate == 1.0 and dec.correction is None
        assert [h.state for h in other.health] == [h.state for h in fast.health]
        assert [h.reason for h in other.health] == [h.reason for h in fast.health]
        np.testing.assert_allclose(other._prev, fast._prev, rtol=1e-9, atol=1e-15)
        # the silences' accounts and the ledger's (a late mouse's debt from before its
        # hold is a silence's: the common case left one kept at the floor's error where
        # the decision keeps it at the window's, and a drive ended 67 mm off for 30)
        mine, theirs = fast.silences, other.silences
        assert list(mine.silent) == list(theirs.silent)
        np.testing.assert_allclose(np.asarray(mine.sum), np.asarray(theirs.sum), rtol=1e-7,
                                   atol=1e-12)  # fmt: skip
        np.testing.assert_allclose(np.asarray(mine.s2), np.asarray(theirs.s2), rtol=1e-7)
        for name in ("owed", "pre", "pre_s2"):
            np.testing.assert_allclose(np.asarray(getattr(fast.ledger, name)),
                                       np.asarray(getattr(other.ledger, name)), rtol=1e-7,
                                       atol=1e-12)  # fmt: skip
        # the noise model's samples: the same mice, the same values (but for the last bits
        # of the two solves' predictions)
        for mine, theirs in ((fast.noise._floor, other.noise._floor),
                             (fast.noise._prop, other.noise._prop)):  # fmt: skip
            for a, b in zip(mine, theirs, strict=True):
                assert len(a) == len(b)
                if len(a):
                    np.testing.assert_allclose(_last(a), _last(b), rtol=1e-7, atol=1e-12)


def _last(samples, k: int = 8) -> np.ndarray:
    """A noise model store's newest ``k`` samples, read without forgetting any (its own
    ``newest`` keeps only those)."""
    chunks = [np.asarray(c, dtype=float) for c in samples._chunks]
    return np.concatenate(chunks)[-k:]


@pytest.mark.parametrize("case", CASES)
def test_a_cut_span_is_accepted_by_the_common_case_as_decide_accepts_it(case, monkeypatch):
    rig, cfg = _rig(case)
    seed = 31 + CASES.index(case)
    result = sim.simulate(rig, scenarios.drive(8.0, seed), seed=seed)
    twin = _Twin()
    twin.install(monkeypatch)
    live, daemon = live_windows(cfg, result)
    # the check ran, and most windows with a cut span are the common case's (before, every
    # one was decided: a third to half of all windows on most of these rigs).  What is left
    # to the decision is mostly a coarse mouse's count that reads short of its motion at a
    # slow speed (the shortfall's sum is the decision's to keep): a third of them on one
    # rig here with two 1 kHz mice of 400 CPI.
    windows = len(live.t)
    assert twin.cut >= 10, (twin.cut, windows)
    assert twin.accepted > 0.6 * twin.cut, (twin.accepted, twin.cut)
    # replay (the batch) decides every window as the daemon did
    silent_cut, twin.decided, twin.silent_cut = twin.silent_cut, 0, 0
    batch, replay = scenarios.run(result, cfg)
    assert len(batch.t) == windows
    np.testing.assert_array_equal(batch.state, live.state)
    np.testing.assert_array_equal(batch.reason, live.reason)
    for field in ("x", "y", "theta"):
        np.testing.assert_allclose(getattr(batch, field), getattr(live, field), rtol=0, atol=1e-9)
    # with the same noise learnt from the same samples (the granularity term alike)
    for name in ("lam_f", "lam_r"):
        np.testing.assert_allclose(getattr(replay.screen.noise, name),
                                   getattr(daemon.screen.noise, name), rtol=1e-6)  # fmt: skip
    # and leaves the decision those the daemon does, and at most as many again (replay also
    # decides the window after one the decision left altered)
    left = twin.cut - twin.accepted
    assert twin.decided <= 2 * left, (twin.decided, twin.cut, twin.accepted)
    # those in which a mouse read nothing among them: a silence's account is the decision's
    assert twin.silent_cut >= silent_cut, (twin.silent_cut, silent_cut)


def test_a_late_mouse_after_a_silence_through_cut_spans_is_paid_back():
    """scripts/fault_sweep.py --seed 12 --only 116 (a triangle whose front mouse jumps,
    under USB gaps and late stamps): when the common case first took windows that cut a
    long span, a silence's account through them was kept at the floor's error
    (``Silences.rows``) where the decision keeps each window at its own (``_runs``, the
    span's term with it). The right mouse, held late at 7.72 s, then brought in less debt
    from before its hold, was not found paid back (20.9 against a threshold of 18.4,
    17.3 before), and was excluded for 1.3 s: 67.1 mm off at the end, against 30.5 with
    fault handling off and before.  Such windows are the decision's again
    (``Screen.fast_one``, ``screenbatch._cut_rows``)."""
    done = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "fault_sweep.py"), "--drives", "300",
         "--seed", "12", "--only", "116", "--jobs", "1"],
        capture_output=True, text=True, timeout=300, cwd=REPO,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    row = done.stdout.splitlines()[0]
    m = re.search(r"default\s+([\d.]+) mm.*off\s+([\d.]+) mm", row)
    assert m is not None and row.startswith("k=116 "), row
    default, off = float(m[1]), float(m[2])
    assert default <= 1.1 * off + 2.0, row
