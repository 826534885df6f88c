"""The bundled demo data: small, loadable, and a faithful capture of its simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import run_mousedom

from mousedom.capture.replay import read_csv
from mousedom.demo import DEMO_CAPTURE, DEMO_CONFIG, demo_config


def test_demo_files_are_small_and_the_config_loads():
    assert DEMO_CAPTURE.stat().st_size < 1_000_000
    config = demo_config()
    assert config.names == ("front", "left", "right")
    assert all(m.replay == str(DEMO_CAPTURE) for m in config.mice)


def test_demo_replays_to_the_closed_square():
    """The demo drives a 1 m UMBmark square counter-clockwise: back home, one turn."""
    proc = run_mousedom("replay", "--config", str(DEMO_CONFIG), "-o", "-")
    assert proc.returncode == 0, proc.stderr
    rows = read_csv(proc.stdout)
    assert math.hypot(rows["x"][-1], rows["y"][-1]) < 0.01
    assert rows["theta"][-1] == pytest.approx(2 * math.pi, abs=0.01)
    # The far corner of the square is about (1, 1).
    far = np.argmax(rows["x"] + rows["y"])
    assert rows["x"][far] == pytest.approx(1.0, abs=0.03)
    assert rows["y"][far] == pytest.approx(1.0, abs=0.03)
