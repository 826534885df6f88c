"""Fuzz targets for every parser: inputs with an independent truth, and one runner each.

Used by ``tests/test_fuzz.py`` (a bounded number of cases in the suite) and by
``scripts/fuzz.py`` (long runs with a seed).  Each target makes a case from a seed:

- ``valid``: a well-formed input written here, line by line, from random reports (not
  with the project's own writers), in any of the dresses users hand files over in (line
  endings, BOM, compression, comments, flow style, SYN_DROPPED, leading zeros).  Its truth
  is what was written: the REL_X/REL_Y totals, the parsed values.  It must be accepted,
  and "counts in = reported + counted as lost" must hold exactly.
- ``damaged``: a valid input with random damage (bytes flipped, inserted, deleted,
  duplicated, numbers made absurd, the end cut off).  It may be refused, with a UserError
  naming the input, or accepted; anything else is a crash.

A case that takes more than ``HANG_S`` seconds is a hang.  Wrong counts are checked only
where the truth is known (valid cases).
"""

from __future__ import annotations

import bz2
import gzip
import json
import lzma
import math
import os
import random
import signal
import struct
import tempfile
from collections.abc import Callable
from dataclasses import dataclass

from fuzz_hostile import HOSTILE

HANG_S = 10.0


@dataclass
class Case:
    target: str
    kind: str  # "valid" or "damaged"
    data: bytes
    truth: tuple | None = None  # what a valid case must give back
    suffix: str = ""


@dataclass
class Result:
    case: Case
    outcome: str  # "ok", "refused", "crash", "hang", "wrong"
    detail: str = ""


class Hang(Exception):
    pass


# --------------------------------------------------------------------------- dresses


def _dress(rng: random.Random, raw: bytes) -> tuple[bytes, str]:
    """One of the ways users hand text files over; the meaning stays."""
    kind = rng.choice(["plain"] * 4 + ["crlf", "cr", "bom", "gz", "xz", "bz2", "gz-crlf"])
    if kind == "crlf":
        return raw.replace(b"\n", b"\r\n"), ""
    if kind == "cr":
        return raw.replace(b"\n", b"\r"), ""
    if kind == "bom":
        return b"\xef\xbb\xbf" + raw, ""
    if kind == "gz":
        return gzip.compress(raw), ".gz"
    if kind == "xz":
        return lzma.compress(raw), ".xz"
    if kind == "bz2":
        return bz2.compress(raw), ".bz2"
    if kind == "gz-crlf":
        return gzip.compress(raw.replace(b"\n", b"\r\n")), ".gz"
    return raw, ""


_ABSURD = [
    b"9" * 400,
    b"-" + b"9" * 30,
    b"1e999",
    b"nan",
    b"-0",
    b"0x7fffffff",
    b"\x00",
    b"\xff\xfe",
]


