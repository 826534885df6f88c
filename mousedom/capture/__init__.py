"""Capture files: evemu, libinput record and mousedom's native format.

Entry points:

- ``open_capture(path)``: sniff the format and open it for streaming (a ``Capture``).
- ``parse_capture_arg("NAME=FILE")``: one ``--capture`` argument.
- ``assign(config, specs)``: open every ``--capture`` (and the config's own ``replay:``
  entries), and map each capture device onto a mouse of the config.
- ``time_offset(captures)``: what to subtract so that epoch-stamped files start at 0.
- ``read_reports(config, specs)``: whole captures as per-mouse report arrays on one time
  base (for calibration and other tools that want everything in memory).
"""

from __future__ import annotations

import os
import stat
import weakref
from dataclasses import dataclass

import numpy as np

from mousedom.capture.base import (
    Batch,
    Capture,
    CaptureError,
    DeviceInfo,
    DeviceStats,
    Feed,
    Motion,
    Serial,
)
from mousedom.capture.evemu import EvemuCapture, companion
from mousedom.capture.libinput import LibinputCapture, looks_like_libinput
from mousedom.capture.native import NativeCapture, NativeWriter, is_native
from mousedom.capture.plain import BOM, compression, discard, plain_copy
from mousedom.config import Config, EvdevMatch, MouseConfig
from mousedom.saferead import kind_of, open_regular
from mousedom.sources.base import Reports

__all__ = [
    "Assignment",
    "Batch",
    "Capture",
    "CaptureError",
    "DeviceInfo",
    "DeviceStats",
    "Feed",
    "Motion",
    "NativeWriter",
    "Serial",
    "assign",
    "captures_of",
    "mice_by_device",
    "open_capture",
    "parse_capture_arg",
    "read_reports",
    "relative_alignment_warning",
    "time_offset",
]


def sniff(path: str, data_path: str | None = None) -> str:
    """'native', 'libinput' or 'evemu' from the first bytes of the file (of its plain copy
    ``data_path`` when it has one)."""
    try:
        if os.path.exists(path) and not stat.S_ISREG(os.stat(path).st_mode):
            if os.path.isdir(path):
                raise IsADirectoryError
            # A pipe would lose what the sniffing read: the readers open the file again.
            raise CaptureError(
                f"{path}: is {kind_of(os.stat(path).st_mode)}, not a regular file; a capture "
                "is read more than once, save it to a file first"
            )
        with open_regular(data_path or path) as f:
            prefix = f.read(65536)
    except FileNotFoundError:
        if path.endswith(".desc") or path.endswith(".events"):
            return "evemu"  # the companion logic gives the better message
        raise CaptureError(f"{path}: capture file not found") from None
    except IsADirectoryError:
        raise CaptureError(f"{path}: is a directory, not a capture") from None
    except OSError as e:
        raise CaptureError(f"{path}: cannot read: {e.strerror}") from None
    if data_path is None and compression(prefix):
        return "compressed"  # open_capture sniffs again, on the decompressed copy
    prefix = prefix.removeprefix(BOM)
    if is_native(prefix):
        return "native"
    if looks_like_libinput(prefix):
        return "libinput"
    for raw in prefix.splitlines():
        line = raw.strip()
        if line.startswith(b"#") and b"EVEMU" in line.upper():
            return "evemu"
        if not line or line.startswith(b"#"):
            continue
        if line[:2] in (b"E:", b"N:", b"I:", b"P:", b"B:", b"A:"):
            return "evemu"
        break
    if not prefix.strip() and (path.endswith(".events") or path.endswith(".desc")):
        return "evemu"
    raise CaptureError(
        f"{path}: byte offset 0: not a capture this program knows "
        "(evemu-record text, libinput record YAML, or a mousedom native capture)"
    )


