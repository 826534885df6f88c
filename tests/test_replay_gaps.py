"""A gap in time costs nothing (issue 11, item 5): skipped with a warning, never windowed.

One corrupted stamp (a relative file whose second event is 1.3e9 s later) once made
replay window through 1.3e11 empty windows.  The reference each test holds the result
against is the same reports with the gap closed up: empty windows move no pose, so the
end pose must be the same, and every count must land."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from conftest import run_mousedom

from mousedom.capture import assign
from mousedom.capture.evemu import format_evemu
from mousedom.capture.replay import MAX_GAP_S, Replay
from mousedom.config import parse_config
from mousedom.fusion.tracker import Tracker

RIG = (
    "rate_hz: {rate}\nmodel: lsq\nmice:\n  a: {{cpi: 400, mount: {{x: 0.05, y: 0.1}}}}\n"
    "  b: {{cpi: 400, mount: {{x: -0.05, y: -0.1}}}}\n"
)


def _files(tmp_path, gap: float, seed: int = 2, n: int = 300):
    rng = np.random.default_rng(seed)
    specs = []
    for k, name in enumerate("ab"):
        t = 0.001 * k + np.cumsum(rng.uniform(0.004, 0.012, n))
        t[n // 2 :] += gap
        p = tmp_path / f"{name}-{gap:g}.evemu"
        p.write_text(format_evemu(np.round(t, 6), rng.integers(-5, 6, n), rng.integers(-9, 3, n)))
        specs.append((name, str(p)))
    return specs


def _replay(tmp_path, specs, rate=100.0):
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(RIG.format(rate=rate))
    config = parse_config(cfg.read_text(), str(cfg), need_sources=False)
    rp = Replay(config, assign(config, specs))
    rows = []
    summary = rp.run(lambda b: rows.append(len(b)))
    return summary, sum(rows)


@pytest.mark.parametrize("gap", [1.3e9, 86400.0, 2 * MAX_GAP_S])
def test_a_long_gap_is_skipped_and_the_pose_is_the_same(tmp_path, gap):
    closed, closed_rows = _replay(tmp_path, _files(tmp_path, 1.0))
    skipped, rows = _replay(tmp_path, _files(tmp_path, gap))
    # Windows of the reports (and at most one MAX_GAP_S of empty ones), not of the span.
    assert rows < closed_rows + MAX_GAP_S * 100 + 200
    for key in ("x", "y", "theta"):
        # Equal but for where float64 rounds the window edges at t = t0 + gap.
        assert skipped.final[key] == pytest.approx(closed.final[key], abs=1e-7)
    for m in skipped.mice:
        assert m.counts_out == pytest.approx(m.counts_in) and any(m.counts_in)
    gaps = [w for w in skipped.warnings if "gap was skipped" in w]
    assert len(gaps) == 1 and "that gap was skipped" in gaps[0]
    # It names the gap from the last report before it (the first half's reports end
    # within 2 s) to the first after it, not from where the skip began (60 s on).
    m = re.match(r"no mouse reported from t=(\S+) to t=(\S+) ", gaps[0])
    assert m, gaps[0]
    last, first = float(m[1]), float(m[2])
    assert 0.5 < last < 2.0 and gap < first < gap + 2.0, gaps[0]


def test_a_gap_shorter_than_the_limit_is_windowed_as_before(tmp_path):
    summary, rows = _replay(tmp_path, _files(tmp_path, MAX_GAP_S / 2))
    assert not [w for w in summary.warnings if "gap" in w]
    assert rows > MAX_GAP_S / 2 * 100


def test_the_cli_says_the_gap_and_finishes(tmp_path):
    specs = _files(tmp_path, 1.3e9)
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(RIG.format(rate=1000.0))
    proc = run_mousedom(
        "replay", "--config", str(cfg), *(f"--capture={n}={p}" for n, p in specs), timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert "gap was skipped" in proc.stderr and "Traceback" not in proc.stderr


def test_a_time_no_window_grid_can_resolve_is_refused_not_looped():
    cfg = parse_config(RIG.format(rate=100.0), need_sources=False)
    tr = Tracker(cfg, t0=0.0)
    tr.push(0, np.array([0.01]), np.array([1.0]), np.array([0.0]))
    tr.push(0, np.array([1e300]), np.array([1.0]), np.array([0.0]))
    tr.complete_until(1e300)
    with pytest.raises(ValueError, match="beyond what a window grid"):
        tr.poll()
    assert math.isfinite(tr.frontier_time)
