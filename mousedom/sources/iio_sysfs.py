"""IIO devices in sysfs: finding the configured one, and its attributes read and written.

The I/O half of the gyro source's set-up (``mousedom.sources.iio`` runs the data plane):
every attribute is read as a regular file of at most a page, and every write is logged with
the value it replaced (``Attributes``), so that closing puts the device back as it was.
Every refusal is a ``SourceUnavailable`` naming the path of the attribute.  All paths live
under ``IioPaths.root``, so tests describe a machine as a directory tree (tests/iio_fakes.py).
"""

from __future__ import annotations

import math
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

from mousedom import saferead
from mousedom.config import GyroConfig
from mousedom.sources.base import SourceUnavailable
from mousedom.sources.iio_layout import TIMESTAMP

MAX_ATTR = 4096  # a sysfs attribute is one page at most
UDEV_HINT = "install the udev rule (udev/72-mousedom.rules, docs/gyro.md)"


@dataclass(frozen=True)
class IioPaths:
    """Where the kernel publishes IIO devices; a test points ``root`` into a tmp dir."""

    root: str = "/"

    @classmethod
    def under(cls, root: str) -> IioPaths:
        return cls(str(root))

    @property
    def sys_iio(self) -> Path:
        return Path(self.root) / "sys" / "bus" / "iio" / "devices"

    @property
    def dev(self) -> Path:
        return Path(self.root) / "dev"

    def rooted(self, path: str) -> str:
        """A path of the real machine (/sys/..., /dev/...) inside ``root``."""
        if self.root == "/" or path.startswith(self.root) or not os.path.isabs(path):
            return path
        return str(Path(self.root) / path.lstrip("/"))


@dataclass(frozen=True)
class IioDevice:
    """One IIO device: its sysfs directory, its character device, its ``name``."""

    sysdir: Path
    node: Path
    name: str

    def label(self) -> str:
        return f"{self.sysdir.name} {self.name!r}"


def read_text(path: Path) -> str:
    """A sysfs attribute: regular files only (a FIFO in a tree must not block a read)."""
    return saferead.read_bytes(path, MAX_ATTR)[:MAX_ATTR].decode("utf-8", "replace").strip()


def write_attr(path: Path, value: str, who: str) -> None:
    """Write a sysfs attribute; SourceUnavailable naming it (and the rule) when refused."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_TRUNC | os.O_NONBLOCK | os.O_CLOEXEC)
    except PermissionError:
        raise SourceUnavailable(
            f"{who}: {path}: permission denied writing {value!r}: {UDEV_HINT}"
        ) from None
    except OSError as e:
        raise SourceUnavailable(f"{who}: {path}: cannot write {value!r}: {e.strerror}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise SourceUnavailable(f"{who}: {path}: not an attribute (not a regular file)")
        os.write(fd, f"{value}\n".encode())
    except OSError as e:
        raise SourceUnavailable(f"{who}: {path}: cannot write {value!r}: {e.strerror}") from None
    finally:
        os.close(fd)


@dataclass
class Attributes:
    """Reads and writes attributes for ``who``; remembers what each write replaced."""

    who: str
    undo: list[tuple[Path, str]] = field(default_factory=list)  # (attribute, old value)

    def text(self, path: Path) -> str:
        try:
            return read_text(path)
        except OSError as e:
            raise SourceUnavailable(f"{self.who}: {path}: {e.strerror or e}") from None

    def number(self, path: Path) -> float:
        text = self.text(path)
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise SourceUnavailable(f"{self.who}: {path}: {text[:40]!r} is not a number")
        return value

    def set(self, path: Path, value: str) -> None:
        """Write an attribute unless it holds ``value``; ``restore`` puts the old back."""
        old = self.text(path)
        if old == value:
            return
        write_attr(path, value, self.who)
        self.undo.append((path, old))

    def restore(self) -> None:
        """Every written attribute back to what it held, newest first (so buffer/enable
        goes back to 0 before the scan elements change); failures are ignored: the
        device, or the tree with it, may be gone."""
        for path, old in reversed(self.undo):
            try:
                write_attr(path, old, self.who)
            except SourceUnavailable:
                pass
        self.undo = []


def list_devices(paths: IioPaths) -> list[IioDevice]:
    """Every ``iio:deviceN`` under the paths' sysfs (triggers are ``triggerN``: not here)."""
    try:
        entries = [p for p in paths.sys_iio.iterdir() if p.name.startswith("iio:device")]
    except OSError:
        return []

    def number(p: Path) -> int:
        tail = p.name[len("iio:device") :]
        return int(tail) if tail.isdigit() else 1 << 30

    out = []
    for p in sorted(entries, key=number):
        try:
            name = read_text(p / "name")
        except OSError:
            name = ""
        out.append(IioDevice(p, paths.dev / p.name, name))
    return out