def _damage(rng: random.Random, raw: bytes) -> bytes:
    data = bytearray(raw)
    for _ in range(rng.randint(1, 4)):
        if not data:
            data += bytes([rng.randrange(256)])
        op = rng.randrange(7)
        at = rng.randrange(len(data))
        if op == 0:
            data[at] = rng.randrange(256)
        elif op == 1:
            data[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        elif op == 2:
            del data[at : at + rng.randint(1, 64)]
        elif op == 3:
            n = rng.randint(1, 200)
            data[at:at] = data[at : at + n]
        elif op == 4:  # a number made absurd
            j = at
            while j < len(data) and not chr(data[j]).isdigit():
                j += 1
            k = j
            while k < len(data) and chr(data[k]).isdigit():
                k += 1
            data[j:k] = rng.choice(_ABSURD)
        elif op == 5:
            del data[at:]  # cut off (a crash while recording)
        else:
            data[at:at] = rng.choice([b"\r", b"\n", b"\t", b"#", b"[", b"{", b"- ", b"\r\n"])
    return bytes(data)


# --------------------------------------------------------------------------- captures


def _reports(rng: random.Random, n: int) -> list[tuple[float, int, int]]:
    t = rng.uniform(0.0, 2.0)
    out = []
    for _ in range(n):
        t += rng.choice([0.001, 0.008, rng.uniform(0.0001, 0.05)])
        out.append((round(t, 6), rng.randint(-127, 127), rng.randint(-127, 127)))
    return out


def _evemu_valid(rng: random.Random) -> Case:
    reps = _reports(rng, rng.randint(1, 400))
    epoch = rng.random() < 0.3
    base = 1_700_000_000.0 if epoch else 0.0
    lines = []
    if rng.random() < 0.7:
        lines += [
            "# EVEMU 1.3",
            '# Input device name: "fuzz mouse"',
            "N: fuzz mouse",
            "I: 0003 046d c077 0111",
            "P: 00 00 00 00 00 00 00 00",
            "B: 00 0b 00 00 00 00 00 00 00",
            "B: 02 03 01 00 00 00 00 00 00",
        ]
        if rng.random() < 0.3:
            lines.append("A: 2f 0 15 0 0 0")
    rel_x = rel_y = 0
    comment = rng.random() < 0.5
    pad = rng.random() < 0.5
    for t, dx, dy in reps:
        sec, usec = divmod(round((t + base) * 1e6), 1_000_000)
        stamp = f"E: {sec}.{usec:06d}"
        frame = []
        if dx:
            frame.append(f"{stamp} 0002 0000 {dx:04d}" if pad else f"{stamp} 0002 0000 {dx}")
        if dy:
            frame.append(f"{stamp} 0002 0001 {dy}" + ("\t# EV_REL / REL_Y" if comment else ""))
        if rng.random() < 0.05:
            frame.append(f"{stamp} 0001 0110 1")  # a button: skipped, not motion
        rel_x += dx
        rel_y += dy
        if rng.random() < 0.03:
            frame.append(f"{stamp} 0000 0003 0000")  # SYN_DROPPED: the frame's counts are lost
        frame.append(f"{stamp} 0000 0000 0000" + ("\t# ---- SYN_REPORT ----" if comment else ""))
        lines += frame
    raw = ("\n".join(lines) + "\n").encode()
    data, suffix = _dress(rng, raw)
    return Case("evemu", "valid", data, (rel_x, rel_y), suffix)


def _libinput_valid(rng: random.Random) -> Case:
    n_dev = rng.randint(1, 3)
    lines = ["# libinput record", "version: 1", f"ndevices: {n_dev}", "libinput:",
             "  version: 1.25.0", "system:", '  kernel: "6.8.0"', "devices:"]  # fmt: skip
    truth = []
    flow = rng.random() < 0.2
    for k in range(n_dev):
        lines += [
            f"- node: /dev/input/event{k + 4}",
            "  evdev:",
            f"    name: fuzz mouse {k}",
            f"    id: [3, 1133, {49271 + k}, 273]",
            "    codes:",
            "      0: [0, 1, 2] # EV_SYN",
            "      2: [0, 1, 8] # EV_REL",
            "    properties: []",
            "  events:",
        ]
        rx = ry = 0
        for t, dx, dy in _reports(rng, rng.randint(0, 200)):
            s, u = divmod(round(t * 1e6), 1_000_000)
            rows = []
            if dx:
                rows.append(f"[{s:3d}, {u:6d},   2,   0, {dx:5d}]")
            if dy:
                rows.append(f"[{s}, {u}, 2, 1, {dy}]")
            rows.append(f"[{s:3d}, {u:6d},   0,   0,     0]")
            rx, ry = rx + dx, ry + dy
            if flow:
                lines.append("  - evdev: [" + ", ".join(rows) + "]")
            else:
                lines.append("  - evdev:")
                lines += [f"    - {r} # EV_REL" for r in rows]
        truth.append((rx, ry))
    raw = ("\n".join(lines) + "\n").encode()
    data, suffix = _dress(rng, raw)
    return Case("libinput", "valid", data, tuple(truth), suffix or ".yml")


def _native_valid(rng: random.Random) -> Case:
    from mousedom.capture import DeviceInfo, NativeWriter

    n_dev = rng.randint(1, 3)
    devices = [DeviceInfo(name=f"d{k}", mouse=f"m{k}", rel_xy=True) for k in range(n_dev)]
    if rng.random() < 0.4:  # a gyro too, some of its samples marked saturated
        devices.append(DeviceInfo(name="g", kind="iio", rel_xy=False))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "x.mdcap")
        truth = [[0, 0] for _ in devices]
        with NativeWriter(path, devices, compress=rng.random() < 0.5,
                          chunk_reports=rng.choice([7, 100, 5000])) as w:  # fmt: skip
            for k in range(n_dev):
                reps = _reports(rng, rng.randint(0, 300))
                if reps:
                    t, dx, dy = zip(*reps, strict=True)
                    w.motion(k, list(t), list(dx), list(dy))
                    truth[k] = [sum(dx), sum(dy)]
                if rng.random() < 0.5:
                    w.sync(reps[-1][0] if reps else 0.0)
            if len(devices) > n_dev:  # (samples, saturated) is its truth
                reps = _reports(rng, rng.randint(0, 300))
                sat = [rng.random() < 0.1 for _ in reps]
                if reps:
                    w.gyro(n_dev, [r[0] for r in reps], [r[1] / 7.0 for r in reps], sat)
                truth[n_dev] = [len(reps), sum(sat)]
        with open(path, "rb") as f:
            data = f.read()
    return Case("native", "valid", data, tuple(map(tuple, truth)), ".mdcap")


