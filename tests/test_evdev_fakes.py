"""Helpers (no tests here): describe a machine's input devices as a directory tree.

The tree has the layout the kernel and udev publish: ``dev/input/eventN`` (a FIFO, so that
the evdev source can read it as a raw input_event stream), ``dev/input/by-id`` and
``by-path`` symlinks, ``sys/class/input/eventN/device/{name,phys,uniq,id/*,capabilities/rel}``
and ``run/udev/data/c13:<minor>``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mousedom.discovery import SystemPaths
from mousedom.events import EV_REL, EV_SYN, REL_X, REL_Y, SYN_REPORT, encode_input_events


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


def motion_bytes(t0: float, dxs, dys, dt: float = 0.008) -> bytes:
    """One SYN_REPORT frame per (dx, dy), REL_X then REL_Y then SYN_REPORT."""
    rows = []
    for i, (dx, dy) in enumerate(zip(dxs, dys, strict=True)):
        t = t0 + i * dt
        rows += [(t, EV_REL, REL_X, dx), (t, EV_REL, REL_Y, dy), (t, EV_SYN, SYN_REPORT, 0)]
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return encode_input_events(a[:, 0], a[:, 1], a[:, 2], a[:, 3].astype(np.int64))
