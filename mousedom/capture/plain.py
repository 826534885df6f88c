"""Captures as users keep them -> the plain bytes the readers parse.

Long captures are compressed (``run.yml.xz``), and text captures pass through editors
and other systems: a UTF-8 byte order mark, CRLF (Windows) or CR-only (old Mac) line
endings.  The readers' regular expressions and numpy passes work on LF-terminated lines,
where a stray ``\\r`` would make a line silently not match (a CRLF libinput file once
replayed as 0 reports, exit 0).  So such a file is first turned into a plain copy: an
anonymous-named temporary file (mkstemp: private, O_EXCL) that the reader opens instead,
removed when the capture is closed or collected.  Line numbers stay those of the original
(CRLF and CR each end one line), so messages still point into the user's file; byte
offsets in a compressed native capture count decompressed bytes, and messages say so.

A file that needs none of this is read in place, with no copy.
"""

from __future__ import annotations

import bz2
import lzma
import os
import tempfile
import zlib
from collections.abc import Callable, Iterator
from typing import Any, BinaryIO

from mousedom.capture.base import CaptureError
from mousedom.saferead import open_regular

BLOCK = 1 << 20
# Decompressed size beyond which a file is taken as a decompression bomb, not a capture
# (a one-hour recording of four 1 kHz mice is about 1.5 GB of evemu text).
MAX_PLAIN_BYTES = 32 << 30
# And at most this many times the compressed file's size (past a floor every small file
# gets): evemu and libinput text compresses 7-14:1 with gzip, xz or bzip2 (the recordings
# of ../shared/captures/external), while a bomb reaches 1000:1 and more.  Without it a
# 1 MB file could fill the temporary directory for minutes before any check.
MAX_PLAIN_RATIO = 200
PLAIN_FLOOR = 64 << 20
BOM = b"\xef\xbb\xbf"
_MAGIC = ((b"\x1f\x8b", "gzip"), (b"\xfd7zXZ\x00", "xz"), (b"BZh", "bzip2"))
# The three decompressor classes share no declared type (zlib's has unconsumed_tail, the
# others needs_input): _decompress tells them apart by ``kind``.
_DECOMPRESSORS: dict[str, Callable[[], Any]] = {
    "gzip": lambda: zlib.decompressobj(wbits=31),
    "xz": lzma.LZMADecompressor,
    "bzip2": bz2.BZ2Decompressor,
}
NATIVE_MAGIC = b"MDCAP\r\n\x1a"  # binary: its CR bytes are data, never line endings


def compression(prefix: bytes) -> str | None:
    for magic, name in _MAGIC:
        if prefix.startswith(magic):
            return name
    return None


def _decompress(src: BinaryIO, kind: str) -> Iterator[bytes]:
    """The decompressed bytes of ``src`` in pieces of at most BLOCK (a bomb never fills
    memory), across concatenated streams (``cat a.gz b.gz``); EOFError at the end if the
    last stream is cut off, after everything it held has been yielded."""
    d = _DECOMPRESSORS[kind]()
    buf = b""
    while True:
        if not buf:
            buf = src.read(BLOCK)
            if not buf:
                if not d.eof:
                    raise EOFError("the compressed stream ends without its end marker")
                return
        if kind == "gzip":
            out = d.decompress(buf, BLOCK)
            buf = d.unconsumed_tail
        else:
            out = d.decompress(buf, BLOCK)
            buf = b""
            while not d.eof and not d.needs_input:
                yield out
                out = d.decompress(b"", BLOCK)
        yield out
        if d.eof:
            # What follows the stream's end: unused_data holds it all (zlib's
            # unconsumed_tail then holds the same bytes again: both, the next gzip member
            # was read twice, a report counted twice, once a member inflated past BLOCK).
            rest = d.unused_data
            if not rest.strip(b"\0"):  # trailing zero padding (tape, dd) is not a stream
                buf = src.read(BLOCK)
                if not buf.strip(b"\0"):
                    return
            else:
                buf = rest
            d = _DECOMPRESSORS[kind]()