def find_device(cfg: GyroConfig, paths: IioPaths, who: str) -> IioDevice:
    """The one device ``cfg`` names (by path, else by name; both must fit when given)."""
    devices = list_devices(paths)
    seen = "; ".join(d.label() for d in devices) or "none"
    if cfg.path:
        real = Path(os.path.realpath(paths.rooted(cfg.path)))
        found = [d for d in devices if d.sysdir.name == real.name]
        if not found:
            raise SourceUnavailable(f"{who}: {cfg.path}: no such IIO device (IIO devices: {seen})")
    else:
        found = [d for d in devices if d.name == cfg.name]
        if len(found) > 1:
            listing = "; ".join(d.label() for d in found)
            raise SourceUnavailable(
                f"{who}: {len(found)} IIO devices are named {cfg.name!r}: {listing}. "
                "Give gyro.path instead (docs/gyro.md)"
            )
        if not found:
            raise SourceUnavailable(
                f"{who}: no IIO device is named {cfg.name!r} (IIO devices: {seen})"
            )
    dev = found[0]
    if cfg.name is not None and dev.name != cfg.name:
        raise SourceUnavailable(f"{who}: {dev.sysdir / 'name'}: {dev.name!r}, not {cfg.name!r}")
    return dev


def calibration(attrs: Attributes, dev: IioDevice, axis: str) -> tuple[float, float]:
    """(scale in rad/s per LSB, offset in LSB) of the axis: its own attribute first, then
    the shared one; no offset attribute means 0."""
    ch, shared = f"in_anglvel_{axis}", "in_anglvel"
    scale_at = first(dev.sysdir, (f"{ch}_scale", f"{shared}_scale"))
    if scale_at is None:
        raise SourceUnavailable(
            f"{attrs.who}: {dev.sysdir}: neither {ch}_scale nor {shared}_scale: "
            f"not a gyro, or no {axis} axis"
        )
    scale = attrs.number(scale_at)
    if scale == 0:
        raise SourceUnavailable(f"{attrs.who}: {scale_at}: a scale of 0")
    offset_at = first(dev.sysdir, (f"{ch}_offset", f"{shared}_offset"))
    return scale, attrs.number(offset_at) if offset_at is not None else 0.0


def no_buffer(attrs: Attributes, dev: IioDevice, channel: str) -> str | None:
    """Why the buffer cannot be used for ``channel`` (the polled fallback is), or None."""
    d = dev.sysdir
    scan = scan_dir(d, channel)
    if scan is None:
        return f"no scan_elements/{channel}_en (the driver has no buffer)"
    if buffer_dir(d) is None:
        return f"no {d / 'buffer' / 'enable'}"
    if not (scan / f"{TIMESTAMP}_en").exists():
        return f"no {scan / (TIMESTAMP + '_en')}: records would carry no time"
    if not (d / "current_timestamp_clock").exists():
        return (
            f"no {d / 'current_timestamp_clock'} (kernels before 4.5 stamp records "
            "on CLOCK_REALTIME)"
        )
    trigger = d / "trigger" / "current_trigger"
    if trigger.exists() and not attrs.text(trigger):
        return f"no trigger ({trigger} is empty)"
    if not dev.node.exists():
        return f"no {dev.node}"
    return None


def first(directory: Path, names: tuple[str, ...]) -> Path | None:
    for name in names:
        if (directory / name).exists():
            return directory / name
    return None


def scan_dir(sysdir: Path, channel: str) -> Path | None:
    """``scan_elements/`` (and since 5.11 the same in ``buffer0/``) holding the channel."""
    for name in ("scan_elements", "buffer0"):
        if (sysdir / name / f"{channel}_en").exists():
            return sysdir / name
    return None


def buffer_dir(sysdir: Path) -> Path | None:
    for name in ("buffer", "buffer0"):
        if (sysdir / name / "enable").exists():
            return sysdir / name
    return None


def int_or(text: str, default: int) -> int:
    """A small non-negative integer attribute, or ``default`` for anything else."""
    return int(text) if text.isdigit() and len(text) < 12 else default
