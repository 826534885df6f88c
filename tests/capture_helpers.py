"""Helpers shared by the capture and replay tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import external_dir, run_mousedom

from mousedom.capture import open_capture
from mousedom.capture.evemu import format_evemu

GOLDEN = Path(__file__).resolve().parent / "golden"

# The facts of ../shared/captures/external/SOURCES.md: (file, events, frames, motion
# frames, net X, net Y, path X, path Y).
EXTERNAL = [
    ("evemu-devices__PS2_Generic_Mouse.events", 7147, 2707, 2707, -5424, -929, 10374, 5251),
    ("evemu-devices__Saitek_Cyborg_RAT5_Mouse.events", 1838, 803, 796, -111, -13, 609, 781),
    ("evemu-devices__Ultrathin_Touch_Mouse.events", 1109, 406, 349, -319, -7, 1765, 2041),
    ("evemu-devices__TPPS2_IBM_TrackPoint.events", 2618, 964, 945, -21, -10, 3447, 2750),
]
PS2 = EXTERNAL[0][0]


def drain(path, **kw):
    """Open a capture and stream it to the end; returns the capture (stats filled)."""
    cap = open_capture(str(path), **kw) if kw else open_capture(str(path))
    motion = {}
    for feed in cap.feeds():
        for batch in feed.batches:
            for m in batch.motion:
                motion.setdefault(m.device, []).append(m)
    cap.motion = {
        d: (
            np.concatenate([m.t for m in ms]),
            np.concatenate([m.dx for m in ms]),
            np.concatenate([m.dy for m in ms]),
        )
        for d, ms in motion.items()
    }
    return cap


ONE_MOUSE_YAML = """\
rate_hz: {rate}
model: diff-drive
mice:
  {name}:
    cpi: 800
    mount: {{x: 0.10, y: 0.0, yaw: 0}}
    report_hz: 125
"""


def one_mouse_config(tmp_path: Path, name: str = "m", rate: float = 100) -> Path:
    p = tmp_path / "one.yaml"
    p.write_text(ONE_MOUSE_YAML.format(name=name, rate=rate))
    return p


def replay_ps2(cfg: Path, *extra: str, **kw):
    """``mousedom replay --config CFG --capture m=<the PS/2 recording> EXTRA``, finished."""
    return run_mousedom(
        "replay", "--config", str(cfg), "--capture", f"m={external_dir() / PS2}", *extra, **kw
    )


def evemu_captures(folder: Path, result, prefix: str = "") -> list[str]:
    """Each mouse of a simulated run (``sim.simulate``'s result) as an evemu file in
    ``folder`` (``<prefix><mouse>.evemu``); the ``--capture NAME=FILE`` arguments."""
    args = []
    for name, r in result.reports.items():
        path = folder / f"{prefix}{name}.evemu"
        path.write_text(format_evemu(r.t, r.dx, r.dy, name=name))
        args += ["--capture", f"{name}={path}"]
    return args