def _run_capture(case: Case, tmp: str) -> str:
    from mousedom.capture import open_capture

    path = os.path.join(tmp, "capture" + case.suffix)
    with open(path, "wb") as f:
        f.write(case.data)
    cap = open_capture(path)
    cap.first_time()
    for feed in cap.feeds():
        for _ in feed.batches:
            pass
    got = tuple((s.reports, s.saturated) if d.kind == "iio" else
                (s.net_x + s.lost_x, s.net_y + s.lost_y)
                for d, s in zip(cap.devices, cap.stats, strict=True))  # fmt: skip
    if case.kind == "valid":
        want = case.truth if case.target != "evemu" else (case.truth,)
        if got != tuple(tuple(w) for w in want):
            return f"counts in {want}, reported + lost {got}"
    return ""


# --------------------------------------------------------------------------- round trips


def _roundtrip_valid(rng: random.Random) -> Case:
    """One to three valid captures (evemu, libinput record with 1-3 devices in its own or
    another layout, native; text in any dress; SYN_DROPPED frames of either sign), to be
    converted into one native capture."""
    from fuzz_hostile import layout_valid

    files = []
    makers = [_evemu_valid, _libinput_valid, _native_valid, layout_valid]
    for _ in range(rng.randint(1, 3)):
        maker = rng.choice(makers)
        if maker is _native_valid:
            makers.remove(_native_valid)  # its mouse names are fixed: one such file a case
        case = maker(rng)
        files.append((case.target, case.suffix, case.data))
    return Case("roundtrip", "valid", json.dumps(
        [[t, s, d.hex()] for t, s, d in files]).encode(), None, ".json")  # fmt: skip


def _motion_of(cap) -> dict[int, tuple]:
    import numpy as np

    got: dict[int, list] = {}
    for feed in cap.feeds():
        for batch in feed.batches:
            for m in batch.motion:
                got.setdefault(m.device, []).append(m)
    return {
        d: tuple(np.concatenate([getattr(m, a) for m in ms]) for a in ("t", "dx", "dy"))
        for d, ms in got.items()
    }