def open_capture(path: str | os.PathLike[str]) -> Capture:
    """Open a capture for streaming: any of the three formats, compressed (gzip, xz,
    bzip2) or not, with any line endings (see ``capture.plain``)."""
    p = str(path)
    sniff(p)  # a missing, special or unknown file is refused before any copy is made
    if p.endswith(".desc"):
        p = companion(p)[0]  # an old evemu pair: the events file is what is read
    if not os.path.exists(p):
        return EvemuCapture(p)  # its companion logic gives the better message
    try:
        copy, warning = plain_copy(p)
    except OSError as e:
        raise CaptureError(f"{p}: cannot read: {e.strerror}") from None
    try:
        kind = sniff(p, copy)
        reader = {"native": NativeCapture, "libinput": LibinputCapture}.get(kind, EvemuCapture)
        cap = reader(p, data_path=copy)
    except BaseException:
        discard(copy)
        raise
    if copy:
        weakref.finalize(cap, discard, copy)  # the copy goes with the capture
    if warning:
        cap.open_warnings.append(warning)
        cap.warnings.append(warning)
    return cap


# --------------------------------------------------------------------------- --capture


def parse_capture_arg(arg: str) -> tuple[str | None, str]:
    """``NAME=FILE`` -> (NAME, FILE); ``FILE`` -> (None, FILE).

    A file whose own name holds ``=`` is taken whole when it exists.
    """
    name, sep, file = arg.partition("=")
    if not sep or os.path.exists(arg):
        return None, arg
    if not name or not file:
        raise CaptureError(f"--capture {arg!r}: expected NAME=FILE or FILE")
    return name, file


@dataclass
class Assignment:
    """Mouse ``mouse`` (index into config.mice) comes from ``capture.devices[device]``."""

    mouse: int
    capture: Capture
    device: int


def _evdev_matches(match: EvdevMatch, dev: DeviceInfo) -> bool:
    given = False
    for key in ("name", "phys", "uniq", "vendor", "product"):
        want = getattr(match, key)
        if want is None:
            continue
        given = True
        if getattr(dev, key) != want:
            return False
    return given


def _matches(mouse: MouseConfig, dev: DeviceInfo) -> bool:
    if mouse.replay_device is not None:
        # By name, or by the recorded device node: two identical mice share their name,
        # and a libinput recording keeps only name, ids and node to tell them apart.
        return mouse.replay_device in (dev.name, dev.extra.get("node"))
    if dev.mouse is not None:
        return dev.mouse == mouse.name
    if mouse.evdev is not None and _evdev_matches(mouse.evdev, dev):
        return True
    return dev.name == mouse.name


def _candidates(capture: Capture) -> list[int]:
    """Devices that can be mice: they move (or may), or they are serial sensors."""
    return [i for i, d in enumerate(capture.devices) if d.kind == "serial" or d.rel_xy is not False]


def _node(capture: Capture, i: int) -> str:
    node = capture.devices[i].extra.get("node")
    return f" ({node})" if node else ""


def _describe(capture: Capture, devices: list[int]) -> str:
    return ", ".join(repr(capture.devices[i].name) + _node(capture, i) for i in devices) or "none"


