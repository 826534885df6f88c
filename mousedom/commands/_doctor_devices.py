"""``mousedom doctor``, the devices: the input directory, and for each mouse of the config
the device it is (evdev rule, FIFO, serial port, replay file) or why there is none."""

from __future__ import annotations

import grp
import os
from typing import TYPE_CHECKING

from mousedom import invocation
from mousedom.commands._doctor_base import Check, Lines
from mousedom.config import Config

if TYPE_CHECKING:
    from mousedom.sources.discovery import Scan


def _group_of(path: str) -> str:
    try:
        gid = os.stat(path).st_gid
    except OSError:
        return "?"
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def _join(group: str) -> str:
    return f"join group '{group}' (sudo usermod -aG {group} $USER, then log in again)"


def check_devices(cfg: Config | None, root: str | None) -> list[Check]:
    """The input directory, then each mouse: the device it is, or why there is none."""
    from mousedom.commands.list import config_gyro, config_matches
    from mousedom.sources.discovery import is_stream, paths_for_root, scan

    lines = Lines("devices")
    paths = paths_for_root(root)
    result = scan(paths)
    mice = cfg.mice if cfg else ()
    streams = {m.name for m in mice if m.evdev and m.evdev.path and is_stream(m.evdev.path)}
    evdev = [m.name for m in mice if m.evdev and m.name not in streams]
    _check_input_dir(lines, result, paths.dev_input, cfg is not None, evdev)
    if cfg is None:
        return lines
    matches: dict[str, dict[str, str | None]] = {}
    if result.present and evdev:
        matches = config_matches(cfg, result)
    ports: dict[str, str] = {}
    for m in mice:
        if m.evdev is not None and m.name in streams:
            lines.ok(f"{m.name} -> {m.evdev.path} (a FIFO: a stream of input events)")
        elif m.evdev:
            if not result.present:
                continue  # said once above
            _check_evdev(lines, m.name, matches.get(m.name, {}), result)
        elif m.serial:
            _check_serial(lines, m.name, m.serial.port, ports)
        elif m.replay:
            if os.path.isfile(m.replay):
                lines.ok(f"{m.name} -> replay {m.replay}")
            else:
                lines.fail(f"{m.name}: replay {m.replay}: capture file not found",
                           "record one (`mousedom record`) or fix the path (relative to the "
                           "config)")  # fmt: skip
    gyro = config_gyro(cfg.gyro, root)
    if gyro is not None:
        _check_gyro(lines, gyro)
    return lines


def _check_gyro(lines: Lines, gyro: dict[str, str | None]) -> None:
    """The gyro (``gyro``, from ``list.config_gyro``): the IIO device its section names as
    the daemon finds it, or the capture or ROS 2 topic it stands in for one."""
    if gyro["error"]:
        hint = ("record one (`mousedom record`) or fix the path" if gyro["note"]
                else "`mousedom list` shows the IIO gyros and the gyro: line for each")  # fmt: skip
        lines.fail(gyro["error"], hint)
    elif gyro["note"]:
        lines.ok(f"gyro -> {gyro['note']}")
    else:
        lines.ok(f"gyro -> {gyro['sysfs']} ({gyro['name'] or 'no name'})")


def _check_input_dir(
    lines: Lines, result: Scan, where: str, configured: bool, evdev: list[str]
) -> None:
    """The input directory: there (or why it need not be), its mice, those closed to this
    user (said per mouse when a config names them)."""
    if not result.present:
        container = (
            "is this a container? pass the devices through (docker/podman run --device "
            "/dev/input/eventN), or replay captures (`mousedom replay`, "
            f"`{invocation.command('run', '--demo')}`)"
        )
        if evdev:
            lines.fail(f"no {where}: this machine has no input devices, so the evdev mice "
                       f"({', '.join(evdev)}) cannot be found", container)  # fmt: skip
        elif not configured:
            lines.warn(f"no {where} on this machine", container)
        else:
            # (an evdev mouse read from a FIFO or a file is one too: say what is not needed)
            lines.ok(f"no {where} on this machine (not needed: no mouse of this config is read "
                     "from an input node)")  # fmt: skip
        return
    if result.error:
        lines.fail(result.error, "the input directory is normally readable by everyone "
                   "(its nodes by group input): check its permissions")  # fmt: skip
        return
    locked = [d for d in result.devices if not d.readable]
    n = len(result.devices)
    s = "s" if result.nodes != 1 else ""
    msg = f"{where}: {result.nodes} input node{s}, {n} with REL_X and REL_Y"
    if locked:
        groups = sorted({d.group or "input" for d in locked})
        msg += f"; {len(locked)} closed to this user (group {', '.join(groups)})"
        if configured:  # each evdev mouse's line says whether it is one of those
            lines.ok(msg)
        else:
            lines.warn(msg, f"{_join(groups[0])}, or install udev/72-mousedom.rules")
    elif n == 0 and (not configured or evdev):
        lines.warn(msg + ": no mouse plugged in", "plug the mice in (`mousedom list`)")
    else:
        lines.ok(msg)


def _check_evdev(lines: Lines, name: str, r: dict[str, str | None], result: Scan) -> None:
    """An evdev mouse: the node its rule matches (``r``, from ``list.config_matches``), and
    whether this user may read it."""
    from mousedom.sources.discovery import join_group_hint

    by_node = {d.node: d for d in result.devices}
    node = r.get("node")
    dev = by_node.get(node) if node else None
    label = f"{node} {dev.name!r}" if dev and dev.name else str(node)
    if r.get("error"):
        lines.fail(f"{name}: {r['error']}", "plug it in, or change its rule: `mousedom "
                   "list` shows each device and a rule that names it")  # fmt: skip
    elif dev is not None and not dev.readable:
        lines.fail(f"{name} -> {label}: closed to this user", join_group_hint(dev),
                   mouse=name, node=node, group=dev.group)  # fmt: skip
    else:
        lines.ok(f"{name} -> {label}", mouse=name, node=node)


def _check_serial(lines: Lines, name: str, port: str, ports: dict[str, str]) -> None:
    """An ADNS-3080 board's serial port: there, and open to this user.  Not opened here:
    opening toggles DTR, which resets many boards."""
    if "://" in port:  # a pyserial URL (socket://, loop://): nothing to look at here
        lines.ok(f"{name} -> serial {port} (a pyserial URL)")
        return
    real = os.path.realpath(port)
    if real in ports:
        lines.fail(f"{name}: serial {port} is {ports[real]}'s port too",
                   "one board per port: give each mouse its own")  # fmt: skip
        return
    ports[real] = name
    if not os.path.exists(port):
        lines.fail(f"{name}: serial port {port} does not exist",
                   "plug the ADNS-3080 board in (`ls /dev/serial/by-id/` names it); in a "
                   "container, pass it through (--device)")  # fmt: skip
    elif not os.access(port, os.R_OK | os.W_OK):
        group = _group_of(port)
        lines.fail(f"{name}: serial port {port}: permission denied", _join(group),
                   mouse=name, port=port, group=group)  # fmt: skip
    else:
        lines.ok(f"{name} -> serial {port}")
