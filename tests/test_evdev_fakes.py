"""Helpers (no tests here): describe a machine's input devices as a directory tree.

The tree has the layout the kernel and udev publish: ``dev/input/eventN`` (a FIFO, so that
the evdev source can read it as a raw input_event stream), ``dev/input/by-id`` and
``by-path`` symlinks, ``sys/class/input/eventN/device/{name,phys,uniq,id/*,capabilities/rel}``
and ``run/udev/data/c13:<minor>``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from mousedom.sources.discovery import SystemPaths
from mousedom.sources.events import EV_REL, EV_SYN, REL_X, REL_Y, SYN_REPORT, encode_input_events


@pytest.fixture
def stamps_on_their_own_clock(monkeypatch):
    """For tests whose stamps are on a clock of their own (0 to 101 s) and that read at
    time 0: the bound of stamps against the read's time (sources.base.STAMP_AHEAD_S) is
    lifted; it is tested in test_stamps.py.  Use it as an autouse fixture."""
    from mousedom.sources import base

    monkeypatch.setattr(base, "STAMP_AHEAD_S", math.inf)
    monkeypatch.setattr(base, "STAMP_BEHIND_S", math.inf)


def add_device(
    root: Path,
    n: int,
    name: str,
    *,
    phys: str = "",
    uniq: str = "",
    bustype: int = 0x03,
    vendor: int = 0x046D,
    product: int = 0xC077,
    rel: str = "903",  # REL_X|REL_Y|REL_WHEEL|REL_WHEEL_HI_RES... (hex mask, sysfs style)
    by_id: tuple[str, ...] = (),
    by_path: tuple[str, ...] = (),
    mouse_dpi: str | None = None,
    fifo: bool = True,
) -> str:
    dev = root / "dev" / "input"
    dev.mkdir(parents=True, exist_ok=True)
    node = dev / f"event{n}"
    if fifo:
        os.mkfifo(node)
    else:
        node.write_bytes(b"")
    for kind, names in (("by-id", by_id), ("by-path", by_path)):
        (dev / kind).mkdir(exist_ok=True)
        for link in names:
            (dev / kind / link).symlink_to(f"../event{n}")
    sysdev = root / "sys" / "class" / "input" / f"event{n}"
    (sysdev / "device" / "id").mkdir(parents=True)
    (sysdev / "device" / "capabilities").mkdir()
    (sysdev / "dev").write_text(f"13:{64 + n}\n")
    (sysdev / "device" / "name").write_text(name + "\n")
    (sysdev / "device" / "phys").write_text(phys + "\n")
    (sysdev / "device" / "uniq").write_text(uniq + "\n")
    (sysdev / "device" / "capabilities" / "rel").write_text(rel + "\n")
    for key, v in (
        ("bustype", bustype),
        ("vendor", vendor),
        ("product", product),
        ("version", 0x111),
    ):
        (sysdev / "device" / "id" / key).write_text(f"{v:04x}\n")
    if mouse_dpi is not None:
        udev = root / "run" / "udev" / "data"
        udev.mkdir(parents=True, exist_ok=True)
        (udev / f"c13:{64 + n}").write_text(
            f"I:123\nE:ID_INPUT=1\nE:ID_INPUT_MOUSE=1\nE:MOUSE_DPI={mouse_dpi}\nG:seat\n"
        )
    return str(node)


def paths(root: Path) -> SystemPaths:
    return SystemPaths.under(str(root))


def report_bytes(t, dx, dy) -> bytes:
    """Reports -> REL_X, REL_Y, SYN_REPORT records (3 per report), all three stamped t."""
    n = len(t)
    return encode_input_events(
        np.repeat(np.asarray(t, dtype=np.float64), 3),
        np.tile([EV_REL, EV_REL, EV_SYN], n),
        np.tile([REL_X, REL_Y, SYN_REPORT], n),
        np.column_stack([dx, dy, np.zeros(n, dtype=np.int64)]).astype(np.int64).ravel(),
    )


def motion_bytes(t0: float, dxs, dys, dt: float = 0.008) -> bytes:
    """One SYN_REPORT frame per (dx, dy), ``dt`` apart from ``t0``."""
    if len(dxs) != len(dys):
        raise ValueError(f"{len(dxs)} dx values, {len(dys)} dy values")
    return report_bytes(t0 + np.arange(len(dxs)) * dt, dxs, dys)
