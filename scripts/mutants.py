#!/usr/bin/env python3
"""Deliberate bugs, one at a time, against the tests that claim to catch them.

    python scripts/mutants.py [--only NAME ...] [--list]

Each mutant replaces one exact piece of source text (it must occur exactly once) in a
fresh copy of the checkout, then runs the tests named for it there (``pytest -x -q``).
"caught" means those tests failed ("hung": they did not finish in TIMEOUT_S, which is how
a bug that makes the work grow without bound shows); "MISSED" means they passed with the
bug in: a test that does not do its job.  Before the mutants, the same tests run on the
unmutated copy and must pass, or the table would mean nothing.  Exit status 1 if any
mutant is missed.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Mutant:
    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]
    why: str


MUTANTS = [
    Mutant(
        "cov-heading-after-array",
        "mousedom/fusion/tracker_batch.py",
        "theta_before = np.concatenate([[carried.pose[2]], poses[:-1, 2]])",
        "theta_before = poses[:, 2]",
        ("tests/test_covariance_truth.py",),
        "window noise rotated by the heading after the window (array path)",
    ),
    Mutant(
        "cov-heading-after-one-window",
        "mousedom/fusion/onewindow.py",
        "g = noise(th0, ux, uy, a + owed, c3)",
        "g = noise(th, ux, uy, a + owed, c3)",
        ("tests/test_covariance_truth.py",),
        "window noise rotated by the heading after the window (one-window path)",
    ),
    Mutant(
        "interp-bisect-left",
        "mousedom/fusion/countfunction.py",
        "j = bisect_right(xp, x) - 1",
        "j = bisect_left(xp, x) - 1",
        ("tests/test_window_rules.py",),
        "repeated knots on a window edge evaluated on the wrong side",
    ),
    Mutant(
        "two-periods-back-array",
        "mousedom/fusion/countfunction.py",
        "start = np.where(gap <= self.bridge, prev, t - self.period)",
        "start = np.where(gap <= self.bridge, prev, t - 2 * self.period)",
        ("tests/test_window_rules.py",),
        "a report reaches two report periods back (array ingest)",
    ),
    Mutant(
        "catch-up-report-one-period-array",
        "mousedom/fusion/countfunction.py",
        "start = np.where(gap <= self.bridge, prev, t - self.period)",
        "start = np.where(gap <= self.period, prev, t - self.period)",
        ("tests/test_window_rules.py",),
        "a catch-up report covers one period only, not the polls skipped (array ingest)",
    ),
    Mutant(
        "bunched-reports-never-join-list",
        "mousedom/fusion/countfunction.py",
        "            gap < join\n",
        "            gap < 0.0\n",
        ("tests/test_window_rules.py",),
        "reports bunched after a delay do not join the span before (list ingest)",
    ),
    Mutant(
        "noise-fit-ignores-the-tail",
        "mousedom/fusion/noisemodel.py",
        "    return np.maximum(middle, (_TAIL_TO_MEDIAN if tail is None else tail) * rows[:, hi])",
        "    return middle",
        ("tests/test_noisemodel.py",),
        "the noise factors fit the median only: a late mouse's heavy tail is shut out",
    ),
    Mutant(
        "no-reexamination-of-earlier-blame",
        "mousedom/fusion/robust.py",
        "else self._reexamine(d, live, used, gate, scale, gran2, spans)",
        "else None",
        ("tests/test_robust_pairs.py",),
        "a healthy mouse blamed where the geometry could not tell stays out for good",
    ),
    Mutant(
        "continuity-judged-from-the-bent-previous-window",
        "mousedom/fusion/robust.py",
        "                    before = self.predict(q_then)",
        "                    pass",
        ("tests/test_robust_pairs.py",),
        "the tie break's continuity from the previous window, which a creeping fault bent",
    ),
    Mutant(
        "sorted-shortcut-forgets-last-push",
        "mousedom/fusion/countfunction.py",
        "        prev = np.concatenate([[self.knot_t], t[:-1]])  # each report's previous stamp\n",
        "        prev = np.concatenate([[-math.inf], t[:-1]])  # each report's previous stamp\n",
        ("tests/test_tracker.py",),
        "a push starting behind the previous one is not clamped (array ingest)",
    ),
    Mutant(
        "two-periods-back-list",
        "mousedom/fusion/countfunction.py",
        "        start = prev if gap <= bridge else ti - period\n",
        "        start = prev if gap <= bridge else ti - 2 * period\n",
        ("tests/test_window_rules.py",),
        "a report reaches two report periods back (list ingest)",
    ),
    Mutant(
        "pose-line-cov-rows-swapped",
        "mousedom/service/protocol.py",
        "    c0, c1, c2 = cov\n",
        "    c1, c0, c2 = cov\n",
        ("tests/test_encode_pose.py",),
        "encode_pose writes the covariance's x and y rows swapped",
    ),
    Mutant(
        "pose-message-cov-rows-swapped",
        "mousedom/service/protocol.py",
        '"cov": [[_finite(c) for c in row] for row in cov],',
        '"cov": [[_finite(c) for c in row] for row in (cov[1], cov[0], cov[2])],',
        ("tests/test_encode_pose.py",),
        "pose_message writes the covariance's x and y rows swapped",
    ),
    Mutant(
        "evemu-abs-value",
        "mousedom/capture/evemu_lines.py",
        'va = (-1 if value[:1] == b"-" else 1) * int(digits)',
        "va = int(digits)",
        ("tests/test_capture_evemu.py",),
        "the careful evemu line parser drops the value's sign",
    ),
    Mutant(
        "evemu-regular-sign",
        "mousedom/capture/evemu_lines.py",
        "return Events(sec + usec / 1_000_000, typ, code, value, line)",
        "return Events(sec + usec / 1_000_000, typ, code, np.abs(value), line)",
        ("tests/test_capture_evemu.py",),
        "the fixed-offset evemu parser drops the value's sign",
    ),
    Mutant(
        "evemu-block-lines",
        "mousedom/capture/evemu.py",
        "lines = len(ev)  # the fast",
        "lines = len(ev) - 1  # the fast",
        ("tests/test_capture_evemu.py",),
        "an error after a few blocks is named by the wrong line number",
    ),
    Mutant(
        "evemu-general-sign",
        "mousedom/capture/evemu_lines.py",
        "value = _digits(b, s3 + 1 + (neg | pos), vend, 10, 10)\n",
        "value = _digits(b, s3 + 1 + (neg | pos), vend, 10, 10)\n    neg = neg & False\n",
        ("tests/test_capture_evemu.py",),
        "the general vectorised evemu parser drops the value's sign",
    ),
    Mutant(
        "clamp-list-does-not-write",
        "mousedom/sources/base.py",
        "            t[i] = run\n",
        "            pass\n",
        ("tests/test_evdev_clamp.py",),
        "the live read's clamp counts a stamp moved but leaves it behind",
    ),
    Mutant(
        "design-matrix-sign",
        "mousedom/fusion/geometry.py",
        "a[0::2, 2] = -p[:, 1]",
        "a[0::2, 2] = p[:, 1]",
        ("tests/test_models.py", "tests/test_seed_kimlee.py"),
        "Kim & Lee eq. (6) with the sign of -p_y dtheta flipped",
    ),
    Mutant(
        "protocol-id-unchecked",
        "mousedom/service/protocol.py",
        '    cmd_id = _valid_id(obj.get("id"))\n',
        '    cmd_id = obj.get("id")\n',
        ("tests/test_server_protocol.py",),
        "an id that cannot be echoed as JSON (1e999) reaches the reply",
    ),
    Mutant(
        "yaml-alias-unbounded",
        "mousedom/safeyaml.py",
        "        if size > max_nodes or total > max_nodes:\n",
        "        if False:\n",
        ("tests/test_safeyaml.py",),
        "an alias bomb is built instead of refused",
    ),
    Mutant(
        "libinput-blank-field",
        "mousedom/capture/libinput_rows.py",
        "        if not _every_field_has_a_digit(joined):\n",
        "        if False:\n",
        ("tests/test_capture_messy.py",),
        "a blank field (or a lone sign) in a libinput row is read as 0",
    ),
    Mutant(
        "gap-windowed-through",
        "mousedom/capture/replay.py",
        "            if self.skip_gap():\n",
        "            if False:\n",
        ("tests/test_replay_gaps.py",),
        "a gap of 1.3e9 s is windowed through (cost by time span)",
    ),
    Mutant(
        "robust-never-excludes",
        "mousedom/fusion/robust.py",
        "            elif blamed is not None:\n",
        "            elif False:\n",
        ("tests/test_robust.py",),
        "the fault-tolerant fusion finds the faulty mouse but never leaves it out",
    ),
    Mutant(
        "robust-no-proportional-noise",
        "mousedom/fusion/noisemodel.py",
        "        return self.lam_f * self.sig2, self.lam_r * (self.rho2 * m2 + g2 * a2)\n",
        "        return self.lam_f * self.sig2, 0.0 * m2\n",
        ("tests/test_robust.py",),
        "the expected error forgets the part in proportion to motion: false alarms",
    ),
    Mutant(
        "robust-never-readmits",
        "mousedom/fusion/readmission.py",
        "        elif shows:\n            h.good += k\n",
        "        elif shows:\n            h.good += 0\n",
        ("tests/test_robust.py",),
        "an excluded mouse that agrees again is never used again",
    ),
    Mutant(
        "late-mouse-debt-dropped",
        "mousedom/fusion/ledger.py",
        "            if self.paid(i):\n",
        "            if False:\n",
        ("tests/test_reconcile.py",),
        "a late mouse excluded by mistake is not given back the counts it owed",
    ),
    Mutant(
        "readmitted-mouse-given-nothing-it-agreed",
        "mousedom/fusion/ledger.py",
        "        if good >= self.evidence:\n",
        "        if False:\n",
        ("tests/test_reconcile.py",),
        "a mouse re-admitted after a jump or a lift loses the windows it agreed in meanwhile",
    ),
    Mutant(
        "fault-onset-kept",
        "mousedom/fusion/robust.py",
        "            score += float(r @ u) / math.sqrt(s2 * spread) - 1.0\n",
        "            score += -1.0\n",
        ("tests/test_reconcile.py",),
        "the window a fault began in, within the test, keeps the fault's share for good",
    ),
    Mutant(
        "take-back-past-readmission",
        "mousedom/fusion/robust.py",
        "        sets = list(self.used_history)[::-1]\n",
        "        sets = [(True,) * self.n] * len(rows)\n",
        ("tests/test_reconcile.py",),
        "windows a mouse was not used in are taken back from the pose as if it had been",
    ),
    Mutant(
        "saturated-mouse-given-nothing-back",
        "mousedom/fusion/readmission.py",
        "                ledger.readmit(i, h.good)\n"
        "                h.state, h.reason, h.good = TRACKING, NONE, 0\n        elif shows:",
        "                pass\n"
        "                h.state, h.reason, h.good = TRACKING, NONE, 0\n        elif shows:",
        ("tests/test_reconcile.py",),
        "a mouse back from its sensor's word loses the windows it agreed in meanwhile",
    ),
    Mutant(
        "lifted-mouse-silence-agrees",
        "mousedom/fusion/readmission.py",
        "        if h.good > 0 or (shows and k <= self._group):\n",
        "        if True:\n",
        ("tests/test_reconcile.py",),
        "a lifted mouse's silence, within a tolerance the motion widened, is given back",
    ),
    Mutant(
        "span-term-from-its-own-reading",
        "mousedom/fusion/robust.py",
        "                out[i] = others_word(dx, dy, float(p[i, 0]), float(p[i, 1]), gains[i])\n",
        "                out[i] = p[i]\n",
        ("tests/test_lateness.py",),
        "a jump spread over a cut report span widens its own tolerance and is kept",
    ),
    Mutant(
        "span-common-case-from-its-own-reading",
        "mousedom/fusion/steady.py",
        "            fx, fy = ox - rig.prev[i][0], oy - rig.prev[i][1]\n",
        "            fx, fy = px - rig.prev[i][0], py - rig.prev[i][1]\n",
        ("tests/test_span_common_case.py",),
        "the common case takes a cut span's change of motion from its own prediction",
    ),
    Mutant(
        "span-common-case-without-its-term",
        "mousedom/fusion/robust.py",
        "        gran2 = nm.f_gran2 if spans is None else nm.f_gran2_for(spans)\n",
        "        gran2 = nm.f_gran2\n",
        ("tests/test_span_common_case.py",),
        "the common case tests and learns a cut span's window without its granularity term",
    ),
    Mutant(
        "span-common-case-keeps-silences",
        "mousedom/fusion/robust.py",
        "        if spans is not None and (self.silences.any or self._any_silent(d, live)):\n",
        "        if False:\n",
        ("tests/test_span_common_case.py",),
        "a silence's account through a cut span kept at the floor's error: a late mouse excluded",
    ),
    Mutant(
        "replay-span-rows-keep-silences",
        "mousedom/fusion/screenbatch.py",
        "    evidence |= silent_cut\n",
        "    pass\n",
        ("tests/test_span_common_case.py",),
        "replay's common case keeps a silence's account through a cut span at the floor",
    ),
    Mutant(
        "replay-span-rows-from-their-own-reading",
        "mousedom/fusion/screenbatch.py",
        "        floor, prop = sc.noise.parts(d, p, prev_p, m2, gran2=gran2, gran_p=gran_p)\n",
        "        floor, prop = sc.noise.parts(d, p, prev_p, m2, gran2=gran2)\n",
        ("tests/test_span_common_case.py",),
        "replay's array screen takes a cut span's change of motion from its own prediction",
    ),
    Mutant(
        "sparse-mouse-planned-on-its-period",
        "mousedom/service/wake.py",
        "            step = round(gap / period) * period\n",
        "            step = period\n",
        ("tests/test_daemon.py",),
        "the loop wakes on a slow mouse's period and then for every report of the others",
    ),
    Mutant(
        "sparse-wake-on-the-prediction",
        "mousedom/service/wake.py",
        "        early = min(step - period, period)\n",
        "        early = 0.0\n",
        ("tests/test_daemon.py",),
        "a slow mouse's report stamped a little late leaves its window waiting for the wake",
    ),
    Mutant(
        "sparse-edge-woken-early",
        "mousedom/service/wake.py",
        "            wake = max(wake, min(edge + 0.5 * period + latency, first - early))\n",
        "            wake = max(wake, min(edge + 0.5 * period + latency, first) - early)\n",
        ("tests/test_daemon.py",),
        "a slow mouse's report on the window's end: woken before the window is final by time",
    ),
    Mutant(
        "still-mouse-watched-with-every-source",
        "mousedom/service/daemon.py",
        "        usable = len(each) == len(waited) and all(fd < FD_SETSIZE for fd, _ in each)\n",
        "        usable = False\n",
        ("tests/test_daemon.py",),
        "a window waiting for a still mouse wakes at every report of the others",
    ),
    Mutant(
        "joined-report-taken-for-final",
        "mousedom/service/wake.py",
        "    if gap is None or gap < 0.5 * period:\n        return None\n",
        "    if gap is None:\n        return None\n",
        ("tests/test_daemon.py",),
        "a report joined to the one before is taken to end the wait for its mouse",
    ),
    Mutant(
        "buffers-bounded-by-the-slowest-mouse",
        "mousedom/service/wake.py",
        "    return waited, read_at + ALONE_REPORTS * min(p for p, _, _, _ in mice)\n",
        "    return waited, read_at + ALONE_REPORTS * max(p for p, _, _, _ in mice)\n",
        ("tests/test_daemon.py",),
        "the others' kernel buffers wait as long as the slowest mouse's would hold: overflow",
    ),
    Mutant(
        "span-after-a-silence-from-the-report-before",
        "mousedom/service/wake.py",
        "    return last - gap if gap <= max(period, bridge) else last - period\n",
        "    return last - gap\n",
        ("tests/test_daemon.py",),
        "a report after a long silence is waited for though its span begins past the end",
    ),
    Mutant(
        "still-mouse-waited-past-its-silence",
        "mousedom/service/wake.py",
        "        final = final_by_time(end, period, latency, bridge, last)\n",
        "        final = math.inf\n",
        ("tests/test_daemon.py",),
        "the loop waits for a still mouse's report past the time its silence closes the window",
    ),
    Mutant(
        "screen-batch-never-decides",
        "mousedom/fusion/screenbatch.py",
        "            bad = np.flatnonzero(~fast | evidence[i:horizon]) + i\n",
        "            bad = np.flatnonzero(evidence[i:horizon]) + i\n",
        ("tests/test_robust.py",),
        "replay's array screen accepts every window the daemon would have decided",
    ),
    Mutant(
        "gyro-saturation-ignored",
        "mousedom/fusion/tracker_gyro.py",
        "seen = spans if sat is None else np.where(sat, 0.0, spans)",
        "seen = spans",
        ("tests/test_gyro_saturation.py",),
        "the windows take a saturated gyro's clipped rate as the turn",
    ),
    Mutant(
        "gyro-unseen-ignored-array",
        "mousedom/fusion/tracker_gyro.py",
        "        live &= closed[:, 1] > np.diff(edges) - UNSEEN_S\n",
        "",
        ("tests/test_gyro_saturation.py", "tests/test_gyro_silence.py"),
        "replay's windows take a turn the gyro did not see (clipped, or a silence as none)",
    ),
    Mutant(
        "iio-saturation-one-end",
        "mousedom/sources/iio.py",
        "at = (raw <= lo) | (raw >= hi)",
        "at = raw >= hi",
        ("tests/test_gyro_saturation.py",),
        "a gyro clipped at the low end of its raw range is not marked",
    ),
    Mutant(
        "ros2-gyro-invalid-sample",
        "mousedom/service/ros2imu.py",
        "taken += [m for m in got if not isinstance(m, InvalidSample)]",
        "taken += list(got)",
        ("tests/test_gyro_ros2.py",),
        "a ROS 2 IMU driver that quits crashes the gyro's read",
    ),
    Mutant(
        "ros2-gyro-never-silent",
        "mousedom/service/ros2imu.py",
        "if now - self._heard > SILENT_S:",
        "if False:",
        ("tests/test_gyro_ros2.py",),
        "a ROS 2 IMU driver that stopped reads as a gyro that turns nothing",
    ),
    Mutant(
        "gyro-relearn-resets-scale",
        "mousedom/fusion/gyrobias.py",
        "self.p = [[max(self.p[0][0], self._prior[0][0]), 0.0], [0.0, self.p[1][1]]]",
        "self.p = [[max(self.p[0][0], self._prior[0][0]), 0.0],\n"
        "                  [0.0, max(self.p[1][1], self._prior[1][1])]]",
        ("tests/test_gyro_faults.py",),
        "a bias that jumped is learnt again with the scale's variance reset (as before)",
    ),
    Mutant(
        "gyro-relearn-teaches-scale",
        "mousedom/fusion/gyrobias.py",
        "            h = [h[0], 0.0]  # (the scale, independent of it now, learns nothing here)\n",
        "",
        ("tests/test_gyro_faults.py",),
        "a gyro clipped unseen, learnt again from trusted mice, takes the clip as its scale",
    ),
    Mutant(
        "gyro-span-timing-its-mean",
        "mousedom/fusion/gyrobias.py",
        "        edges = (self._sure_first + self._sure_last if sure else\n"
        "                 self._timing_first + self._timing_last) + self._holes  # fmt: skip\n",
        "        edges = 2.0 * (self._sure_first + self._sure_last if sure else\n"
        "                 self._timing_first + self._timing_last) / (self._n + 1) + self._holes\n",
        (
            "tests/test_gyro_sudden_starts.py",
            "tests/test_gyro_late_mean.py",
            "tests/test_gyro_late_stamps.py",
        ),
        "a span's timing taken as its mean, not its edges': a sudden start teaches the scale",
    ),
    Mutant(
        "gyro-jump-blamed-on-still-mice",
        "mousedom/fusion/gyro.py",
        "        jumped = still and not slow and n_used == 2\n",
        "        jumped = False\n",
        ("tests/test_gyro_faults.py",),
        "two still mice blamed for a gyro whose bias jumped: the heading turns for good",
    ),
    Mutant(
        "odom-covariance-collapses-at-reset",
        "mousedom/service/ros2conv.py",
        "        if self.carried is not None:\n",
        "        if False:\n",
        ("tests/test_ros2.py::test_the_odom_covariance_goes_on_through_a_reset",),
        "/odom's covariance falls with the daemon's at a reset: a filter over-trusts it",
    ),
    Mutant(
        "gyro-silence-read-as-no-turn",
        "mousedom/fusion/tracker_gyro.py",
        "        if start < self.first_t or seen <= (end - start) - UNSEEN_S:\n",
        "        if start < self.first_t:\n",
        ("tests/test_gyro_silence.py",),
        "windows a silent gyro missed fused as no turn (a mouse's rule, not a gyro's)",
    ),
    Mutant(
        "gyro-judge-told-late-mice-array",
        "mousedom/fusion/tracker_batch.py",
        "self._with_gyro(setup.gyro, q, sol, d, in_solve, turn,",
        "self._with_gyro(setup.gyro, q, sol, d, mask & (health != robust.EXCLUDED), turn,",
        ("tests/test_gyro_live_is_replay.py",),
        "replay's gyro judge counts a late mouse as in the solve: replay is not the daemon",
    ),
    Mutant(
        "wake-at-first-report",
        "mousedom/service/wake.py",
        "            wake = max(wake, first + min(step, 0.5 * period + latency) - early)",
        "            wake = max(wake, first - early)",
        ("tests/test_daemon.py",),
        "the loop wakes at the first report after a window, which cannot close it yet",
    ),
    Mutant(
        "steady-saturation-reading-only",
        "mousedom/fusion/steady.py",
        "m2 = max(dx * dx + dy * dy, px * px + py * py)",
        "m2 = dx * dx + dy * dy",
        ("tests/test_robust.py",),
        "the common case misses a mouse the solve says moved beyond its speed",
    ),
    Mutant(
        "steady-no-threshold",
        "mousedom/fusion/steady.py",
        "    if dof > 0 and total > threshold:\n        return None\n",
        "",
        ("tests/test_robust.py",),
        "the common case accepts a window whose mice disagree",
    ),
    Mutant(
        "noise-sample-floor-by-prop",
        "mousedom/fusion/noisemodel.py",
        "by_floor = (v - prop) / sig2 if 4.0 * floor >= prop else None",
        "by_floor = (v - floor) / sig2 if 4.0 * floor >= prop else None",
        ("tests/test_noisemodel.py", "tests/test_robust.py"),
        "the floor factor's sample takes the wrong part of the variance out",
    ),
    Mutant(
        "deferred-learning-never-settled-by-the-next-poll",
        "mousedom/fusion/tracker.py",
        "        self.settle()\n        k_old = self._grid.closed",
        "        k_old = self._grid.closed",
        ("tests/test_scalelearn.py",),
        "a block end the daemon deferred is lost when the next window closes unsettled",
    ),
    Mutant(
        "learning-not-deferred",
        "mousedom/fusion/tracker.py",
        "        if not defer_learning:\n            self.settle()\n        return batch",
        "        self.settle()\n        return batch",
        ("tests/test_scalelearn.py",),
        "the block end stays between the window's last report and its POSE",
    ),
    Mutant(
        "heap-frozen-for-good",
        "mousedom/service/daemon.py",
        "    gc.unfreeze()\n    gc.collect()\n    gc.freeze()",
        "    gc.collect()\n    gc.freeze()",
        ("tests/test_daemon.py",),
        "what a reload replaced stays frozen, never collected",
    ),
    Mutant(
        "screen-block-end-not-deferred",
        "mousedom/fusion/robust.py",
        "        if not defer_block_end:\n            self.settle()",
        "        self.settle()",
        ("tests/test_scalelearn.py",),
        "the screen's noise model learns between the window's last report and its POSE",
    ),
    Mutant(
        "screen-block-end-never-settled",
        "mousedom/fusion/tracker.py",
        "        if self.screen is not None:  # (first, as when it learns within the window)\n"
        "            self.screen.settle()\n",
        "",
        ("tests/test_scalelearn.py",),
        "a block end of the screen's noise model the daemon deferred is never learnt",
    ),
    Mutant(
        "loop-learns-before-it-publishes",
        "mousedom/service/daemon.py",
        "        self.publisher.publish(tracker.poll(defer_learning=True, one_by_one=True))\n"
        "        tracker.settle()",
        "        batch = tracker.poll(defer_learning=True, one_by_one=True)\n"
        "        tracker.settle()\n"
        "        self.publisher.publish(batch)",
        ("tests/test_daemon.py",),
        "the loop learns from a block before the POSE of the window that ended it",
    ),
    Mutant(
        "several-windows-all-deferred",
        "mousedom/fusion/tracker.py",
        "for row in self._close_one(False).rows()]",
        "for row in self._close_one(defer_learning).rows()]",
        ("tests/test_scalelearn.py",),
        "a poll of several windows defers every block end in it: the next window's rows"
        " go into a block not yet learnt",
    ),
    Mutant(
        "several-windows-take-the-array-path",
        "mousedom/fusion/tracker.py",
        "    _SMALL = 8\n",
        "    _SMALL = 1\n",
        ("tests/test_scalelearn.py",),
        "a daemon's poll of two windows pays the array path's fixed cost (0.5 ms)",
    ),
    Mutant(
        "loop-never-settles",
        "mousedom/service/daemon.py",
        "        tracker.settle()  # a learners' block end: after the POSE is out"
        " (Tracker.settle)\n",
        "",
        ("tests/test_daemon.py",),
        "the loop leaves a block's learning to its next poll: a fix in between misses it",
    ),
    Mutant(
        "fix-does-not-settle",
        "mousedom/fusion/tracker.py",
        "        others, and their correlations with each other, are kept.\n"
        '        """\n        self.settle()\n',
        '        others, and their correlations with each other, are kept.\n        """\n',
        ("tests/test_scalelearn.py",),
        "a fix after a deferred block end sets the pose, then the learning gives back into it",
    ),
    Mutant(
        "short-mouse-accepted-by-the-common-case",
        "mousedom/fusion/steady.py",
        "        return None  # short of its motion: decide (the screen's shortfall)\n",
        "        pass\n",
        (
            "tests/test_robust.py::"
            "test_the_common_case_leaves_a_mouse_short_of_its_motion_to_the_decision",
        ),
        "the daemon's path leaves a mouse short of its motion to the common case: replay and "
        "the daemon decide apart",
    ),
    Mutant(
        "short-mouse-never-held",
        "mousedom/fusion/robust.py",
        "            if used[i] and in_use and beyond > worst and self._solve(d, _but(used, i)) "
        "is not None:\n",
        "            if False:\n",
        ("tests/test_robust.py::test_a_lift_is_found_where_late_stamps_widened_every_tolerance",),
        "a lift passes where late stamps widened every tolerance",
    ),
    Mutant(
        "late-mouse-back-while-short",
        "mousedom/fusion/robust.py",
        "        if self.ledger.paid(i) and not self._short_now[i]:\n",
        "        if self.ledger.paid(i):\n",
        ("tests/test_robust.py::test_a_lift_is_found_where_late_stamps_widened_every_tolerance",),
        "a lifted mouse reading noise owes little for a window, is taken back as paid and "
        "given its debt, again and again",
    ),
    Mutant(
        "readmission-without-the-run-fit",
        "mousedom/fusion/readmission.py",
        "        return h.fit_r * h.fit_r <= thr1 * h.fit_info\n",
        "        return True\n",
        ("tests/test_robust.py", "tests/test_reconcile.py"),
        "an under-read at low speed agrees window by window and is re-admitted, its run given back",
    ),
    Mutant(
        "readmission-held-to-its-own-error",
        "mousedom/fusion/readmission.py",
        "        cov = s2 * np.eye(2) + pred_cov\n",
        "        cov = s2 * np.eye(2)\n",
        (
            "tests/test_timing_not_fault.py::test_a_mouse_the_others_predict_poorly_is_not_left_out",
            "tests/test_readmission_evidence.py::"
            "test_a_far_mouse_lifted_behind_a_close_pair_is_back_within_a_second",
        ),
        "a far mouse the others predict poorly never agrees again",
    ),
    Mutant(
        "short-rows-accepted-by-replay",
        "mousedom/fusion/screenbatch.py",
        "        ok &= ~quiet[:, i]\n",
        "        pass\n",
        ("tests/test_robust.py::test_replay_leaves_a_mouse_short_of_its_motion_to_the_decision",),
        "replay's array path accepts windows with a mouse short of its motion: lifts pass",
    ),
    Mutant(
        "scale-bound-on-the-scale",
        "mousedom/fusion/scalelearn.py",
        "        return 1.0 / (1.0 + self.limit), 1.0 / (1.0 - self.limit)\n",
        "        return 1.0 - self.limit, 1.0 + self.limit\n",
        (
            "tests/test_scale_give_back.py::test_a_cpi_ten_per_cent_off_either_way_is_corrected_in_full",
        ),
        "a mouse reading 10 % less is corrected to 1.1 of its needed 1.111: the heading drifts",
    ),
    Mutant(
        "give-back-of-consistent-windows-only",
        "mousedom/fusion/tracker_learn.py",
        "        in_solve = batch.used == self._n\n",
        "        in_solve = usable.all(axis=1)\n",
        ("tests/test_scale_give_back.py::test_the_turn_of_inconsistent_windows_is_given_back",),
        "the turn inconsistent windows made at the old scales is kept for good",
    ),
    Mutant(
        "give-back-without-the-direct-walk",
        "mousedom/fusion/scalelearn.py",
        "        straight = straight_each.sum(axis=0)\n",
        "        straight = straight_each.sum(axis=0) * 0.0\n",
        ("tests/test_scale_give_back.py::test_the_position_a_wrong_cpi_moved_is_given_back",),
        "the position a wrong CPI moved directly (mice off the rig's centre) is kept for good",
    ),
    Mutant(
        "shortfall-held-to-the-floor-alone",
        "mousedom/fusion/robust.py",
        "                self._thresholds[2] * (2.0 * floor[i] + self._quiet_var[i] + sys2)\n",
        "                self._thresholds[2] * (2.0 * floor[i])\n",
        ("tests/test_shortfall_pivot.py",),
        "a healthy mouse at a spin's pivot is held out for the others' errors",
    ),
    Mutant(
        "motion-before-drops-every-nothing",
        "mousedom/fusion/robust.py",
        "                out = _but(out, i)\n",
        "                pass\n        out = kept & (np.abs(then).sum(axis=1) > 0)\n",
        ("tests/test_shortfall_pivot.py",),
        "the pivot mouse's zero left out of the motion before: a lift blames it",
    ),
    Mutant(
        "silence-shows-a-far-mouse-sound",
        "mousedom/fusion/readmission.py",
        "            float(di @ pi) >= SHORT * p2\n            or float(",
        "            read2 > 0.0\n            or float(",
        ("tests/test_reconcile.py",),
        "a landing (part-read) window starts a far mouse's run: its shortfall given back",
    ),
    Mutant(
        "scale-fault-never-seen",
        "mousedom/fusion/scalelearn.py",
        "        flagged = np.flatnonzero((beyond > 0) & (beyond > FAULT_SIGMAS * spread))"
        ".tolist()\n",
        "        flagged = []\n",
        ("tests/test_scale_faults.py",),
        "a mouse reading half its motion passes as noise",
    ),
    Mutant(
        "scale-fault-not-given-back",
        "mousedom/fusion/scalelearn.py",
        "        self._give_back_faults(block_scale)\n",
        "        pass\n",
        ("tests/test_scale_faults.py",),
        "the block a fault was found in keeps the turn its readings gave the heading",
    ),
    Mutant(
        "scale-fault-block-before-kept",
        "mousedom/fusion/scalelearn.py",
        "                self._give_back_block(i, g, prev, parts[-2], 2, block.steps)\n",
        "                pass\n",
        ("tests/test_scale_faults.py",),
        "the block a fault began in, learnt as a CPI, keeps the turn its readings gave",
    ),
    Mutant(
        "readmit-judged-per-short-window",
        "mousedom/fusion/readmission.py",
        "        self._group = max(1, math.ceil(EVIDENCE_S / window - 1e-9))",
        "        self._group = 1 or max(1, math.ceil(EVIDENCE_S / window - 1e-9))",
        ("tests/test_robust_short_windows.py",),
        "a healthy mouse excluded at 2.5-5 ms windows is never let back",
    ),
    Mutant(
        "scale-fault-take-back-given-again",
        "mousedom/fusion/scalelearn.py",
        "        if keep.all():\n            return unit, local\n",
        "        if True:\n            return unit, local\n",
        ("tests/test_scale_faults.py",),
        "the windows the screen took back from a faulty mouse are given back a second time",
    ),
    Mutant(
        "scale-fault-learnt-as-a-cpi",
        "mousedom/fusion/scalelearn.py",
        "        learnt = not found.beyond and len(c) > 0\n",
        "        learnt = len(c) > 0\n",
        ("tests/test_scale_faults.py",),
        "an under-read's block is learnt as the mouse's CPI",
    ),
    Mutant(
        "scale-judged-by-its-residual-alone",
        "mousedom/fusion/scalelearn.py",
        "        spread = widened(spread, self.gram, self._segments)\n",
        "        pass\n",
        ("tests/test_scalelearn.py",),
        "a scale from a few blocks of hard driving is applied on the residual's white spread",
    ),
    Mutant(
        "scale-change-not-followed",
        "mousedom/fusion/scalelearn.py",
        "        keep = self._changed()\n",
        "        keep = 0\n",
        ("tests/test_scale_change.py",),
        "a mouse whose scale steps keeps a mean of its two scales, given back over the whole drive",
    ),
    Mutant(
        "scale-beyond-kept-in-use",
        "mousedom/fusion/tracker.py",
        "            self.screen.hold_beyond(renewal.beyond)\n",
        "            pass\n",
        ("tests/test_scale_beyond.py",),
        "a mouse stepping beyond the bounds is kept in use at the bound: 5-15 % off",
    ),
    Mutant(
        "scale-beyond-readmitted",
        "mousedom/fusion/readmission.py",
        "            if h.good >= self.readmit and not beyond:\n",
        "            if h.good >= self.readmit:\n",
        ("tests/test_scale_beyond.py",),
        "a mouse held out beyond the bounds passes its run's test and comes back",
    ),
    Mutant(
        "scale-beyond-given-back-clipped",
        "mousedom/fusion/scalelearn.py",
        "        lo[self.beyond], hi[self.beyond] = -np.inf, np.inf\n",
        "        pass\n",
        ("tests/test_scale_beyond.py",),
        "the windows a mouse beyond the bounds was used in are given back at the bound",
    ),
    Mutant(
        "scale-change-at-a-fixed-split",
        "mousedom/fusion/scalelearn.py",
        "        best = change_point(segments)\n",
        "        best = CHANGE_SEGMENTS\n",
        ("tests/test_scale_beyond.py",),
        "a change a few segments back is mixed into the last ten: found late, its mean given back",
    ),
    Mutant(
        "scale-change-of-one-scale-alone",
        "mousedom/fusion/scalelearn.py",
        "        m = g[:, None] * np.repeat(np.eye(self.n), 2, axis=0)\n",
        "        m = np.repeat(np.eye(self.n), 2, axis=0)\n",
        ("tests/test_scale_axis_change.py",),
        "a mouse off on one axis 'changes' scale with the mix of directions: evidence dropped",
    ),
    Mutant(
        "scale-change-axes-of-the-older-alone",
        "mousedom/fusion/scalelearn.py",
        "        g = axis_scales(older, groups, n, cols, prior=whole)\n",
        "        g = axis_scales(older, groups, n, cols)\n",
        ("tests/test_scale_axis_change.py",),
        "older evidence that never read an axis: the axis off taken for a change",
    ),
    Mutant(
        "scale-fault-not-excluded",
        "mousedom/fusion/tracker.py",
        "            self.screen.exclude_faulty(renewal.faults)\n",
        "            pass\n",
        ("tests/test_scale_faults.py",),
        "the fault found, the mouse kept",
    ),
    Mutant(
        "tie-fit-one-window-only",
        "mousedom/fusion/robust.py",
        "        if last >= self._windows - self.history_len and sums.keys() == fits.keys():\n",
        "        if False:\n",
        ("tests/test_tie_sums.py",),
        "an ambiguous fault's evidence judged window by window, never summed",
    ),
    Mutant(
        "short-of-the-solve-with-it",
        "mousedom/fusion/shortfall.py",
        "        alone[odd] = True\n",
        "        pass\n",
        ("tests/test_under_read_onset.py",),
        "a mouse reading half bends the solve until it reads three quarters: never short",
    ),
    Mutant(
        "short-of-the-others-not-the-odd-one",
        "mousedom/fusion/shortfall.py",
        "        if by > odd_by:\n",
        "        if by > 0.0:\n",
        ("tests/test_scale_beyond.py", "tests/test_under_read_onset.py"),
        "beside a mouse reading 44 % more, a healthy one short of the others' bent word",
    ),
    Mutant(
        "short-of-the-others-alone",
        "mousedom/fusion/shortfall.py",
        "            odd_short = ratio < SHORT and along < SHORT_OF_ALL * p2\n",
        "            odd_short = ratio < SHORT\n",
        ("tests/test_under_read_onset.py", "tests/test_scale_beyond.py"),
        "a mouse short of the others' word though it reads the solve with it in full",
    ),
    Mutant(
        "replay-short-of-the-solve-with-it",
        "mousedom/fusion/screenbatch.py",
        "    quiet = moved & ((along < SHORT_ALONE * p2) | of_others)\n",
        "    quiet = moved & (along < SHORT_ALONE * p2)\n",
        ("tests/test_under_read_onset.py",),
        "replay lets an under-read's windows by on the common case: never found",
    ),
    Mutant(
        "tie-run-ends-at-a-passing-window",
        "mousedom/fusion/robust.py",
        "        if last >= self._windows - self.history_len and sums.keys() == fits.keys():\n",
        "        if last == self._windows - 1 and sums.keys() == fits.keys():\n",
        ("tests/test_tie_sums.py",),
        "a window in four passing whole ends the fit's run short of its margin",
    ),
    Mutant(
        "tie-sums-only-what-passed",
        "mousedom/fusion/robust.py",
        "                fits[tuple(combo)] = stat.t\n                if self._passes(stat):\n",
        "                if self._passes(stat):\n                    fits[tuple(combo)] = stat.t\n",
        ("tests/test_tie_sums.py",),
        "a third explanation passing now and then ends the fit's run short of its margin",
    ),
    Mutant(
        "quiet-hold-not-in-a-tie",
        "mousedom/fusion/robust.py",
        "            elif quiet is not None and used[quiet] and self._passes_without("
        "d, used, quiet, s2):\n",
        "            elif False:\n",
        ("tests/test_tie_shortfall.py",),
        "a mouse short of its motion for 38 windows left in while the tie stays unbroken",
    ),
    Mutant(
        "continuity-against-the-fit",
        "mousedom/fusion/robust.py",
        "                and (smooth == ranked[0].excluded\n",
        "                and (True\n",
        ("tests/test_tie_shortfall.py",),
        "the motion takes a healthy mouse out where the tie's fit speaks against it",
    ),
    Mutant(
        "continuity-vetoed-by-noise",
        "mousedom/fusion/robust.py",
        "FIT_VETO = 0.95\n",
        "FIT_VETO = 0.5\n",
        ("tests/test_tie_shortfall.py",),
        "sums of noise veto the motion's word on a jump, which goes into the pose",
    ),
    Mutant(
        "scale-fault-from-bent-scales",
        "mousedom/fusion/scalelearn.py",
        "            if carriers:\n",
        "            if False:\n",
        (
            "tests/test_scale_faults.py::test_jumps_of_a_close_pair_mouse_in_a_spin_never_blame_a_healthy_mouse",
            "tests/test_scale_faults.py::test_a_stall_across_a_block_end_blames_the_stalled_mouse_alone",
        ),
        "a block bent by jumps its scales cannot explain blames a healthy mouse for 9 s",
    ),
    Mutant(
        "scale-fault-from-an-ambiguous-block",
        "mousedom/fusion/scalelearn.py",
        "                flagged = [i for i in flagged if carriers == [i]]\n",
        "                flagged = [i for i in flagged if i in carriers]\n",
        (
            "tests/test_scale_faults.py::test_jumps_of_a_close_pair_mouse_in_a_spin_never_blame_a_healthy_mouse",
        ),
        "a jump across a close pair, which the pair reads as a turn, blames the far mouse",
    ),
    Mutant(
        "scale-given-back-for-one-group",
        "mousedom/fusion/scalelearn.py",
        "        scaled = explained and not self._one_group(block, groups, pj) & set(flagged)\n",
        "        scaled = explained\n",
        ("tests/test_scale_faults.py::test_a_far_mouse_jumping_in_a_spin_is_given_back_no_turn",),
        "a far mouse's one jump in a spin is given back as a scale: 15 degrees in one window",
    ),
    Mutant(
        "one-axis-left-to-one-scale",
        "mousedom/fusion/scalelearn.py",
        "            split = self._one_split(evidence, before)\n",
        "            pass\n",
        ("tests/test_scale_one_split.py",),
        "a mouse off on one axis is given one scale that bends the healthy mice",
    ),
    Mutant(
        "one-split-without-a-margin",
        "mousedom/fusion/scalelearn.py",
        "_ONE_SPLIT_MARGIN = 1.5\n",
        "_ONE_SPLIT_MARGIN = 1.0\n",
        ("tests/test_scale_one_split.py",),
        "the split that explains a little more, of two alike, may be a healthy mouse",
    ),
    Mutant(
        "gyro-span-clipped-at-its-period",
        "mousedom/fusion/gyro.py",
        "    spans = np.where(gaps <= bridge, np.maximum(gaps, 0.0), period)\n",
        "    spans = np.where(gaps <= bridge, np.clip(gaps, 0.0, period), period)\n",
        ("tests/test_gyro_tracker.py",),
        "a jittering gyro, or one faster than its config says, loses a part of every turn",
    ),
    Mutant(
        "gyro-samples-join-as-reports",
        "mousedom/fusion/tracker_gyro.py",
        "        self.join = 0.0\n",
        "        pass\n",
        ("tests/test_gyro_tracker.py",),
        "without sample_hz, a 200 Hz gyro's turn moves to the sample before",
    ),
    Mutant(
        "replay-windows-from-the-first-report",
        "mousedom/capture/timebase.py",
        "        if (t := c.grid_start()) is not None or (t := c.first_time()) is not None\n",
        "        if (t := c.first_time()) is not None\n",
        ("tests/test_capture_native.py",),
        "the replay of a daemon's recording has other windows than the daemon's",
    ),
    Mutant(
        "source-rate-kept-after-it-stopped",
        "mousedom/sources/base.py",
        "        self._drop_reads(now)\n"
        "        if self._first_read is None:\n            return 0.0\n",
        "        if self._first_read is None:\n            return 0.0\n",
        ("tests/test_source_rate.py",),
        "a mouse that stopped keeps its last report rate",
    ),
    Mutant(
        "paid-back-within-its-own-error",
        "mousedom/fusion/ledger.py",
        "        cov = 2.0 * (s2 * np.eye(2) + (v * np.maximum(w - s2, 0.0)) @ v.T)\n",
        "        cov = 2.0 * s2 * np.eye(2)\n",
        (
            "tests/test_lateness.py::test_a_late_mouse_far_behind_a_close_pair_pays_back_within_their_error",
        ),
        "a far mouse late once is excluded for the close pair's prediction error",
    ),
    Mutant(
        "reload-finishes-every-window",
        "mousedom/service/reload.py",
        "        self.publisher.publish(old.poll())\n",
        "        self.publisher.publish(old.finish())\n",
        ("tests/test_reload_keeps_counts.py",),
        "a reload closes windows before the slower mice's reports for them came",
    ),
    Mutant(
        "warm-up-never-restated",
        "mousedom/fusion/tracker_learn.py",
        "                cov_add = warm.restatement(self.noise)\n",
        "                cov_add = 0.0 * warm.restatement(self.noise)\n",
        ("tests/test_nees_drives.py::test_nees_of_a_mouse_noisier_than_configured_is_three",),
        "the covariance of the seconds before the noise is learnt stays at the config's sigma",
    ),
    Mutant(
        "noise-two-mice-never-learnt",
        "mousedom/fusion/tracker.py",
        '            self.n_mice >= 3 or (self.n_mice == 2 and self.model != "bonarini")\n',
        "            self.n_mice >= 3\n",
        ("tests/test_nees_drives.py::test_two_mouse_drives_are_not_overconfident",),
        "two mice keep the config's guessed sigma: the covariance is overconfident",
    ),
    Mutant(
        "noise-two-mice-may-lower-sigma",
        "mousedom/fusion/noiserate.py",
        "        self._floor = (1.0 if self.redundant < FEW_READINGS else FLOOR) * sig2\n",
        "        self._floor = FLOOR * sig2\n",
        (
            "tests/test_covariance_truth.py::test_a_mouse_with_unequal_axis_cpis_is_not_overconfident",
        ),
        "one redundant reading's noisy estimate lowers a right sigma: overconfident by chance",
    ),
    Mutant(
        "noise-two-mice-blocks-misaligned",
        "mousedom/fusion/tracker_learn.py",
        "        if self.scales.active or self.noise_rate is None:\n",
        "        if True:\n",
        ("tests/test_noiserate.py",),
        "two mice: replay learns the noise at other windows than the daemon",
    ),
    Mutant(
        "readmission-fit-keeps-noise-bias",
        "mousedom/fusion/readmission.py",
        "h.fit_r += (float(r @ di) - 2.0 * s2) / var",
        "h.fit_r += float(r @ di) / var",
        ("tests/test_readmission_evidence.py::test_the_run_fit_of_a_healthy_mouse_is_unbiased",),
        "a healthy excluded mouse's own noise reads as an over-read in its run's fit",
    ),
    Mutant(
        "readmission-fit-chosen-by-reading",
        "mousedom/fusion/readmission.py",
        "        if moved and read2 > 0.0 and not caught_up:",
        "        if read2 > _SHOWS * thr2 * not_proportional and not caught_up:",
        ("tests/test_readmission_evidence.py::test_the_run_fit_of_a_healthy_mouse_is_unbiased",),
        "the run's fit takes the windows whose reading is long: a healthy mouse reads over",
    ),
    Mutant(
        "readmission-groups-never-grow",
        "mousedom/fusion/readmission.py",
        "EVIDENCE_MAX_S = 0.25\n",
        "EVIDENCE_MAX_S = 0.01\n",
        ("tests/test_readmission_evidence.py",),
        "under late stamps an excluded mouse's windows seldom show it sound: never let back",
    ),
    Mutant(
        "readmission-grown-group-given-back",
        "mousedom/fusion/readmission.py",
        "or (shows and k <= self._group):",
        "or shows:",
        (
            "tests/test_robust.py::test_a_lift_is_found_where_late_stamps_widened_every_tolerance",
            "tests/test_readmission_evidence.py",
        ),
        "a group grown to show gives back the silence a lifted mouse landed in",
    ),
    Mutant(
        "ledger-paid-by-the-summed-prediction",
        "mousedom/fusion/ledger.py",
        "        w, v = np.linalg.eigh(self.sum_pc[i] / max(1, self.windows_pc[i]))\n",
        "        w, v = np.linalg.eigh(self.sum_pc[i])\n",
        (
            "tests/test_readmission_evidence.py::test_a_lifts_shortfall_is_not_taken_for_a_paid_back_debt",
        ),
        "a lift's shortfall passes as paid back on the prediction's error of every window summed",
    ),
    Mutant(
        "ledger-paid-by-the-largest-window",
        "mousedom/fusion/ledger.py",
        "        s2 = self.sum_s2[i] / self.windows[i]\n",
        "        s2 = self.owed_s2[i]\n",
        (
            "tests/test_readmission_evidence.py::test_a_noisy_lifts_shortfall_is_not_paid_back_whole",
        ),
        "a lift's shortfall passes as paid back on the largest error of any window held out",
    ),
    Mutant(
        "continuity-blind-to-ramps",
        "mousedom/fusion/robust.py",
        "                and ramp_agrees\n",
        "                and True\n",
        (
            "tests/test_tie_sums.py::test_continuity_does_not_take_a_ramp_for_a_fault",
            "tests/test_tie_sums.py::test_continuity_does_not_blame_a_healthy_mouse_as_the_robot_speeds_up",
        ),
        "as the robot speeds up or a turn eases off, an under-reading mouse changes least",
    ),
    Mutant(
        "lifted-by-exact-silence",
        "mousedom/fusion/robust.py",
        "            d[j] @ d[j] <= floor2",
        "            self._silent(d, j)",
        ("tests/test_lifted_tie.py::test_the_lifted_mouse_is_the_one_blamed[noisy-lift]",),
        "a noisy lift is never silent: a triangle suspect for the whole lift, 0.45 m off",
    ),
    Mutant(
        "lifted-in-a-first-window",
        "mousedom/fusion/robust.py",
        "            and prev[0] * prev[0] + prev[1] * prev[1] > floor2",
        "            and True",
        ("tests/test_lifted_tie.py::test_the_lifted_mouse_is_the_one_blamed[first-window]",),
        "a 125 Hz mouse's first window of a motion holds no report: the healthy one blamed",
    ),
    Mutant(
        "lifted-short-of-its-prediction",
        "mousedom/fusion/robust.py",
        "            d[j] @ d[j] <= floor2",
        "            d[j] @ d[j] <= 0.25 * 0.25 * (p[j] @ p[j])",
        ("tests/test_lifted_tie.py::test_the_lifted_mouse_is_the_one_blamed[short-of-a-spin]",),
        "a far mouse reads little of the spin a faulty pair implies: the far mouse blamed",
    ),
    Mutant(
        "a-fit-better-than-expected-wins",
        "mousedom/fusion/robust.py",
        "    return total > chi2.median(dof)",
        "    return True",
        (
            "tests/test_tie_sums.py::test_a_fit_better_than_its_own_expectation_is_no_evidence_against_another",
            "tests/test_tie_sums.py::test_a_pair_that_cannot_fail_does_not_win_the_fit",
        ),
        "a pair across the motion cannot fail, wins the fit, and the far mouse is blamed",
    ),
]