def _gyro_of(cap) -> dict[int, tuple]:
    """Each gyro's (t, rate, saturated) as read, saturated False where unmarked."""
    import numpy as np

    got: dict[int, list] = {}
    for feed in cap.feeds():
        for batch in feed.batches:
            for r in batch.gyro:
                sat = np.zeros(len(r.t), bool) if r.saturated is None else r.saturated
                got.setdefault(r.device, []).append((r.t, r.rate, sat))
    return {d: tuple(np.concatenate(c) for c in zip(*rs, strict=True)) for d, rs in got.items()}


def _gyro_differs(want: dict[int, tuple], got: dict[int, tuple]) -> str:
    import numpy as np

    for d, w in want.items():
        g = got.get(d, ())
        if len(w) != len(g) or not all(np.array_equal(a, b) for a, b in zip(w, g, strict=True)):
            return f"device {d}: gyro samples or their marks differ after the round trip"
    return ""


def _run_roundtrip(case: Case, tmp: str) -> str:
    """convert -> native -> read back: every device's reports (times to the microsecond,
    counts exactly) and its counters (frames, dropped, lost counts of either sign) as the
    inputs gave them."""
    import numpy as np

    from mousedom.capture import open_capture, time_offset
    from mousedom.commands.convert import convert

    if case.kind != "valid":
        return _run_capture(Case("native", case.kind, case.data, None, ".mdcap"), tmp)
    inputs = []
    for k, (target, suffix, data) in enumerate(json.loads(case.data)):
        path = os.path.join(tmp, f"in{k}.{target}{suffix}")
        with open(path, "wb") as f:
            f.write(bytes.fromhex(data))
        inputs.append((None, open_capture(path)))
    out = os.path.join(tmp, "out.mdcap")
    convert(inputs, out, compress=bool(len(inputs) % 2))
    want_motion, want_stats = [], []
    # Epoch times are rebased when the inputs mix time bases (the replay would do the same).
    offset, _ = time_offset([cap for _, cap in inputs])
    mixed = len({cap.time_base for _, cap in inputs}) > 1
    want_gyro: dict[int, tuple] = {}
    for _, cap in inputs:
        gyros = _gyro_of(cap)
        motion = _motion_of(cap)  # (re)streams the capture, so its stats are whole
        sub = offset if mixed and cap.time_base == "epoch" else 0.0
        for d, dev in enumerate(cap.devices):
            if dev.kind == "iio":  # a gyro: its samples and marks, exactly
                g = gyros.get(d)
                want_gyro[len(want_motion)] = () if g is None else (g[0] - sub, g[1], g[2])
                want_motion.append(None)
                want_stats.append(cap.stats[d])
                continue
            if dev.rel_xy is False:
                continue
            m = motion.get(d)
            want_motion.append(None if m is None or not len(m[0]) else (m[0] - sub, m[1], m[2]))
            want_stats.append(cap.stats[d])
    back = open_capture(out)
    bad = _gyro_differs(want_gyro, _gyro_of(back))
    if bad:
        return bad
    got_motion = _motion_of(back)
    if len(back.devices) != len(want_motion):
        return f"{len(want_motion)} devices written, {len(back.devices)} read back"
    for d, want in enumerate(want_motion):
        got = got_motion.get(d)
        got = None if got is None or not len(got[0]) else got
        if (want is None) != (got is None):
            return f"device {d}: reports written {want is not None}, read {got is not None}"
        if want is not None:
            t_ok = np.array_equal(np.round(want[0] * 1e6), np.round(got[0] * 1e6))
            if not (t_ok and np.array_equal(want[1], got[1]) and np.array_equal(want[2], got[2])):
                return f"device {d}: reports differ after the round trip"
        a, b = want_stats[d], back.stats[d]
        for name in ("frames", "dropped_frames", "lost_x", "lost_y", "net_x", "net_y", "skipped"):
            if getattr(a, name) != getattr(b, name):
                return f"device {d}: {name} {getattr(a, name)} written, {getattr(b, name)} read"
    return ""


