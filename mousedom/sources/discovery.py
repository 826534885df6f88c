"""Find the input devices that can be mice, and pick the one a config entry means.

Two halves:

* ``scan()`` (I/O): every ``/dev/input/event*`` node with both REL_X and REL_Y, described
  from sysfs (``/sys/class/input/eventN/device``: name, phys, uniq, id, capabilities),
  which needs no permission on the node, plus its ``/dev/input/by-id`` and ``by-path``
  links, MOUSE_DPI from the udev database (``/run/udev/data/c13:<minor>``), and whether
  we may open the node (if not: the node's group, which the user should join).  Without
  sysfs it falls back to opening each node with python-evdev.  All roots are parameters,
  so tests describe a machine as a directory tree.
* ``match_device()`` (pure): which of those descriptions a config ``EvdevMatch`` names.
  Every field the rule gives must match; no match or more than one is an error that
  lists the candidates.
"""

from __future__ import annotations

import grp
import os
import stat
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from mousedom.config import EvdevMatch
from mousedom.errors import UserError
from mousedom.saferead import read_bytes

BUS_NAMES = {
    0x01: "pci",
    0x03: "usb",
    0x05: "bluetooth",
    0x06: "virtual",
    0x11: "i8042",
    0x18: "i2c",
    0x19: "host",
    0x1C: "spi",
}
REL_X_BIT, REL_Y_BIT = 0, 1


@dataclass(frozen=True)
class SystemPaths:
    """Where the kernel and udev publish things; a test points these into a tmp dir."""

    dev_input: str = "/dev/input"
    sys_input: str = "/sys/class/input"
    udev_data: str = "/run/udev/data"

    def rooted(self, path: str) -> str:
        """A config's node path as found here: under ``dev_input`` where that is another
        tree's (``--root``), so a rule naming /dev/input/by-path/... finds its link
        there; any other path as it is."""
        default = SystemPaths.dev_input
        if self.dev_input != default and (path == default or path.startswith(default + "/")):
            return self.dev_input + path[len(default) :]
        return path

    @classmethod
    def under(cls, root: str) -> SystemPaths:
        r = Path(root)
        return cls(
            str(r / "dev" / "input"), str(r / "sys" / "class" / "input"), str(r / "run/udev/data")
        )


@dataclass(frozen=True)
class DeviceInfo:
    """One input device, as data: what ``list`` prints and what a rule matches against."""

    node: str
    name: str = ""
    phys: str = ""
    uniq: str = ""
    bustype: int = 0
    vendor: int = 0
    product: int = 0
    version: int = 0
    rel_x: bool = False
    rel_y: bool = False
    by_id: tuple[str, ...] = ()
    by_path: tuple[str, ...] = ()
    mouse_dpi: str | None = None  # raw udev/hwdb MOUSE_DPI, e.g. "400 *800 1600@125"
    readable: bool = True
    group: str | None = None  # group owning the node (join it when not readable)

    @property
    def is_pointer(self) -> bool:
        return self.rel_x and self.rel_y

    @property
    def bus(self) -> str:
        return BUS_NAMES.get(self.bustype, f"bus{self.bustype:#x}")

    def label(self) -> str:
        """One line that tells candidates apart in an error message."""
        parts = [self.node, repr(self.name), f"{self.vendor:04x}:{self.product:04x}"]
        if self.phys:
            parts.append(f"phys={self.phys}")
        if self.uniq:
            parts.append(f"uniq={self.uniq}")
        return " ".join(parts)

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["by_id"], d["by_path"] = list(self.by_id), list(self.by_path)
        d["bus"] = self.bus
        d["id"] = f"{self.vendor:04x}:{self.product:04x}"
        d["dpi"] = parse_mouse_dpi(self.mouse_dpi)
        return d


def paths_for_root(root: str | None) -> SystemPaths:
    """The ``--root DIR`` option of ``list`` and ``record``: DIR must exist.

    A mistyped root would otherwise look like a machine without input devices, which
    ``list`` reports as fine (exit 0): a silent wrong answer.
    """
    if root is None:
        return SystemPaths()
    if not os.path.isdir(root):
        why = "not a directory" if os.path.exists(root) else "no such directory"
        raise UserError(f"--root {root}: {why}")
    return SystemPaths.under(root)


