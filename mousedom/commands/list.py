"""``mousedom list``: the input devices that can serve as mice, and how to name them."""

from __future__ import annotations

import argparse
import json
import os
import sys

from mousedom.commands import _options as options
from mousedom.config import Config, GyroConfig, load_config
from mousedom.errors import UserError, escaped
from mousedom.sources.discovery import (
    DeviceInfo,
    Scan,
    is_stream,
    join_group_hint,
    locate,
    parse_mouse_dpi,
    paths_for_root,
    scan,
)
from mousedom.sources.iio_sysfs import IioDevice, IioPaths, list_devices


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "list",
        help="list input devices with REL_X and REL_Y (candidate mice)",
        description="List every evdev device with REL_X and REL_Y: node, name, phys, uniq, "
        "vendor:product, /dev/input/by-id and by-path links, MOUSE_DPI from udev, and a "
        "config rule that names it; and every IIO device with a gyro (in_anglvel) channel, "
        "with the gyro: section that names it.",
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument(
        "-c",
        "--config",
        metavar="RIG.yaml",
        help="also say which device each evdev mouse and the gyro of this config match; "
        "exit 1 if a rule matches none or several",
    )
    options.add_root(p)
    p.set_defaults(func=run)


def suggested_rule(dev: DeviceInfo) -> str:
    """A config rule for this device: by-path is stable per port, even for twin mice."""
    if dev.by_path:
        return f"evdev: {{path: {_quoted(dev.by_path[0])}}}"
    if dev.phys:
        return f"evdev: {{name: {_quoted(dev.name)}, phys: {_quoted(dev.phys)}}}"
    if dev.uniq:
        return (f"evdev: {{vendor: {dev.vendor:#06x}, product: {dev.product:#06x}, "
                f"uniq: {_quoted(dev.uniq)}}}")  # fmt: skip
    return f"evdev: {{path: {_quoted(dev.node)}}}"


def _quoted(text: str) -> str:
    """``text`` as a YAML double-quoted scalar that reads back as this very text: JSON's
    escapes are YAML's, written with the characters themselves (JSON's ASCII escapes of an
    emoji, a surrogate pair, are no YAML; a uniq 0123 written plain read as a number)."""
    return json.dumps(text, ensure_ascii=False)


def _text(result: Scan) -> str:
    where = result.paths.dev_input
    if not result.present:
        return (
            f"no input devices: {where} does not exist on this machine "
            "(in a container, pass the mice through, e.g. --device /dev/input/eventN)\n"
        )
    if result.error:
        return f"input devices unknown: {result.error} (run as a user who may list it)\n"
    if not result.devices:
        return f"no devices with REL_X and REL_Y among {result.nodes} input devices in {where}\n"
    lines = []
    locked = [d for d in result.devices if not d.readable]
    for d in result.devices:
        unnamed = "(no name)" if d.readable else "(unknown: cannot open)"
        lines.append(f"{d.node}  {escaped(d.name) or unnamed}")
        if d.name or d.readable:
            lines.append(f"  id       {d.bus} {d.vendor:04x}:{d.product:04x}")
            lines.append(f"  phys     {escaped(d.phys) or '-'}")
            lines.append(f"  uniq     {escaped(d.uniq) or '-'}")
        for link in d.by_id:
            lines.append(f"  by-id    {link}")
        for link in d.by_path:
            lines.append(f"  by-path  {link}")
        dpi = parse_mouse_dpi(d.mouse_dpi)
        if dpi:
            known = f"{dpi['dpi']} cpi" if dpi["dpi"] else "no default"
            if dpi["hz"]:
                known += f" at {dpi['hz']} Hz"
            lines.append(f"  MOUSE_DPI {dpi['raw']} ({known})")
        if d.readable:
            lines.append(f"  config   {suggested_rule(d)}")
        else:
            lines.append(f"  cannot open: {join_group_hint(d)}")
        lines.append("")
    n = len(result.devices)
    lines.append(f"{n} device{'s' if n != 1 else ''} with REL_X and REL_Y in {where}")
    if locked:
        groups = sorted({d.group or "input" for d in locked})
        lines.append(f"{len(locked)} cannot be opened by this user: join group {', '.join(groups)}")
    return "\n".join(lines) + "\n"