# --------------------------------------------------------------------------- ADNS bytes


def _adns_valid(rng: random.Random) -> Case:
    from mousedom.sources import adns_protocol as P

    stream = b""
    sx = sy = 0
    t_us = rng.randrange(1 << 31)
    for seq in range(rng.randint(1, 200)):
        t_us = (t_us + rng.randint(1000, 20000)) % (1 << 32)  # wraps now and then
        dx, dy = rng.randint(-2000, 2000), rng.randint(-2000, 2000)
        stream += P.encode_packet(P.Motion(seq % 65536, t_us, dx, dy, 12, rng.randint(0, 169), 0))
        sx, sy = sx + dx, sy - dy  # the decoder turns sensor +dy (forward) into -REL_Y
    return Case("adns", "valid", stream, (sx, sy))


def _run_adns(case: Case, tmp: str) -> str:
    from mousedom.sources.adns_decode import AdnsDecoder

    dec = AdnsDecoder(name="fuzz")
    rng = random.Random(len(case.data))
    sx = sy = 0
    at, host = 0, 100.0
    while at < len(case.data):
        n = rng.randint(1, 64)
        host += rng.uniform(0.0, 0.01)
        reports, _ = dec.feed(case.data[at : at + n], host)
        at += n
        if len(reports.t):
            if not all(b >= a for a, b in zip(reports.t, reports.t[1:], strict=False)):
                return "report times go backwards"
        sx += int(sum(reports.dx))
        sy += int(sum(reports.dy))
    if case.kind == "valid" and ((sx, sy) != case.truth or dec.lost):
        return f"counts in {case.truth}, reported {(sx, sy)}, lost packets {dec.lost}"
    return ""


# --------------------------------------------------------------------------- IIO records

_IIO_TYPES = ("le:s16/16>>0", "be:s16/16>>0", "le:u16/16>>0", "le:s24/32>>8", "be:s12/16>>4",
              "le:s32/32>>0", "be:u8/8>>0")  # fmt: skip


