"""``mousedom replay`` / ``convert`` on outputs that fail and inputs that are wrong: one
clear line and a non-zero exit, never a traceback (real processes)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from capture_helpers import external_dir, one_mouse_config
from conftest import mousedom_env, run_mousedom

PS2 = "evemu-devices__PS2_Generic_Mouse.events"

needs_dev_full = pytest.mark.skipif(
    not os.path.exists("/dev/full") and not os.environ.get("CI"), reason="no /dev/full"
)


def _one_error_line(stderr: str, *needles: str) -> str:
    assert "Traceback" not in stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mousedom: error:"), stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@needs_dev_full
def test_replay_csv_to_a_full_disk_is_one_line(tmp_path):
    cfg = one_mouse_config(tmp_path, rate=1000)
    proc = run_mousedom(
        "replay", "--config", str(cfg), "--capture", f"m={external_dir() / PS2}", "-o", "/dev/full"
    )
    assert proc.returncode != 0
    _one_error_line(proc.stderr, "/dev/full", "cannot write")


@needs_dev_full
@pytest.mark.parametrize("extra", [("-o", "-"), ()], ids=["csv", "summary"])
def test_replay_stdout_on_a_full_disk_is_one_line(tmp_path, extra):
    cfg = one_mouse_config(tmp_path, rate=1000)
    with open("/dev/full", "w") as full:
        proc = subprocess.run(
            [sys.executable, "-m", "mousedom", "replay", "--config", str(cfg)]
            + ["--capture", f"m={external_dir() / PS2}", *extra],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            env=mousedom_env(),
            timeout=120,
        )
    assert proc.returncode != 0
    _one_error_line(proc.stderr, "<stdout>", "cannot write")
