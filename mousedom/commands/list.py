"""``mousedom list``: the input devices that can serve as mice, and how to name them."""

from __future__ import annotations

import argparse
import json
import sys

from mousedom.discovery import DeviceInfo, Scan, SystemPaths, join_group_hint, scan


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "list",
        help="list input devices with REL_X and REL_Y (candidate mice)",
        description="List every evdev device with REL_X and REL_Y: node, name, phys, uniq, "
        "vendor:product, /dev/input/by-id and by-path links, MOUSE_DPI from udev, and a "
        "config rule that names it.",
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument(
        "--root",
        metavar="DIR",
        help="read DIR/dev/input, DIR/sys/class/input and DIR/run/udev/data instead of "
        "the real ones (containers, tests)",
    )
    p.set_defaults(func=run)


def suggested_rule(dev: DeviceInfo) -> str:
    """A config rule for this device: by-path is stable per port, even for twin mice."""
    if dev.by_path:
        return f"evdev: {{path: {dev.by_path[0]}}}"
    if dev.phys:
        return f"evdev: {{name: {json.dumps(dev.name)}, phys: {json.dumps(dev.phys)}}}"
    if dev.uniq:
        return (
            f"evdev: {{vendor: {dev.vendor:#06x}, product: {dev.product:#06x}, uniq: {dev.uniq}}}"
        )
    return f"evdev: {{path: {dev.node}}}"


def _text(result: Scan) -> str:
    where = result.paths.dev_input
    if not result.present:
        return (
            f"no input devices: {where} does not exist on this machine "
            "(in a container, pass the mice through, e.g. --device /dev/input/eventN)\n"
        )
    if not result.devices:
        return f"no devices with REL_X and REL_Y among {result.nodes} input devices in {where}\n"
    lines = []
    locked = [d for d in result.devices if not d.readable]
    for d in result.devices:
        lines.append(f"{d.node}  {d.name or '(unknown: cannot open)'}")
        if d.name:
            lines.append(f"  id       {d.bus} {d.vendor:04x}:{d.product:04x}")
            lines.append(f"  phys     {d.phys or '-'}")
            lines.append(f"  uniq     {d.uniq or '-'}")
        for link in d.by_id:
            lines.append(f"  by-id    {link}")
        for link in d.by_path:
            lines.append(f"  by-path  {link}")
        dpi = d.as_dict()["dpi"]
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


def run(args: argparse.Namespace) -> int:
    paths = SystemPaths.under(args.root) if args.root else SystemPaths()
    result = scan(paths)
    if args.json:
        doc = {
            "input_dir": paths.dev_input,
            "present": result.present,
            "nodes": result.nodes,
            "devices": [d.as_dict() for d in result.devices],
        }
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
    else:
        sys.stdout.write(_text(result))
    return 0