def plain_copy(path: str) -> tuple[str | None, str | None]:
    """(path of a plain temporary copy of ``path`` or None if it is plain already, a
    warning or None).  The caller owns the copy and removes it (``discard``).

    A compressed stream cut off at its end (a recording piped into gzip when the robot
    lost power) keeps what it held, with a warning, as an uncompressed torn file would."""
    with open_regular(path) as f:
        prefix = f.read(8)
    kind = compression(prefix)
    if kind is None and (prefix.startswith(NATIVE_MAGIC) or not _needs_text_repair(path)):
        return None, None
    with open_regular(path) as src:
        pieces = _decompress(src, kind) if kind else iter(lambda: src.read(BLOCK), b"")
        limit = MAX_PLAIN_BYTES
        if kind:
            limit = min(limit, max(PLAIN_FLOOR, MAX_PLAIN_RATIO * os.fstat(src.fileno()).st_size))
        return _copy(path, pieces, compressed=kind, limit=limit)


def discard(copy: str | None) -> None:
    if copy:
        try:
            os.unlink(copy)
        except OSError:
            pass


def _needs_text_repair(path: str) -> bool:
    """A BOM at the start, or a CR anywhere (memchr speed: a cheap pass over the file)."""
    with open_regular(path) as f:
        first = True
        while block := f.read(BLOCK):
            if first and block.startswith(BOM):
                return True
            first = False
            if b"\r" in block:
                return True
    return False


def _copy(
    path: str, pieces: Iterator[bytes], compressed: str | None, limit: int = MAX_PLAIN_BYTES
) -> tuple[str, str | None]:
    fd, tmp = tempfile.mkstemp(prefix="mousedom-capture-", suffix=".plain")
    total = 0
    warning = None
    try:
        with os.fdopen(fd, "wb") as out:
            first = _next(pieces)
            text = not first.startswith(NATIVE_MAGIC)
            if first.startswith(BOM):
                first = first[len(BOM) :]
            held = b""  # a CR at the end of a block may be the first half of a CRLF
            block = first
            while block:
                if total + len(block) > limit:
                    raise CaptureError(_too_big(path, total + len(block), limit, compressed))
                total += len(block)
                if text:
                    block = held + block
                    held = b""
                    if block.endswith(b"\r"):
                        block, held = block[:-1], b"\r"
                    block = block.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
                out.write(block)
                try:
                    block = _next(pieces)
                except EOFError:
                    warning = (
                        f"{path}: the {compressed} stream is cut off after {total} bytes "
                        "(truncated recording); what it held is kept"
                    )
                    block = b""
            out.write(held.replace(b"\r", b"\n"))
    except (EOFError, OSError, lzma.LZMAError, zlib.error) as e:
        discard(tmp)
        what = f"{compressed} data" if compressed else "file"
        if isinstance(e, OSError) and e.errno is not None and not compressed:
            raise CaptureError(f"{path}: cannot read: {e.strerror}") from None
        if isinstance(e, OSError) and e.errno is not None:
            raise CaptureError(f"{path}: cannot make a plain copy: {e.strerror}") from None
        raise CaptureError(
            f"{path}: byte offset {total} of the decompressed data: the {what} is cut off "
            f"or corrupt ({e})"
        ) from None
    except BaseException:
        discard(tmp)
        raise
    return tmp, warning


def _too_big(path: str, offset: int, limit: int, compressed: str | None) -> str:
    if compressed and limit < MAX_PLAIN_BYTES:
        why = (f"inflates past {limit} bytes, more than {MAX_PLAIN_RATIO} times its "
               f"compressed size: a decompression bomb, not a capture")  # fmt: skip
    else:
        why = f"is more than {limit >> 30} GiB; not a capture (or split it)"
    return (
        f"{path}: byte offset {offset} of the decompressed data: the {compressed or 'file'} {why}"
    )


def _next(pieces: Iterator[bytes]) -> bytes:
    """The next non-empty piece, or b"" at the end."""
    for piece in pieces:
        if piece:
            return piece
    return b""
