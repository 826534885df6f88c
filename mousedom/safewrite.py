"""Every file the program writes goes through here: no link followed, no input clobbered.

Two kinds of writer, two rules:

- Streams (``record -o``, ``run --record``, ``replay -o``, appending to RUNS.csv) are
  written in place, because a crash must leave what was written so far.  The path is
  opened with O_NOFOLLOW and without O_TRUNC, checked (a regular file, not one of the
  inputs nor the running config, by device and inode), and only then truncated.  A symbolic
  link, dangling or not, is refused: writing through it would land wherever its maker
  chose.
- Whole files (``convert``, ``calibrate --write``, ``umbmark --write``, ``--plot``) are
  written to a fresh temporary file in the target's own folder (mkstemp: O_EXCL and an
  unpredictable name, so a planted link cannot redirect it) and renamed over the target
  when complete, so a failure half-way leaves the old file.  A target that is a symbolic
  link is refused too rather than replaced, so no writer ever changes what a link means.

Either way the refusal names the output and the reason.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from collections.abc import Callable, Iterable
from typing import IO

from mousedom.errors import UserError


def _identity(path: str) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def same_file(a: str, b: str) -> bool:
    """One file (through any link or hard link), or one path for a file not made yet."""
    ida = _identity(a)
    return (ida is not None and ida == _identity(b)) or os.path.abspath(a) == os.path.abspath(b)


def refuse_inputs(output: str, inputs: Iterable[str | None]) -> None:
    """UserError if ``output`` is (through any link) one of ``inputs``, or names it."""
    for path in inputs:
        if path and same_file(output, path):
            raise UserError(f"{output}: is the input {path}; not overwriting it")


def refuse_shared_outputs(outputs: Iterable[tuple[str, str | None]]) -> None:
    """UserError if two of one run's outputs, (option, path) each, name one file: the later
    writer would replace the earlier, which would still be reported written.  A device
    (/dev/null) may take several; None and "-" (stdout) are not files."""
    named = [(flag, path) for flag, path in outputs if path and path != "-"]
    for k, (flag, path) in enumerate(named):
        try:
            if stat.S_ISCHR(os.stat(path).st_mode):
                continue
        except OSError:
            pass
        for other_flag, other in named[:k]:
            if same_file(path, other):
                raise UserError(f"{flag} {path}: {other_flag} writes that file too; give each "
                                "output its own file")  # fmt: skip


def _is_special(st: os.stat_result) -> bool:
    """A pipe or a device: nothing there can be clobbered (/dev/stdout, /dev/null, a FIFO)."""
    return stat.S_ISFIFO(st.st_mode) or stat.S_ISCHR(st.st_mode)


def _refuse_link(path: str) -> bool:
    """UserError if ``path`` is a symbolic link to a file or to nothing; True if it is a
    link to a pipe or device (such as /dev/stdout), which may be written through."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    except OSError as e:
        raise UserError(f"{path}: cannot write: {e.strerror}") from None
    if not stat.S_ISLNK(st.st_mode):
        return False
    try:
        if _is_special(os.stat(path)):
            return True
    except OSError:
        pass  # dangling: refused below
    raise UserError(f"{path}: is a symbolic link; not writing through it (name the file itself)")


def open_stream(
    path: str, inputs: Iterable[str | None] = (), *, append: bool = False, text: bool = False
) -> IO:
    """Open ``path`` for writing in place (see the module docstring); UserError if not.

    Pipes and devices are written as they are; a regular file is truncated (or appended
    to) only once it is known to be none of ``inputs``."""
    inputs = list(inputs)
    refuse_inputs(path, inputs)
    follow = _refuse_link(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC | (0 if follow else os.O_NOFOLLOW)
    if append:
        flags |= os.O_APPEND
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as e:
        if e.errno == errno.ELOOP:  # a link planted since the check above
            raise UserError(f"{path}: is a symbolic link; not writing through it") from None
        raise UserError(f"{path}: cannot write: {e.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) and not _is_special(st):
            raise UserError(f"{path}: not a regular file, pipe or device; not writing into it")
        for other in inputs:
            if other and _identity(other) == (st.st_dev, st.st_ino):
                raise UserError(f"{path}: is the input {other}; not overwriting it")
        if not append and stat.S_ISREG(st.st_mode):
            os.ftruncate(fd, 0)
    except BaseException:
        os.close(fd)
        raise
    # (outside the try, as saferead.open_regular: the file object owns the descriptor)
    if text:
        return os.fdopen(fd, "w", newline="", encoding="utf-8")
    return os.fdopen(fd, "wb")


def replace_file(
    path: str,
    write: Callable[[str], None],
    inputs: Iterable[str | None] = (),
    *,
    make_folder: bool = False,
) -> None:
    """Write a whole file: ``write(temp_path)`` fills a fresh temporary file beside
    ``path``, which then replaces ``path`` atomically (UserError naming ``path`` if not).

    The new file keeps the mode of the one it replaces (or the umask's default), since
    mkstemp's 0600 would lock out a daemon running as another user."""
    refuse_inputs(path, inputs)
    if _refuse_link(path):
        raise UserError(f"{path}: a link to a pipe or device; give a file to write")
    folder = os.path.dirname(os.path.abspath(path))
    try:
        if make_folder:
            os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".part",
                                   dir=folder)  # fmt: skip
    except OSError as e:
        raise UserError(f"{path}: cannot write: {e.strerror}") from None
    try:
        os.fchmod(fd, _mode_for(path))
        os.close(fd)
        write(tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        _unlink(tmp)
        raise UserError(f"{path}: cannot write: {e.strerror or e}") from None
    except BaseException:
        _unlink(tmp)
        raise


def replace_bytes(
    path: str, raw: bytes, inputs: Iterable[str | None] = (), *, make_folder: bool = False
) -> None:
    """``replace_file`` with a ready-made content."""

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(raw)

    replace_file(path, write, inputs, make_folder=make_folder)


def _mode_for(path: str) -> int:
    try:
        return os.stat(path).st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass
