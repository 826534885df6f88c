"""Decompression bombs (issue 26): what a capture may inflate to is bounded by its size on
disk, in every compressed form a reader accepts (native chunks, gzip, xz, bzip2), with a
one-line error naming the file and the byte offset, a non-zero exit, bounded memory."""

from __future__ import annotations

import bz2
import lzma
import struct
import subprocess
import sys
import zlib

import pytest
from capture_helpers import one_mouse_config
from conftest import mousedom_env

from mousedom.capture import CaptureError, DeviceInfo, NativeWriter, open_capture
from mousedom.capture.native import CHUNK, MOTION, ZLIB, _chunk_crc
from mousedom.capture.plain import MAX_PLAIN_RATIO


def _chunk(kind: int, count: int, raw: bytes) -> bytes:
    payload = zlib.compress(raw, 9)
    head = CHUNK.pack(b"MDCK", kind, ZLIB, 0, count, len(payload), 0)[:16]
    return head + struct.pack("<I", _chunk_crc(head, payload)) + payload


def native_bomb(path, chunks: int, reports: int = 4 << 20) -> None:
    """A valid header, then chunks of ``reports`` all-zero reports (t 0, no motion): each
    64 MiB of columns stored in about 64 KB."""
    with NativeWriter(str(path), [DeviceInfo(name="d", mouse="m", rel_xy=True)]) as w:
        w.motion(0, [0.0], [1], [1])
    bomb = _chunk(MOTION, reports, bytes(16 * reports))
    with open(path, "ab") as f:
        for _ in range(chunks):
            f.write(bomb)


def _drain(path) -> int:
    cap = open_capture(str(path))
    n = 0
    for feed in cap.feeds():
        for batch in feed.batches:
            n += sum(len(m.t) for m in batch.motion)
    return n


def _replay_rss(cfg, capture, tmp_path) -> tuple[subprocess.CompletedProcess, int]:
    """replay as a child process; its peak RSS in MB (the largest child so far)."""
    code = (
        "import resource, subprocess, sys\n"
        "p = subprocess.run(sys.argv[1:], capture_output=True, text=True, timeout=120)\n"
        "sys.stdout.write(p.stdout); sys.stderr.write(p.stderr)\n"
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)\n"
        "sys.exit(p.returncode)\n"
    )
    argv = [
        sys.executable,
        "-c",
        code,
        sys.executable,
        "-m",
        "mousedom",
        "replay",
        "--config",
        str(cfg),
        "--capture",
        f"m={capture}",
        "-o",
        str(tmp_path / "o.csv"),
    ]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=180, env=mousedom_env())
    *_, rss = proc.stderr.strip().splitlines()
    proc.stderr = proc.stderr.strip().rsplit("\n", 1)[0]
    return proc, int(rss) // 1024


def test_a_native_chunk_bomb_is_refused_at_its_offset(tmp_path):
    path = tmp_path / "bomb.mdcap"
    native_bomb(path, chunks=16)  # 1 MB on disk, 1 GiB of reports claimed
    assert path.stat().st_size < 2 << 20
    with pytest.raises(CaptureError, match=r"bomb\.mdcap: byte offset \d+: .*decompression bomb"):
        _drain(path)
    proc, rss = _replay_rss(one_mouse_config(tmp_path), path, tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "decompression bomb" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert rss < 300, f"peak RSS {rss} MB"


def test_a_chunk_may_not_inflate_past_its_stated_count(tmp_path):
    """A chunk whose data inflates to more than its count of reports holds is refused
    before the excess is inflated (not after 64 MiB of it)."""
    path = tmp_path / "over.mdcap"
    with NativeWriter(str(path), [DeviceInfo(name="d", mouse="m", rel_xy=True)]) as w:
        w.motion(0, [0.0], [1], [1])
    with open(path, "ab") as f:
        f.write(_chunk(MOTION, 10, bytes(16 * 1000)))
    with pytest.raises(CaptureError, match="inflates past 160 bytes"):
        _drain(path)


def test_honest_compressed_captures_stay_well_inside_the_bound(tmp_path):
    """The writer's own chunks of realistic motion (1 kHz, small counts) and of long runs
    of identical reports inflate far below the ratio."""
    import numpy as np

    path = tmp_path / "ok.mdcap"
    n = 200_000
    t = np.arange(n) * 1e-3
    with NativeWriter(str(path), [DeviceInfo(name="d", mouse="m", rel_xy=True)]) as w:
        w.motion(0, t, np.ones(n, int), np.zeros(n, int))
    assert _drain(path) == n


def _text_bomb(kind: str, size: int) -> bytes:
    """``size`` bytes of evemu lines as one stream compressed many times over, the streams
    concatenated (which every reader must accept: ``cat a.gz b.gz``)."""
    block = b"E: 0.000000 0000 0000 0000\n" * (1 << 15)
    one = {"gzip": _gzip, "xz": lzma.compress, "bzip2": lambda b: bz2.compress(b, 9)}[kind](block)
    return one * (size // len(block))


def _gzip(raw: bytes) -> bytes:
    c = zlib.compressobj(9, zlib.DEFLATED, 31)
    return c.compress(raw) + c.flush()


@pytest.mark.parametrize("kind,suffix", [("gzip", ".gz"), ("xz", ".xz"), ("bzip2", ".bz2")])
def test_compressed_text_bombs_are_refused(tmp_path, kind, suffix):
    data = _text_bomb(kind, 200 << 20)
    ratio = (200 << 20) / len(data)
    assert ratio > MAX_PLAIN_RATIO * 2, ratio  # a bomb indeed
    path = tmp_path / f"bomb.events{suffix}"
    path.write_bytes(data)
    with pytest.raises(CaptureError, match=rf"bomb\.events{suffix}: byte offset \d+ of the "
                       rf"decompressed data: the {kind} inflates past"):  # fmt: skip
        open_capture(str(path))
    proc, rss = _replay_rss(one_mouse_config(tmp_path), path, tmp_path)
    assert proc.returncode == 2 and "decompression bomb" in proc.stderr, proc.stderr
    assert rss < 300, f"peak RSS {rss} MB"


def test_the_bound_spares_real_recordings(tmp_path, external_captures):
    """The real recordings, compressed as hard as each tool can, read back whole."""
    src = external_captures / "evemu-devices__PS2_Generic_Mouse.events"
    raw = src.read_bytes()
    for name, data in (("a.events.xz", lzma.compress(raw, preset=9 | lzma.PRESET_EXTREME)),
                       ("a.events.bz2", bz2.compress(raw, 9))):  # fmt: skip
        (tmp_path / name).write_bytes(data)
        assert _drain(tmp_path / name) == 2707


@pytest.mark.parametrize("kind", ["gzip", "xz", "bzip2"])
def test_concatenated_streams_decompress_to_what_they_hold(kind):
    """``cat a.gz b.gz``: each stream's bytes once, in order, whatever the streams' sizes.
    A gzip member that inflated past one BLOCK left the input after it in zlib's
    unconsumed_tail as well as in its unused_data, and both were read: the next member came
    twice (57 of 200 random splits of a capture; a report counted twice, exit 0)."""
    import io
    import random

    from mousedom.capture.plain import BLOCK, _decompress

    compress = {"gzip": _gzip, "xz": lzma.compress, "bzip2": lambda b: bz2.compress(b, 9)}[kind]
    for seed in range(12 if kind == "gzip" else 4):
        rng = random.Random(seed)
        parts = []
        for _ in range(rng.randint(1, 4)):
            size = rng.choice([0, 1, 100, BLOCK - 1, BLOCK, BLOCK + 1, 3 * BLOCK + 17])
            lines = b"".join(b"E: %d.%06d 0002 0000 %d\n" % (k, rng.randrange(10**6),
                             rng.randint(-99, 99)) for k in range(2000))  # fmt: skip
            parts.append((lines * (size // len(lines) + 1))[:size])
        data = b"".join(compress(p) for p in parts) + b"\0" * rng.choice([0, 0, 512])
        got = b"".join(_decompress(io.BytesIO(data), kind))
        assert got == b"".join(parts), (seed, [len(p) for p in parts], len(got))
