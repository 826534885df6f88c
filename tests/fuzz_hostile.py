"""Fuzz targets for the classes of issue 26: device layouts, compression, stamps.

Registered into ``fuzz_targets``'s registry (so ``scripts/fuzz.py`` and
``tests/test_fuzz.py`` run them with the others):

- ``layout``: a valid libinput recording written in another layout of the same YAML
  (PyYAML's block dump, sorted or not; a device as a flow mapping; ``node :``); its
  truth is the counts written, which the reader must give back.
- ``bomb``: a compressed capture (gzip, xz, bzip2 text, or a native file with zlib
  chunks) that inflates by a random ratio, up to far past what any capture does: small
  ratios are valid cases with their truth, large ones must be refused, none may crash or
  take long.
- ``stamps``: raw input_event bytes with hostile stamps (2**62 s, negative, far ahead or
  behind the read's time, NaN-free but absurd microseconds) and records out of step, read
  through a real pipe by the evdev source: every REL count must come out (reported, or
  counted as lost in a dropped frame), and every stamp handed on must lie within the
  bound of the read's time.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import os
import random
import struct
import zlib

import yaml


def _case(*a, **kw):
    from fuzz_targets import Case

    return Case(*a, **kw)


# --------------------------------------------------------------------------- layouts

# libyaml's parser and emitter: the same documents and text as yaml.safe_load's and
# yaml.safe_dump's (the same constructor, resolver and representer), at a fraction of the
# time: the pure-Python parse was most of a layout case's time.
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def layout_valid(rng: random.Random):
    from fuzz_targets import _libinput_valid

    base = _libinput_valid(random.Random(rng.random()))
    data = base.data
    if base.suffix in (".gz", ".xz", ".bz2"):
        data = {".gz": gzip.decompress, ".xz": lzma.decompress, ".bz2": bz2.decompress}[
            base.suffix
        ](data)
    text = data.decode("utf-8-sig").replace("\r\n", "\n").replace("\r", "\n")
    doc = yaml.load(text, Loader=_LOADER)
    kind = rng.choice(["sorted", "unsorted", "flow", "node-space", "flow-all"])
    if kind == "sorted":
        out = yaml.dump(doc, Dumper=_DUMPER, default_flow_style=False)
    elif kind == "unsorted":
        out = yaml.dump(doc, Dumper=_DUMPER, default_flow_style=False, sort_keys=False)
    elif kind == "flow-all":
        out = yaml.dump(doc, Dumper=_DUMPER, default_flow_style=True)
    elif kind == "node-space":
        out = text.replace("- node:", "- node :")
    else:  # each device a flow mapping on one line
        head = text[: text.index("\ndevices:") + 1] + "devices:\n"
        out = head + "".join(
            "- "
            + yaml.dump(d, Dumper=_DUMPER, default_flow_style=True, width=1 << 30).strip()
            + "\n"
            for d in doc["devices"]
        )
    return _case("layout", "valid", out.encode(), base.truth, ".yml")


def run_layout(case, tmp: str) -> str:
    from fuzz_targets import Case, _run_capture

    return _run_capture(Case("libinput", case.kind, case.data, case.truth, ".yml"), tmp)


# --------------------------------------------------------------------------- bombs


def bomb_valid(rng: random.Random):
    """A compressed file of evemu lines (or a native capture with one zlib chunk) whose
    inflated size is ``ratio`` times its stored size, more or less."""
    kind = rng.choice(["gzip", "xz", "bzip2", "native"])
    big = rng.random() < 0.5
    if kind == "native":
        count = rng.choice([1 << 10, 1 << 16, 1 << 20]) if big else rng.randint(1, 4000)
        payload = bytes(16 * count) if big else _native_motion(rng, count)
        return _case("bomb", "valid", _native_file(payload, count),
                     ("native", count, big), ".mdcap")  # fmt: skip
    if big:  # past the floor (1 MiB while fuzzing, see run_bomb) and past the ratio
        line = b"E: 0.000000 0000 0000 0000\n"
        n = rng.choice([1 << 16, 1 << 17, 1 << 18])  # 1.8 to 7 MB of lines
        block = line * (1 << 14)
        one = _compress(kind, block)
        raw = one * (n // (1 << 14))
        return _case("bomb", "valid", raw, ("text", 0, True), _SUFFIX[kind])
    from fuzz_targets import _evemu_valid

    c = _evemu_valid(random.Random(rng.random()))
    plain = c.data
    if c.suffix:
        plain = {".gz": gzip.decompress, ".xz": lzma.decompress, ".bz2": bz2.decompress}[c.suffix](
            plain
        )
    return _case("bomb", "valid", _compress(kind, plain), ("text", c.truth, False),
                 _SUFFIX[kind])  # fmt: skip


_SUFFIX = {"gzip": ".gz", "xz": ".xz", "bzip2": ".bz2"}


def _compress(kind: str, raw: bytes) -> bytes:
    if kind == "gzip":
        c = zlib.compressobj(9, zlib.DEFLATED, 31)
        return c.compress(raw) + c.flush()
    return lzma.compress(raw) if kind == "xz" else bz2.compress(raw, 9)


def _native_motion(rng: random.Random, count: int) -> bytes:
    t = sorted(rng.uniform(0, 100) for _ in range(count))
    dx = [rng.randint(-50, 50) for _ in range(count)]
    dy = [rng.randint(-50, 50) for _ in range(count)]
    return (struct.pack(f"<{count}d", *t) + struct.pack(f"<{count}i", *dx)
            + struct.pack(f"<{count}i", *dy))  # fmt: skip


def _native_file(payload: bytes, count: int) -> bytes:
    from mousedom.capture.native import CHUNK, MAGIC, MOTION, VERSION, ZLIB, _chunk_crc

    header = (
        b'{"config": null, "devices": [{"name": "d", "mouse": "m", "rel_xy": true}], '
        b'"format": "mousedom-capture", "time_base": "monotonic", "version": [1, 0]}'
    )
    out = MAGIC + struct.pack("<HHI", *VERSION, len(header)) + header
    out += struct.pack("<I", zlib.crc32(header))
    stored = zlib.compress(payload, 9)
    head = CHUNK.pack(b"MDCK", MOTION, ZLIB, 0, count, len(stored), 0)[:16]
    return out + head + struct.pack("<I", _chunk_crc(head, stored)) + stored


def run_bomb(case, tmp: str) -> str:

    from mousedom.capture import plain

    what, truth, big = case.truth
    path = os.path.join(tmp, "bomb" + case.suffix)
    with open(path, "wb") as f:
        f.write(case.data)
    # The ratio bound is what is fuzzed: every file may inflate to PLAIN_FLOOR (64 MiB)
    # whatever its size, which would make each case slow; 1 MiB here, the same code.
    floor, plain.PLAIN_FLOOR = plain.PLAIN_FLOOR, 1 << 20
    try:
        return _run_bomb(case, path, what, truth, big)
    finally:
        plain.PLAIN_FLOOR = floor


def _run_bomb(case, path: str, what: str, truth, big: bool) -> str:
    from mousedom.capture import open_capture
    from mousedom.errors import UserError

    try:
        cap = open_capture(path)
        n = 0
        for feed in cap.feeds():
            for batch in feed.batches:
                n += sum(len(m.t) for m in batch.motion)
    except UserError as e:
        if big:
            if "decompression bomb" not in str(e):
                return f"a bomb refused for another reason: {e}"
            return ""
        raise
    stored = len(case.data)
    if big:
        inflated = 16 * truth if what == "native" else 0
        if what == "native" and inflated > 100 * stored + 4096:
            return f"a chunk inflating {inflated / stored:.0f}:1 was accepted"
        if what == "text":
            return "a text bomb was accepted"
        return ""
    if what == "native":
        return "" if n == truth else f"{truth} reports written, {n} read"
    got = (cap.stats[0].net_x + cap.stats[0].lost_x, cap.stats[0].net_y + cap.stats[0].lost_y)
    return "" if got == tuple(truth) else f"counts in {truth}, reported + lost {got}"


# --------------------------------------------------------------------------- stamps


def stamps_valid(rng: random.Random):
    """(bytes written to the pipe, the read's time, REL totals): frames with random, some
    absurd, stamps; sometimes a few stray bytes put the stream out of step."""
    now = rng.uniform(100.0, 1e6)
    out = []
    rel = [0, 0]
    for _ in range(rng.randint(1, 120)):
        r = rng.random()
        if r < 0.6:
            t = now - rng.uniform(0, 2)
        elif r < 0.7:
            t = now + rng.choice([0.5, 2.0, 30.0, 1e6, 1e12])
        elif r < 0.8:
            t = now - rng.choice([59.0, 61.0, 1e6])
        else:
            t = None
        if t is None:
            sec, usec = rng.choice([(2**62, 0), (0, 2**62), (-(2**62), 0), (-1, -1),
                                    (2**63 - 1, 999_999), (0, -(2**63))])  # fmt: skip
        else:
            sec = int(t)
            usec = int((t - sec) * 1e6)
        dx, dy = rng.randint(-300, 300), rng.randint(-300, 300)
        drop = rng.random() < 0.05
        out.append(struct.pack("<qqHHi", sec, usec, 2, 0, dx))
        out.append(struct.pack("<qqHHi", sec, usec, 2, 1, dy))
        if drop:
            out.append(struct.pack("<qqHHi", sec, usec, 0, 3, 0))
        out.append(struct.pack("<qqHHi", sec, usec, 0, 0, 0))
        rel[0] += dx
        rel[1] += dy
    data = b"".join(out)
    stray = rng.random() < 0.2
    if stray:  # out of step: the totals are then unknown, only the bounds are checked
        k = rng.randrange(len(data))
        data = data[:k] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 23))) + data[k:]
    return _case("stamps", "valid", data, (now, None if stray else tuple(rel)), "")


def run_stamps(case, tmp: str) -> str:
    import logging

    from mousedom.config import EvdevMatch, Mount, MouseConfig
    from mousedom.sources.base import STAMP_AHEAD_S, STAMP_BEHIND_S, SourceGone
    from mousedom.sources.evdev import EvdevSource

    logging.getLogger("mousedom.sources.base").setLevel(logging.ERROR)  # said per case
    now, truth = case.truth
    path = os.path.join(tmp, "mouse.fifo")
    os.mkfifo(path)
    src = EvdevSource(MouseConfig("m", 800.0, 800.0, Mount(), evdev=EvdevMatch(path=path)))
    src.open()
    w = os.open(path, os.O_WRONLY)
    try:
        os.write(w, case.data)
    finally:
        os.close(w)
    got = [0, 0]
    stamps: list[float] = []
    for _ in range(10_000):
        try:
            batches = src.read(now)
        except SourceGone:
            break
        for b in batches:
            stamps += b.t.tolist()
            got[0] += int(sum(b.dx.tolist()))
            got[1] += int(sum(b.dy.tolist()))
    src.close()
    os.unlink(path)
    bad = [t for t in stamps if not now - STAMP_BEHIND_S <= t <= now + STAMP_AHEAD_S]
    if bad:
        return f"{len(bad)} stamps handed on out of bounds, e.g. {bad[0]!r} at {now!r}"
    if any(b < a for a, b in zip(stamps, stamps[1:], strict=False)):
        return "stamps handed on out of order"
    if truth is not None:
        st = src.assembler.stats
        out = (got[0] + st.dropped_dx, got[1] + st.dropped_dy)
        if out != truth:
            return f"counts in {truth}, reported + lost {out}"
    return ""


HOSTILE = {
    "layout": (layout_valid, run_layout),
    "bomb": (bomb_valid, run_bomb),
    "stamps": (stamps_valid, run_stamps),
}