def assign(
    config: Config, specs: list[tuple[str | None, str]], *, require_all: bool = True
) -> list[Assignment]:
    """Open the captures and map their devices onto the config's mice.

    ``specs`` are parsed ``--capture`` arguments; mice of the config with a ``replay:``
    source and no ``--capture`` of their own are read from that file.  Every mouse of the
    config must get exactly one device (unless ``require_all`` is false).
    """
    cfg_name = config.path or "the config"
    opened: dict[str, Capture] = {}

    def get(path: str) -> Capture:
        key = os.path.realpath(path)
        if key not in opened:
            opened[key] = open_capture(path)
        return opened[key]

    result: dict[int, Assignment] = {}

    def put(mouse: int, cap: Capture, dev: int, why: str) -> None:
        name = config.mice[mouse].name
        if mouse in result:
            prev = result[mouse]
            raise CaptureError(
                f"mouse {name!r} is given twice: {prev.capture.path} "
                f"({prev.capture.devices[prev.device].name!r}) and {cap.path} ({why})"
            )
        dev_info = cap.devices[dev]
        if dev_info.rel_xy is False:
            raise CaptureError(
                f"{cap.path}: device {dev_info.name!r} has no REL_X/REL_Y motion: "
                f"not a mouse, cannot be {name!r}"
            )
        result[mouse] = Assignment(mouse, cap, dev)

    for name, path in specs:
        cap = get(path)
        cands = _candidates(cap)
        if name is not None:
            if name not in config.names:
                raise CaptureError(
                    f"--capture {name}={path}: {cfg_name} has no mouse {name!r} "
                    f"(its mice: {', '.join(config.names)})"
                )
            mouse = config.index(name)
            wanted = config.mice[mouse].replay_device
            if wanted is not None and not any(_matches(config.mice[mouse], d) for d in cap.devices):
                raise CaptureError(
                    f"--capture {name}={path}: {cfg_name} names device {wanted!r} for mouse "
                    f"{name!r} (mice.{name}.replay.device), and the file holds "
                    f"{_describe(cap, cands)}"
                )
            if len(cap.devices) == 1:
                put(mouse, cap, 0, "given by name")
                continue
            hits = [i for i in cands if _matches(config.mice[mouse], cap.devices[i])]
            if len(cands) == 1 and not hits and config.mice[mouse].replay_device is None:
                hits = cands  # the only mover, and no device named that it could contradict
            if len(hits) != 1:
                raise CaptureError(
                    f"--capture {name}={path}: the file holds {len(cands)} motion devices "
                    f"({_describe(cap, cands)}) and {len(hits)} match mouse {name!r}; "
                    f"name the device (or its node) in {cfg_name} (mice.{name}.replay.device)"
                )
            put(mouse, cap, hits[0], "given by name")
        else:
            used = False
            for i in cands:
                hits = [k for k, m in enumerate(config.mice) if _matches(m, cap.devices[i])]
                if len(hits) > 1:
                    raise CaptureError(
                        f"{path}: device {cap.devices[i].name!r}{_node(cap, i)} matches several "
                        f"mice ({', '.join(config.mice[k].name for k in hits)}); set "
                        "mice.NAME.replay.device to the device's name or node"
                    )
                if hits:
                    put(hits[0], cap, i, "matched")
                    used = True
            if not used:
                raise CaptureError(
                    f"{path}: no device ({_describe(cap, cands)}) matches a mouse of "
                    f"{cfg_name} ({', '.join(config.names)}); give it as NAME={path}"
                )

    for k, m in enumerate(config.mice):
        if k in result or not m.replay:
            continue
        cap = get(m.replay)
        cands = _candidates(cap)
        hits = [i for i in cands if _matches(m, cap.devices[i])]
        if not hits and len(cands) == 1 and m.replay_device is None:
            hits = cands  # the only mover, and no device named that it could contradict
        if not hits and m.replay_device is not None:
            raise CaptureError(
                f"{m.replay}: mice.{m.name}.replay.device: no device {m.replay_device!r} in "
                f"this file (it holds {_describe(cap, cands)})"
            )
        if len(hits) != 1:
            raise CaptureError(
                f"{m.replay}: mice.{m.name}.replay: {len(hits)} devices match "
                f"(the file holds {_describe(cap, cands)}); set replay.device"
            )
        put(k, cap, hits[0], "from the config")

    if require_all:
        missing = [m.name for k, m in enumerate(config.mice) if k not in result]
        if missing:
            raise CaptureError(
                f"no capture for mouse {', '.join(map(repr, missing))} of {cfg_name}: "
                "give --capture NAME=FILE for every mouse"
            )
    return [result[k] for k in sorted(result)]


def relative_alignment_warning(captures: list[Capture]) -> str | None:
    """The one rule for separate files with relative times, in replay and calibration
    alike: each file's t = 0 is taken as the same instant, and this warning says so."""
    files = {os.path.realpath(c.path): c for c in captures if c.time_base == "relative"}
    if len(files) < 2:
        return None
    names = ", ".join(sorted(os.path.basename(c.path) for c in files.values()))
    return (
        f"{names}: times relative to each recording's own start; they are aligned at "
        "their t = 0, which is right only if the recordings started together (to be sure, "
        "record the mice into one file: `mousedom record`, or one `libinput record`)"
    )