def config_matches(cfg: Config, result: Scan) -> dict[str, dict[str, str | None]]:
    """For each evdev mouse of the config: the node its rule matches, or why none."""
    out: dict[str, dict[str, str | None]] = {}
    for m in cfg.mice:
        if m.evdev is None:
            continue
        rule = m.evdev
        if rule.path and is_stream(rule.path):
            out[m.name] = {"node": rule.path, "error": None, "note": "FIFO/pipe stream"}
            continue
        try:
            dev = locate(rule, result.devices, result.paths)
            out[m.name] = {"node": dev.node, "error": None, "note": None}
        except UserError as e:
            out[m.name] = {"node": None, "error": str(e), "note": None}
    # Two rules naming one device would split its reports between two mice (or count
    # them twice): as wrong as a rule that matches nothing.
    first: dict[str, str] = {}
    for name, r in out.items():
        node = r["node"]
        if node is None:
            continue
        key = os.path.realpath(node)
        if key in first:
            r["error"] = f"matches {node}, the same device as {first[key]}"
        else:
            first[key] = name
    return out


def config_gyro(g: GyroConfig | None, root: str | None) -> dict[str, str | None] | None:
    """A config's gyro section: the IIO device its rule matches as the daemon finds it (its
    sysfs folder, node and name), or why none; the capture (which must be a file) or ROS 2
    topic it stands in for one (a note); None where the rig has no gyro.  (doctor says
    the same: one rule.)"""
    from mousedom.sources.base import SourceUnavailable
    from mousedom.sources.iio_sysfs import find_device

    if g is None:
        return None
    out: dict[str, str | None] = {"sysfs": None, "node": None, "name": None, "error": None,
                                  "note": None}  # fmt: skip
    if g.replay is not None:
        out["note"] = f"replay {g.replay}"
        if not os.path.isfile(g.replay):
            out["error"] = f"gyro: replay {g.replay}: capture file not found"
    elif g.ros2 is not None:
        out["note"] = f"ROS 2 topic {g.ros2.topic}"
    else:
        try:
            dev = find_device(g, IioPaths.under(root or "/"), "gyro")
        except SourceUnavailable as e:
            out["error"] = str(e)
        else:
            out["sysfs"], out["node"], out["name"] = str(dev.sysdir), str(dev.node), dev.name
    return out


def _config_text(
    config_path: str,
    matches: dict[str, dict[str, str | None]],
    gyro: dict[str, str | None] | None,
) -> str:
    lines = [f"{config_path}:"]
    if not matches:
        lines.append("  no evdev mice in this config")
    for name, r in matches.items():
        if r["error"]:
            lines.append(f"  {name}: {r['error']}")
        else:
            note = f" ({r['note']})" if r["note"] else ""
            lines.append(f"  {name} -> {r['node']}{note}")
    if gyro is not None:
        if gyro["error"]:
            lines.append(f"  {gyro['error']}")
        elif gyro["note"]:
            lines.append(f"  gyro: {gyro['note']}")
        else:
            lines.append(f"  gyro -> {gyro['sysfs']} ({gyro['node']})")
    return "\n".join(lines) + "\n"


def gyros(root: str | None) -> list[IioDevice]:
    """The IIO devices with a gyro channel (in_anglvel_*): the rig's candidate gyros."""
    found = list_devices(IioPaths.under(root or "/"))
    return [d for d in found if any(d.sysdir.glob("in_anglvel_*"))]


def _gyro_text(found: list[IioDevice]) -> str:
    if not found:
        return "no IIO gyro (no device with an in_anglvel channel)\n"
    lines = []
    for d in found:
        lines += [f"{d.sysdir.name}  {d.name}", f"  node     {d.node}",
                  f"  sysfs    {d.sysdir}", f"  config   gyro: {{name: {d.name}}}"]  # fmt: skip
    return "\n".join(lines) + f"\n{len(found)} IIO gyro{'s' if len(found) != 1 else ''}\n"


def run(args: argparse.Namespace) -> int:
    paths = paths_for_root(args.root)
    result = scan(paths)
    found = gyros(args.root)
    cfg = load_config(args.config) if args.config else None
    matches = config_matches(cfg, result) if cfg is not None else None
    gyro = config_gyro(cfg.gyro, args.root) if cfg is not None else None
    if args.json:
        doc = {
            "input_dir": paths.dev_input,
            "present": result.present,
            "nodes": result.nodes,
            "devices": [d.as_dict() for d in result.devices],
            "gyros": [
                {"sysfs": str(d.sysdir), "node": str(d.node), "name": d.name} for d in found
            ],  # fmt: skip
        }
        if result.error:  # (the folder is there but could not be listed: devices unknown)
            doc["error"] = result.error
        if matches is not None:
            doc["config"] = {"path": args.config, "mice": matches, "gyro": gyro}
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
    else:
        sys.stdout.write(_text(result))
        sys.stdout.write("\n" + _gyro_text(found))
        if matches is not None:
            sys.stdout.write("\n" + _config_text(args.config, matches, gyro))
    if (
        (matches and any(r["error"] for r in matches.values()))
        or (gyro is not None and gyro["error"])
        or result.error
    ):
        return 1
    return 0
