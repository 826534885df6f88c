"""``--capture NAME=FILE`` arguments -> per-mouse report arrays on one time base.

The readers are ``mousedom.capture`` (evemu, libinput record, native); this only picks
the reader by the file's first bytes, takes the device meant for NAME, and gathers its
motion reports.  A file with several devices (libinput record, native) gives the device
recorded as NAME (native) or the one named with ``NAME=FILE#DEVICE`` (its name or index).
Times stay on the captures' own base, which must be the same for every file (and the
same as the reference's, for ``calibrate mounts``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mousedom.capture.base import Capture
from mousedom.capture.evemu import EvemuCapture
from mousedom.capture.libinput import LibinputCapture, looks_like_libinput
from mousedom.capture.native import NativeCapture, is_native
from mousedom.config import Config
from mousedom.errors import UserError
from mousedom.sources.base import Reports


def parse_capture_arg(spec: str, names: Sequence[str]) -> tuple[str, str, str | None]:
    """'NAME=FILE[#DEVICE]' -> (name, file, device); NAME must be a mouse of the config."""
    name, sep, rest = spec.partition("=")
    if not sep or not name or not rest:
        raise UserError(f"--capture {spec!r}: expected NAME=FILE (NAME: a mouse of the config)")
    if name not in names:
        raise UserError(
            f"--capture {spec!r}: the config has no mouse {name!r} (it has {', '.join(names)})"
        )
    file, _, device = rest.partition("#")
    return name, file, device or None


def open_capture(path: str) -> Capture:
    """The reader for ``path``, chosen by its first bytes."""
    try:
        with open(path, "rb") as f:
            prefix = f.read(4096)
    except FileNotFoundError:
        raise UserError(f"{path}: capture file not found") from None
    except IsADirectoryError:
        raise UserError(f"{path}: is a directory, not a capture") from None
    except OSError as e:
        raise UserError(f"{path}: cannot read: {e.strerror}") from None
    if is_native(prefix):
        return NativeCapture(path)
    if looks_like_libinput(prefix):
        return LibinputCapture(path)
    return EvemuCapture(path)


def _pick_device(cap: Capture, name: str, device: str | None) -> int:
    names = [d.name for d in cap.devices]
    if device is not None:
        if device.isdigit() and int(device) < len(names):
            return int(device)
        if device in names:
            return names.index(device)
        raise UserError(f"{cap.path}: no device {device!r} (it has {', '.join(names)})")
    if len(names) == 1:
        return 0
    recorded = [i for i, d in enumerate(cap.devices) if d.mouse == name]
    if len(recorded) == 1:
        return recorded[0]
    listing = ", ".join(f"{i}: {n}" for i, n in enumerate(names))
    raise UserError(
        f"{cap.path}: holds {len(names)} devices ({listing}); say which is {name} with "
        f"--capture {name}={cap.path}#INDEX"
    )


def read_motion(cap: Capture, index: int, name: str) -> Reports:
    """All motion reports of one device of ``cap``, in time order."""
    ts, dxs, dys = [], [], []
    for feed in cap.feeds():
        if index not in feed.devices:
            continue
        for batch in feed.batches:
            for m in batch.motion:
                if m.device == index:
                    ts.append(m.t)
                    dxs.append(m.dx)
                    dys.append(m.dy)
    if not ts:
        return Reports(name, np.zeros(0), np.zeros(0), np.zeros(0))
    t = np.concatenate(ts)
    order = np.argsort(t, kind="stable")
    return Reports(name, t[order], np.concatenate(dxs)[order], np.concatenate(dys)[order])


def load_captures(specs: Sequence[str], config: Config) -> dict[str, Reports]:
    """Per-mouse reports from ``--capture`` arguments; every mouse of the config once."""
    recording: dict[str, Reports] = {}
    bases: dict[str, str] = {}
    files: set[str] = set()
    for spec in specs:
        name, file, device = parse_capture_arg(spec, config.names)
        if name in recording:
            raise UserError(f"--capture {spec!r}: mouse {name} is given twice")
        cap = open_capture(str(Path(file)))
        recording[name] = read_motion(cap, _pick_device(cap, name, device), name)
        bases[name] = cap.time_base
        files.add(str(Path(cap.path).resolve()))
    if len(files) > 1 and "relative" in bases.values():
        rel = ", ".join(n for n, b in bases.items() if b == "relative")
        raise UserError(
            f"the captures of {rel} have times relative to their own first event, so "
            "separate files cannot be aligned: record the mice together (one libinput "
            "record or native file) or with absolute times"
        )
    if len(set(bases.values())) > 1:
        listing = ", ".join(f"{n}: {b}" for n, b in bases.items())
        raise UserError(f"the captures do not share one time base ({listing})")
    return recording
