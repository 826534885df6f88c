"""Opening a capture: which of the three formats a file holds, and its reader.

``sniff`` reads the first bytes; ``open_capture`` makes a plain copy of a compressed file
or one with odd line endings (see ``capture.plain``) and hands it to the right reader.
"""

from __future__ import annotations

import os
import stat
import weakref

from mousedom.capture.base import Capture, CaptureError
from mousedom.capture.evemu import EvemuCapture, companion
from mousedom.capture.libinput import LibinputCapture, looks_like_libinput
from mousedom.capture.native import NativeCapture, is_native
from mousedom.capture.plain import BOM, compression, discard, plain_copy
from mousedom.saferead import kind_of, open_regular


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