def time_offset(captures: list[Capture]) -> tuple[float, list[str]]:
    """Seconds to subtract from epoch-stamped captures (0 for the others), and warnings.

    Epoch times are rebased to the earliest event of all epoch files given together, so
    that they stay aligned with one another; relative and monotonic times are kept.
    """
    firsts = [c.first_time() for c in captures if c.time_base == "epoch"]
    firsts = [t for t in firsts if t is not None]
    warnings = []
    bases = {c.time_base for c in captures}
    if "epoch" in bases and len(bases) > 1:
        warnings.append(
            "captures mix epoch (wall clock) and relative/monotonic times; "
            "their events cannot be aligned in time"
        )
    elif bases == {"monotonic", "relative"}:
        # Seconds since boot against seconds since a recording's start: as far apart as
        # the machine had been up, with empty windows all the way between.
        names = ", ".join(f"{os.path.basename(c.path)} ({c.time_base})" for c in captures)
        warnings.append(
            f"captures mix monotonic (since boot) and relative times ({names}); "
            "their events cannot be aligned in time"
        )
    aligned = relative_alignment_warning(captures)
    if aligned and bases == {"relative"}:
        warnings.append(aligned)
    return (min(firsts) if firsts else 0.0), warnings


def read_reports(
    config: Config, specs: list[tuple[str | None, str]], *, require_all: bool = True
) -> tuple[dict[str, Reports], dict[str, DeviceStats], list[str]]:
    """Every assigned mouse's whole capture as ``Reports`` on one time base.

    Returns (reports by mouse name, reader stats by mouse name, warnings).  For tools that
    need all the data at once (calibration); replay streams instead.
    """
    assignments = assign(config, specs, require_all=require_all)
    captures = captures_of(assignments)
    offset, warnings = time_offset(captures)
    parts: dict[int, list[Motion]] = {a.mouse: [] for a in assignments}
    stats: dict[str, DeviceStats] = {}
    for cap in captures:
        wanted = mice_by_device(assignments, cap)
        decoders: dict = {}
        for feed in cap.feeds():
            for batch in feed.batches:
                for mo in batch.motion:
                    for mouse in wanted.get(mo.device, ()):
                        parts[mouse].append(mo)
                for chunk in batch.serial:
                    if chunk.device in wanted:
                        # Raw ADNS-3080 bytes: the daemon's own decoder, on the file's times
                        # (the epoch offset is applied below, as for motion).
                        from mousedom.sources.adns import replay_decoder

                        dec = decoders.get(chunk.device)
                        if dec is None:  # not setdefault: that would build one per chunk
                            mouse = config.mice[wanted[chunk.device][0]]
                            dec = decoders[chunk.device] = replay_decoder(mouse)
                        r = dec.feed_many(chunk.t, chunk.data)
                        t, dx, dy = r.t, r.dx, r.dy
                        cap.stats[chunk.device].add_motion(t, dx, dy)
                        for mouse in wanted[chunk.device]:
                            parts[mouse].append(Motion(chunk.device, t, dx, dy))
        for dev, mice in wanted.items():
            for mouse in mice:
                stats[config.mice[mouse].name] = cap.stats[dev]
        warnings += cap.warnings
    out = {}
    for mouse, mos in parts.items():
        sub = offset if _capture_of(assignments, mouse).time_base == "epoch" else 0.0
        t = np.concatenate([m.t for m in mos]) if mos else np.empty(0)
        dx = np.concatenate([m.dx for m in mos]) if mos else np.empty(0)
        dy = np.concatenate([m.dy for m in mos]) if mos else np.empty(0)
        name = config.mice[mouse].name
        out[name] = Reports(name, t - sub, dx, dy)
    return out, stats, warnings


def _capture_of(assignments: list[Assignment], mouse: int) -> Capture:
    return next(a.capture for a in assignments if a.mouse == mouse)


def captures_of(assignments: list[Assignment]) -> list[Capture]:
    """The opened captures, each once, in the order of the assignments."""
    seen: list[Capture] = []
    for a in assignments:
        if all(a.capture is not s for s in seen):
            seen.append(a.capture)
    return seen


def mice_by_device(assignments: list[Assignment], capture: Capture) -> dict[int, tuple[int, ...]]:
    """Device index -> the mice it feeds, for one capture (one device may feed several)."""
    out: dict[int, tuple[int, ...]] = {}
    for a in assignments:
        if a.capture is capture:
            out[a.device] = out.get(a.device, ()) + (a.mouse,)
    return out