@dataclass
class Scan:
    """What ``scan()`` found: pointer devices and how many input nodes there were."""

    paths: SystemPaths
    present: bool  # the input directory exists at all
    nodes: int = 0  # event nodes seen, pointers or not
    # why the input directory could not be listed (it is there, closed to this user)
    error: str | None = None
    devices: list[DeviceInfo] = field(default_factory=list)


# --------------------------------------------------------------------------- pure parsing


def parse_udev_db(text: str) -> dict[str, str]:
    """Properties (``E:KEY=VALUE`` lines) of one udev database file."""
    props = {}
    for line in text.splitlines():
        if line.startswith("E:") and "=" in line:
            key, _, value = line[2:].partition("=")
            props[key] = value
    return props


def parse_mouse_dpi(value: str | None) -> dict[str, Any] | None:
    """hwdb MOUSE_DPI (``"400 *800 1600@125"``, ``"1000@500"``) -> default dpi and rate.

    The default is the entry marked ``*``, else the only entry.  Returns None for
    a missing or unreadable value (hwdb entries are free text written by people).
    """
    if not value:
        return None
    entries = value.split()
    chosen = [e for e in entries if e.startswith("*")] or (entries if len(entries) == 1 else [])
    if not chosen:
        return {"raw": value, "dpi": None, "hz": None, "choices": len(entries)}
    dpi_s, _, hz_s = chosen[0].lstrip("*").partition("@")
    try:
        dpi = int(dpi_s)
        hz = int(hz_s) if hz_s else None
    except ValueError:
        return {"raw": value, "dpi": None, "hz": None, "choices": len(entries)}
    return {"raw": value, "dpi": dpi, "hz": hz, "choices": len(entries)}


def parse_bitmask(text: str) -> int:
    """sysfs capability masks: hex words, most significant first, each one a long."""
    value = 0
    words = text.split()
    for word in words:
        value = (value << 64) | int(word, 16)
    return value


# --------------------------------------------------------------------------- pure matching


def rule_text(rule: EvdevMatch) -> str:
    parts = []
    for key in ("path", "name", "phys", "uniq"):
        v = getattr(rule, key)
        if v is not None:
            parts.append(f"{key}={v!r}")
    if rule.vendor is not None:
        parts.append(f"vendor={rule.vendor:#06x}")
    if rule.product is not None:
        parts.append(f"product={rule.product:#06x}")
    return ", ".join(parts) or "(empty rule)"


def matches(rule: EvdevMatch, dev: DeviceInfo, resolved_path: str | None = None) -> bool:
    """True when every field the rule gives matches ``dev``.

    ``path`` matches the node itself or any of its by-id/by-path links, or the node that
    ``resolved_path`` (the rule's path with its symlinks followed) names.
    """
    if rule.path is not None:
        names = {dev.node, *dev.by_id, *dev.by_path}
        # (the node as its real path too: under a relative or linked --root the rule's
        # resolved path is absolute and real, the scanned node is neither)
        if (rule.path not in names and resolved_path not in names
                and resolved_path != os.path.realpath(dev.node)):  # fmt: skip
            return False
    if rule.name is not None and rule.name != dev.name:
        return False
    if rule.phys is not None and rule.phys != dev.phys:
        return False
    if rule.uniq is not None and rule.uniq != dev.uniq:
        return False
    if rule.vendor is not None and rule.vendor != dev.vendor:
        return False
    if rule.product is not None and rule.product != dev.product:
        return False
    return True


class NoDevice(UserError):
    """No pointer device matches the rule (it may be unplugged: retry later)."""


class AmbiguousDevice(UserError):
    """More than one device matches the rule: the config must say more."""


