"""scripts/fault_sweep.py: the long run that finds far-off drives (generated faults under
conditions) rebuilds a drive from its number, and says what is wrong with its arguments."""

from __future__ import annotations

import subprocess
import sys

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
