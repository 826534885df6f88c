"""scripts/fault_sweep.py: the long run that finds far-off drives (generated faults under
conditions) rebuilds a drive from its number, and says what is wrong with its arguments."""

from __future__ import annotations

import re
import subprocess
import sys
from itertools import pairwise

from conftest import REPO

SCRIPT = REPO / "scripts" / "fault_sweep.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True,
                          timeout=300, cwd=REPO)  # fmt: skip


def test_a_drive_is_rebuilt_from_its_number():
    """Drive 5 (a square, an under-read under late stamps) alone and among others gives the
    same row: what the summary prints for a far-off drive rebuilds it."""
    alone = _run("--only", "5", "--jobs", "1")
    assert alone.returncode == 0, alone.stderr
    row = alone.stdout.splitlines()[0]
    assert row.startswith("k=5 ") and "under-read" in row and "late-stamps" in row, row
    among = _run("--only", "4,5", "--jobs", "2")
    assert among.returncode == 0, among.stderr
    assert row in among.stdout.splitlines()
    assert "far off (default > 3 x informed + 30 mm):" in among.stdout


def test_an_unknown_kind_is_named():
    out = _run("--kinds", "lift,glossy", "--drives", "1")
    assert out.returncode == 2
    assert "unknown kind 'glossy'" in out.stderr
    assert "Traceback" not in out.stderr


def test_a_timeline_shows_the_drive_and_each_change_of_health():
    """``--timeline`` under a drive's row: its held stretches, then one line per window in
    which some mouse's health changed, the first with every mouse tracking and the times
    increasing.  Drive 5's under-read of mouse fr (7.26-9.43 s) is seen: fr leaves
    tracking within the fault, not before, and is back after it."""
    out = _run("--only", "5", "--jobs", "1", "--timeline")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    row = re.match(r"k=5 +\S+ +(\S+) +under-read +([\d.]+)- *([\d.]+) s ", lines[0])
    assert row, lines[0]
    mouse, start, end = row[1], float(row[2]), float(row[3])
    assert lines[1].startswith("  drive: ") and "straight" in lines[1], lines[1]
    changes = []
    for ln in lines[2:]:
        if not re.match(r" +\d+\.\d{3} s  ", ln):
            break
        t, health = ln.split(" s  ")
        changes.append((float(t), dict(m.split(" ")[:2] for m in health.split("  "))))
    times = [t for t, _ in changes]
    assert times == sorted(times) and len(set(times)) == len(times)
    assert all(a != b for (_, a), (_, b) in pairwise(changes)), "a line per change"
    assert set(changes[0][1].values()) == {"tracking"} and mouse in changes[0][1]
    out_of_use = [t for t, h in changes if h[mouse] != "tracking"]
    assert out_of_use and start <= out_of_use[0] <= end, (start, end, out_of_use)
    assert changes[-1][0] > end and changes[-1][1][mouse] == "tracking", changes[-1]


def test_a_timeline_needs_the_drives_named():
    out = _run("--timeline", "--drives", "2")
    assert out.returncode == 2
    assert "--timeline needs --only K" in out.stderr
    assert "Traceback" not in out.stderr