def _iio_valid(rng: random.Random) -> Case:
    """Records of a random IIO layout (a gyro axis of a random type, the s64 timestamp,
    maybe another channel), packed here one value at a time as the kernel documents:
    channels in scan-index order, each at a multiple of its storage bytes, the record
    padded to the largest.  The case's data starts with the layout as a JSON line."""
    chans = [(4, rng.choice(_IIO_TYPES)), (7, "le:s64/64>>0")]
    if rng.random() < 0.5:
        chans.insert(0, (rng.randint(0, 3), rng.choice(_IIO_TYPES)))
    values = []
    out = bytearray()
    for _ in range(rng.randint(0, 200)):
        row = []
        record = bytearray()
        for _, kind in chans:
            endian, rest = kind.split(":")
            signed = rest[0] == "s"
            real, rest2 = rest[1:].split("/")
            storage, shift = (int(v) for v in rest2.split(">>"))
            real_bits = int(real)
            lo = -(1 << (real_bits - 1)) if signed else 0
            hi = (1 << (real_bits - 1)) - 1 if signed else (1 << real_bits) - 1
            v = rng.randint(lo, hi)
            row.append(v)
            field = (v & ((1 << real_bits) - 1)) << shift
            size = storage // 8
            while len(record) % size:
                record.append(0)
            record += field.to_bytes(size, "big" if endian == "be" else "little")
        big = max(int(k.split("/")[1].split(">>")[0]) // 8 for _, k in chans)
        while len(record) % big:
            record.append(0)
        out += record
        values.append(tuple(row))
    head = json.dumps(chans).encode() + b"\n"
    return Case("iio", "valid", head + bytes(out), tuple(values))


def _run_iio(case: Case, tmp: str) -> str:
    from mousedom.sources.iio_layout import (
        Element,
        LayoutError,
        decode_records,
        parse_scan_type,
        record_layout,
    )

    head, _, body = case.data.partition(b"\n")
    try:
        chans = json.loads(head)
        elements = [Element(f"c{i}", int(ix), parse_scan_type(str(kind), f"c{i}"))
                    for i, (ix, kind) in enumerate(chans)]  # fmt: skip
        layout = record_layout(elements)
    except (ValueError, TypeError, OverflowError, LayoutError):
        # a damaged layout line (the harness's own encoding of the scan elements): nothing
        # to decode; the source refuses such a layout (tests/test_iio_layout.py)
        return ""
    rng = random.Random(len(body))
    rows: list[tuple] = []
    rest = b""
    at = 0
    while at < len(body):  # in reads of any size, the partial record kept for the next
        n = rng.randint(1, 97)
        decoded = decode_records(rest + body[at : at + n], layout)
        at += n
        rest = decoded.rest
        if len(rest) >= max(layout.size, 1):
            return f"{len(rest)} bytes held back of records of {layout.size}"
        cols = [
            decoded.columns[e.name].tolist() for e in sorted(elements, key=lambda e: e.scan_index)
        ]
        rows += list(zip(*cols, strict=True))
    if case.kind == "valid":
        order = sorted(range(len(chans)), key=lambda i: int(chans[i][0]))
        want = [tuple(v[i] for i in order) for v in case.truth or ()]
        if rows != want or rest:
            return f"{len(want)} records written, {len(rows)} decoded differently"
    return ""


# --------------------------------------------------------------------------- config YAML


def _config_valid(rng: random.Random) -> Case:
    n = rng.randint(2, 4)
    model = rng.choice(["lsq", "diff-drive"])
    integrator = rng.choice(["exact", "taylor", "euler", "midpoint"])
    lines = [f"rate_hz: {rng.choice([50, 100, 125.5])}", f"model: {model}",
             f"integrator: {integrator}", "mice:"]  # fmt: skip
    mice = {}
    for k in range(n):
        x, y = round(rng.uniform(-0.2, 0.2), 3), round(rng.uniform(-0.2, 0.2), 3)
        if model == "diff-drive" and k == 0:
            x = 0.15
        cpi = rng.randint(200, 3200)
        mice[f"m{k}"] = (cpi, x, y)
        lines += [f"  m{k}:", f"    cpi: {cpi}", f"    mount: {{x: {x}, y: {y}, yaw: 0}}",
                  f"    evdev: {{path: /dev/input/event{k + 3}}}"]  # fmt: skip
    lines.append("server: {mode: '0660', control_uids: [0], max_line: 4096}")
    raw = ("\n".join(lines) + "\n").encode()
    if rng.random() < 0.3:
        raw = raw.replace(b"\n", b"\t\n")  # trailing tabs: legal YAML for libyaml
    return Case("config", "valid", raw, tuple(sorted(mice.items())))


def _run_config(case: Case, tmp: str) -> str:
    from mousedom.config import load_config

    path = os.path.join(tmp, "rig.yaml")
    with open(path, "wb") as f:
        f.write(case.data)
    cfg = load_config(path)
    if case.kind == "valid":
        got = tuple(sorted((m.name, (m.cpi_x, m.mount.x, m.mount.y)) for m in cfg.mice))
        if got != case.truth:
            return f"wrote {case.truth}, read {got}"
    return ""


# --------------------------------------------------------------------------- CSV


def _csv_valid(rng: random.Random) -> Case:
    if rng.random() < 0.5:
        rows = [(round(0.1 * k, 3), rng.uniform(-1, 1), 0.0, rng.uniform(-1, 1))
                for k in range(rng.randint(2, 50))]  # fmt: skip
        text = "t,vx,vy,omega\n" + "".join(",".join(f"{v!r}" for v in r) + "\n" for r in rows)
        return Case("csv", "valid", text.encode(), ("ref", len(rows)))
    rows = [(rng.choice(["cw", "ccw"]), rng.uniform(-1, 1), rng.uniform(-1, 1))
            for _ in range(rng.randint(1, 20))]  # fmt: skip
    text = "# runs\ndirection,dx,dy\n" + "".join(f"{d},{x!r},{y!r}\n" for d, x, y in rows)
    return Case("csv", "valid", text.encode(), ("runs", len(rows)))


def _run_csv(case: Case, tmp: str) -> str:
    from mousedom.calibrate.reference import parse_reference
    from mousedom.calibrate.umbmark import parse_runs

    try:
        text = case.data.decode("utf-8")
    except UnicodeDecodeError:
        return ""  # the readers' callers refuse undecodable bytes before parsing
    ref_like = text.lstrip().startswith("t,") or (case.truth or ("",))[0] == "ref"
    if ref_like:
        ref = parse_reference(text, "REF.csv")
        n = len(ref.t)
    else:
        directions, _ = parse_runs(text, "RUNS.csv")
        n = len(directions)
    if case.kind == "valid" and n != case.truth[1]:
        return f"wrote {case.truth[1]} rows, read {n}"
    return ""


# --------------------------------------------------------------------------- protocol


def _protocol_valid(rng: random.Random) -> Case:
    cmd = rng.choice([
        {"cmd": "status"},
        {"cmd": "reset", "x": rng.uniform(-5, 5)},
        {"cmd": "fix", "theta": rng.uniform(-3, 3)},
        {"cmd": "rate", "hz": rng.choice([0, 1, 10, 100.5])},
    ])  # fmt: skip
    if rng.random() < 0.5:
        cmd["id"] = rng.choice([1, "a", 2.5, None, True])
    lines = [json.dumps(cmd).encode() for _ in range(rng.randint(1, 5))]
    return Case("protocol", "valid", b"\n".join(lines) + b"\n", (cmd["cmd"], len(lines)))


def _run_protocol(case: Case, tmp: str) -> str:
    from mousedom.service.protocol import (
        LineBuffer,
        ProtocolError,
        TooLong,
        encode,
        error_message,
        parse_command,
    )

    buf = LineBuffer(4096)
    rng = random.Random(len(case.data))
    names = []
    at = 0
    while at < len(case.data):
        n = rng.randint(1, 100)
        for line in buf.feed(case.data[at : at + n]):
            if isinstance(line, TooLong) or not line.strip():
                continue
            try:
                cmd = parse_command(line)
            except ProtocolError as e:
                json.loads(encode(error_message(str(e), e.id)))  # the reply must encode
                continue
            if not all(math.isfinite(v) for v in cmd.args.values()):
                return f"non-finite argument in {cmd}"
            json.loads(encode({"class": "OK", "id": cmd.id}))
            names.append(cmd.name)
        at += n
    if case.kind == "valid" and (len(names), set(names)) != (case.truth[1], {case.truth[0]}):
        return f"sent {case.truth}, parsed {names}"
    return ""


# --------------------------------------------------------------------------- registry

_MAKERS: dict[str, tuple[Callable[[random.Random], Case], Callable[[Case, str], str]]] = {
    "evemu": (_evemu_valid, _run_capture),
    "libinput": (_libinput_valid, _run_capture),
    "native": (_native_valid, _run_capture),
    "roundtrip": (_roundtrip_valid, _run_roundtrip),
    "adns": (_adns_valid, _run_adns),
    "config": (_config_valid, _run_config),
    "csv": (_csv_valid, _run_csv),
    "protocol": (_protocol_valid, _run_protocol),
    "iio": (_iio_valid, _run_iio),
}
_MAKERS.update(HOSTILE)
TARGETS = tuple(_MAKERS)


def _damage_native_chunk(rng: random.Random, raw: bytes) -> bytes:
    """Damage one chunk's header or payload and make its CRC right again, so the reader's
    checks beyond the CRC are reached (a count beyond the payload, absurd times)."""
    import zlib

    from mousedom.capture.native import CHUNK, _chunk_crc

    starts = [i for i in range(len(raw)) if raw.startswith(b"MDCK", i)]
    if not starts:
        return _damage(rng, raw)
    at = rng.choice(starts)
    magic, kind, flags, source, count, size, _ = CHUNK.unpack_from(raw, at)
    payload = raw[at + CHUNK.size : at + CHUNK.size + size]
    if flags & 1:
        try:
            payload = zlib.decompress(payload)
        except zlib.error:
            return _damage(rng, raw)
        flags &= ~1
    field = rng.randrange(6)
    if field == 0:
        count = rng.choice([0, count + 1, count * 1000 + 7, 2**32 - 1])
    elif field == 1:
        kind = rng.choice([0, 1, 2, 3, 4, 5, 6, 9])
    elif field == 2:
        source = rng.choice([source + 1, 0xFFFF])
    elif field == 3 and len(payload) >= 8:
        bad = struct.pack("<d", rng.choice([float("nan"), float("inf"), 1e300, -1e300, -1.0]))
        k = rng.randrange(0, len(payload) - 7)
        payload = payload[:k] + bad + payload[k + 8 :]
    elif field == 4:
        payload = rng.choice([b"", payload[: len(payload) // 2], payload * 2,
                              b'{"skipped": 1e999}', b"[" * 3000])  # fmt: skip
    else:
        payload = bytes(rng.randrange(256) for _ in range(rng.randint(0, 64)))
    head = CHUNK.pack(magic, kind, flags, source, count % 2**32, len(payload), 0)[:16]
    chunk = head + struct.pack("<I", _chunk_crc(head, payload)) + payload
    return raw[:at] + chunk + raw[at + CHUNK.size + size :]


def make_case(target: str, seed: int) -> Case:
    rng = random.Random(f"{target}:{seed}")
    case = _MAKERS[target][0](rng)
    if target in ("roundtrip", "bomb", "stamps"):
        return case  # hostile or valid by construction: that is what is tried
    if target == "native" and rng.random() < 0.3:
        return Case(target, "damaged", _damage_native_chunk(rng, case.data), None, case.suffix)
    if rng.random() < 0.6:
        raw = case.data
        if case.suffix in (".gz", ".xz", ".bz2") and rng.random() < 0.7:
            raw = {".gz": gzip.decompress, ".xz": lzma.decompress, ".bz2": bz2.decompress}[
                case.suffix
            ](raw)
            case.suffix = ""
        case = Case(target, "damaged", _damage(rng, raw), None, case.suffix)
    return case


def _alarm(signum, frame):
    raise Hang


def run_case(case: Case, tmp: str, hang_s: float = HANG_S) -> Result:
    """Run one case; never raises (but KeyboardInterrupt)."""
    from mousedom.errors import UserError

    runner = _MAKERS[case.target][1]
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, hang_s)
    try:
        wrong = runner(case, tmp)
    except Hang:
        return Result(case, "hang", f"more than {hang_s:g} s")
    except UserError as e:
        text = str(e)
        if case.kind == "valid":
            return Result(case, "wrong", f"a valid input was refused: {text}")
        lines = text.strip().splitlines()
        # One line, or (a config's several mistakes at once) one line per problem, each
        # naming the file as the first does.
        first = lines[0].split(":", 1)[0] if lines else ""
        if not lines or not first or not all(ln.startswith(first + ":") for ln in lines):
            return Result(case, "crash", f"refusal is not one line per problem: {text!r}")
        return Result(case, "refused", text)
    except Exception as e:  # noqa: BLE001 - that is what a fuzzer looks for
        import traceback

        return Result(case, "crash", f"{type(e).__name__}: {e}\n{traceback.format_exc()}")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    if wrong:
        return Result(case, "wrong", wrong)
    return Result(case, "ok")