def _copy_checkout(dest: Path) -> None:
    files = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    for f in files:
        if not f:
            continue
        src = REPO / f.decode()
        if src.is_file():
            (dest / f.decode()).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / f.decode())


TIMEOUT_S = 180  # a mutant that makes its tests hang (a gap windowed through) is caught


def _pytest(copy: Path, tests: tuple[str, ...]) -> int:
    """pytest's exit status, or -1 if the tests did not finish within TIMEOUT_S."""
    try:
        return subprocess.run(
            [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests],
            cwd=copy,
            # The Python is what the mutants change (the compiled core is held equal to it
            # by tests/test_core.py): the tests run on it, and the copy builds no core.
            env={
                "PYTHONPATH": str(copy),
                "PATH": "/usr/bin:/bin",
                "HOME": str(copy),
                "MOUSEDOM_CORE": "python",
                "MOUSEDOM_BUILD_CORE": "0",
            },  # fmt: skip
            capture_output=True,
            timeout=TIMEOUT_S,
        ).returncode
    except subprocess.TimeoutExpired:
        return -1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", action="append", help="run this mutant only (repeatable)")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    args = ap.parse_args(argv)
    chosen = [m for m in MUTANTS if not args.only or m.name in args.only]
    if args.list:
        for m in chosen:
            print(f"{m.name:32s} {m.path}: {m.why}")
        return 0
    missed = 0
    with tempfile.TemporaryDirectory(prefix="mousedom-mutants-") as tmp:
        copy = Path(tmp)
        _copy_checkout(copy)
        for tests in sorted({m.tests for m in chosen}):
            if _pytest(copy, tests) != 0:
                print(f"the unmutated copy fails {' '.join(tests)}: fix that first")
                return 2
        print(f"{'mutant':32s} {'result':7s} {'seconds':>7s}  tests")
        for m in chosen:
            target = copy / m.path
            original = target.read_text()
            if original.count(m.old) != 1:
                print(f"{m.name:32s} {'STALE':7s} {'':>7s}  the text to mutate is not there once")
                missed += 1
                continue
            target.write_text(original.replace(m.old, m.new))
            start = time.monotonic()
            rc = _pytest(copy, m.tests)
            target.write_text(original)
            caught = rc in (1, -1)  # failed, or hung; 2-5 would be a broken run, not a catch
            missed += not caught
            result = {1: "caught", -1: "hung", 0: "MISSED"}.get(rc, f"rc={rc}")
            print(f"{m.name:32s} {result:7s} {time.monotonic() - start:7.1f}  {' '.join(m.tests)}")
    print(f"mutants: {len(chosen)}, caught {len(chosen) - missed}, missed {missed}")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