def match_device(
    rule: EvdevMatch, devices: list[DeviceInfo], *, resolved_path: str | None = None, who: str = ""
) -> DeviceInfo:
    """The one pointer device ``rule`` names; NoDevice or AmbiguousDevice otherwise."""
    who = f"{who}: " if who else ""
    pointers = [d for d in devices if d.is_pointer]
    found = [d for d in pointers if matches(rule, d, resolved_path)]
    if len(found) == 1:
        return found[0]
    if not found:
        seen = "; ".join(d.label() for d in pointers) or "none"
        raise NoDevice(f"{who}no input device matches {rule_text(rule)} (pointer devices: {seen})")
    listing = "; ".join(d.label() for d in found)
    raise AmbiguousDevice(
        f"{who}{len(found)} devices match {rule_text(rule)}: {listing}. "
        "Add a by-path link, phys or uniq to the rule (see `mousedom list`)"
    )


def locate(
    rule: EvdevMatch, devices: list[DeviceInfo], paths: SystemPaths, who: str = ""
) -> DeviceInfo:
    """``match_device`` on the machine ``paths`` describe: a rule's /dev/input path is that
    tree's (``--root``), followed through its links.  One rule for ``list --config`` and
    the sources (``record --root`` looked for the path on this machine, where ``list``
    found it under the root)."""
    if rule.path:
        rule = replace(rule, path=paths.rooted(rule.path))
    resolved = os.path.realpath(rule.path) if rule.path else None
    return match_device(rule, devices, resolved_path=resolved, who=who)


def join_group_hint(dev: DeviceInfo) -> str:
    group = dev.group or "input"
    return (
        f"permission denied on {dev.node}: join group '{group}' "
        f"(sudo usermod -aG {group} $USER, then log in again) or install the udev rule"
    )


# --------------------------------------------------------------------------- I/O: the scan


def _read(path: Path) -> str:
    """A sysfs attribute (a page at most): regular files only, so that a scan of a tree
    given with --root never blocks on a FIFO nor reads a device without end."""
    try:
        return read_bytes(path, 4096)[:4096].decode("utf-8", "replace").strip()
    except OSError:
        return ""


def _hex(path: Path) -> int:
    try:
        return int(_read(path) or "0", 16)
    except ValueError:
        return 0


# A node's links: by-id's and by-path's, each (target's real path -> its links, sorted)
Links = tuple[dict[str, tuple[str, ...]], dict[str, tuple[str, ...]]]


def _link_index(directory: Path) -> dict[str, tuple[str, ...]]:
    """The links in ``directory`` by the real path they lead to, each resolved once (a
    scan resolved every link for every node: 73 s for 1,000 nodes); empty where it cannot
    be listed (a by-path folder closed to this user: the devices are still described)."""
    try:
        if not directory.is_dir():
            return {}
        links = sorted(directory.iterdir())
    except OSError:
        return {}
    out: dict[str, list[str]] = {}
    for link in links:
        try:
            out.setdefault(os.path.realpath(link), []).append(str(link))
        except OSError:
            continue
    return {target: tuple(found) for target, found in out.items()}


def _links(paths: SystemPaths) -> Links:
    base = Path(paths.dev_input)
    return _link_index(base / "by-id"), _link_index(base / "by-path")


def _node_access(node: str) -> tuple[bool, str | None] | None:
    """(readable by this user, the node's group), or None where the node is gone (unplugged
    between the listing and now, or a link to nothing): it was said to be closed to this
    user, with advice to join a group, even to root."""
    try:
        st = os.stat(node)
    except FileNotFoundError:
        return None
    except OSError:
        return False, None
    try:
        group = grp.getgrgid(st.st_gid).gr_name
    except KeyError:
        group = str(st.st_gid)
    return os.access(node, os.R_OK), group


