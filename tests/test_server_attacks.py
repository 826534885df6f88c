"""Fairness under attack (issue 26): a running daemon (the demo rig at 50 Hz, looping)
is attacked through its socket by separate processes while a healthy client, in a process
of its own, measures the gaps between the POSE lines it receives (scripts/attack.py).

Before the budgets, a connect/close flood gave the healthy client gaps of 0.7-0.9 s and
four clients sending bare newlines gaps over 100 ms; 32 idle connections held every
client slot for ever.  Each attack runs for a bounded time here; longer runs:
``python scripts/attack.py --seconds 30``."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import REPO, mousedom_env


@pytest.mark.parametrize("attack", ["connect", "newlines", "status", "badlines", "idle"])
def test_a_healthy_client_keeps_its_poses_under_attack(attack):
    proc = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "attack.py"), "--seconds", "2",
         "--attack", attack, "--idle-timeout", "2", "--max-gap", "300", "--json"],
        capture_output=True, text=True, timeout=120, env=mousedom_env(),
    )  # fmt: skip
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert len(rows) == 1, proc.stdout + proc.stderr
    row = rows[0]
    assert not row["dropped"], row
    assert row["poses"] >= 80, row  # 2 s at 50 Hz, and more
    # The 99th percentile of the gaps holds the window steady (a flood that delays every
    # POSE moves it); the worst gap, one stall of the shared machine (two test workers on
    # two cores gave one of 104 ms with p99 23), is held under the 0.7 s the connect
    # flood gave before the budgets.
    assert row["p99_gap_ms"] < 50.0, row
    assert row["worst_gap_ms"] < 300.0, row
    if attack == "idle":
        assert row["new_client_after_idle"] is True, row
    # (the script's own verdict, at the worst gap held above.  Its default of 50 ms once
    # failed on a gap of 149 ms, and a CI run failed p99 at 149 ms: both were the demo rig
    # stopping, which holds a POSE back by late_report_s; the script now sets it to 0.)
    assert proc.returncode == 0, proc.stdout + proc.stderr