def _describe_from_sysfs(
    paths: SystemPaths, event: str, node: str, links: Links
) -> DeviceInfo | None:
    base = Path(paths.sys_input) / event / "device"
    try:
        if not base.is_dir():
            return None
    except OSError:  # sysfs closed to this user: described by opening the node instead
        return None
    try:
        rel = parse_bitmask(_read(base / "capabilities" / "rel") or "0")
    except ValueError:  # (the kernel writes hex; a tree given with --root may not)
        rel = 0
    udev = {}
    major_minor = _read(Path(paths.sys_input) / event / "dev")  # "13:67"
    if major_minor:
        udev = parse_udev_db(_read(Path(paths.udev_data) / f"c{major_minor}"))
    access = _node_access(node)
    if access is None:
        return None  # gone: nothing to describe
    readable, group = access
    real = os.path.realpath(node)
    return DeviceInfo(
        node=node,
        name=_read(base / "name"),
        phys=_read(base / "phys"),
        uniq=_read(base / "uniq"),
        bustype=_hex(base / "id" / "bustype"),
        vendor=_hex(base / "id" / "vendor"),
        product=_hex(base / "id" / "product"),
        version=_hex(base / "id" / "version"),
        rel_x=bool(rel >> REL_X_BIT & 1),
        rel_y=bool(rel >> REL_Y_BIT & 1),
        by_id=links[0].get(real, ()),
        by_path=links[1].get(real, ()),
        mouse_dpi=udev.get("MOUSE_DPI"),
        readable=readable,
        group=group,
    )


def _describe_with_evdev(paths: SystemPaths, node: str, links: Links) -> DeviceInfo | None:
    """Fallback without sysfs: open the node with python-evdev (needs permission)."""
    import evdev  # late: only this fallback and the live source need the C extension

    access = _node_access(node)
    if access is None:
        return None  # gone
    readable, group = access
    real = os.path.realpath(node)
    by_id, by_path = links[0].get(real, ()), links[1].get(real, ())
    try:
        dev = evdev.InputDevice(node)
    except PermissionError:
        # Without sysfs nor permission we cannot tell a mouse from a keyboard: list it
        # anyway so that the user learns which group to join.
        return DeviceInfo(node=node, readable=False, group=group, by_id=by_id, by_path=by_path)
    except OSError:
        return None
    try:
        rel = dev.capabilities(absinfo=False).get(evdev.ecodes.EV_REL, [])
        return DeviceInfo(
            node=node,
            name=dev.name,
            phys=dev.phys or "",
            uniq=dev.uniq or "",
            bustype=dev.info.bustype,
            vendor=dev.info.vendor,
            product=dev.info.product,
            version=dev.info.version,
            rel_x=evdev.ecodes.REL_X in rel,
            rel_y=evdev.ecodes.REL_Y in rel,
            readable=readable,
            group=group,
            by_id=by_id,
            by_path=by_path,
        )
    finally:
        dev.close()


def _event_number(name: str) -> int:
    return int(name[5:]) if name[5:].isdigit() else 1 << 30


def scan(paths: SystemPaths | None = None, *, pointers_only: bool = True) -> Scan:
    """Describe the event nodes of ``paths.dev_input`` (pointer devices only by default)."""
    paths = paths or SystemPaths()
    dev_dir = Path(paths.dev_input)
    try:
        if not dev_dir.is_dir():
            return Scan(paths, present=False)
        names = [p.name for p in dev_dir.iterdir()]
    except OSError as e:  # a directory closed to this user: its devices are unknown
        return Scan(paths, present=True, error=f"{dev_dir}: cannot list it: {e.strerror}")
    events = sorted((n for n in names if n.startswith("event")), key=_event_number)
    result = Scan(paths, present=True, nodes=len(events))
    links = _links(paths)
    for event in events:
        node = str(dev_dir / event)
        info = _describe_from_sysfs(paths, event, node, links)
        if info is None:
            info = _describe_with_evdev(paths, node, links)
        if info is None:
            continue
        # A node we could not even describe (no sysfs, no permission) is kept: the user
        # needs to hear about it.
        undescribed = not info.readable and not info.name
        if not pointers_only or info.is_pointer or undescribed:
            result.devices.append(info)
    return result


def is_stream(path: str) -> bool:
    """True for a FIFO or pipe: the test/bench hook that stands in for an event node."""
    try:
        return stat.S_ISFIFO(os.stat(path).st_mode)
    except OSError:
        return False
