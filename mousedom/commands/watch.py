"""``mousedom watch``: the live pose, rates and sensor health of a running daemon."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any, TextIO

from mousedom.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "watch",
        help="show a running daemon's pose and sensor health",
        description="Connect to the daemon's socket and show the pose, the rates and the "
        "sensors' health. On a terminal the display is redrawn in place; otherwise one line "
        "is printed per pose.",
    )
    p.add_argument("--socket", metavar="PATH", help="daemon socket (default: found as run does)")
    p.add_argument("--rate", type=float, default=10.0, metavar="HZ", help="poses per second")
    p.add_argument("--count", type=int, metavar="N", help="stop after N poses")
    p.add_argument("--json", action="store_true", help="print the raw protocol lines")
    p.set_defaults(func=run)


def _deg(rad: float | None) -> str:
    return "   nan" if rad is None else f"{math.degrees(rad):+8.2f}"


def _num(v: float | None, fmt: str) -> str:
    return "nan" if v is None else format(v, fmt)


def pose_line(m: dict[str, Any]) -> str:
    state = "updating" if m["updating"] else "NOT UPDATED (no rank)"
    line = (
        f"t {m['t']:.3f}  x {_num(m['x'], '+.4f')} m  y {_num(m['y'], '+.4f')} m  "
        f"theta {_deg(m['theta'])} deg  v {_num(m['vx'], '+.3f')} {_num(m['vy'], '+.3f')} m/s  "
        f"omega {_deg(m['omega'])} deg/s  {m['used']} used, {state}"
    )
    if m.get("missing"):
        line += "  missing: " + ", ".join(m["missing"])
    return line


def sigma_line(m: dict[str, Any]) -> str:
    cov = m["cov"]
    sd = [math.sqrt(cov[i][i]) if cov[i][i] is not None and cov[i][i] >= 0 else None
          for i in range(3)]  # fmt: skip
    return (
        f"sd  x {_num(sd[0] and sd[0] * 1e3, '.2f')} mm  y {_num(sd[1] and sd[1] * 1e3, '.2f')} mm"
        f"  theta {_num(sd[2] and math.degrees(sd[2]), '.3f')} deg"
    )


def source_line(s: dict[str, Any]) -> str:
    state = "connected" if s.get("connected") else "GONE"
    if s.get("excluded") and s.get("connected"):
        state = "excluded"
    age = s.get("age")
    res = s.get("residual")
    parts = [
        f"{s.get('name', '?'):<12}",
        f"{state:<10}",
        f"{s.get('rate_hz') or 0:7.1f} Hz",
        f"age {'-' if age is None else f'{age:.3f}s':>8}",
        f"residual {'-' if res is None else f'{res * 1e3:.3f} mm':>10}",
        f"dropped {s.get('dropped', 0)}",
    ]
    if "squal" in s:
        parts.append(f"SQUAL {s['squal']}")
    if s.get("error") and not s.get("connected"):
        parts.append(str(s["error"]))
    return "  ".join(parts)


class Screen:
    """Redraws a block in place on a terminal; prints line by line otherwise."""

    def __init__(self, out: TextIO, tty: bool) -> None:
        self.out, self.tty = out, tty
        self.last: dict[str, Any] | None = None

    def show(self, header: str, pose: dict[str, Any] | None, sources: dict[str, dict]) -> None:
        if pose is not None:
            self.last = pose
        pose = self.last
        if not self.tty:
            if pose is not None:
                print(pose_line(pose), file=self.out, flush=True)
            return
        lines = [header, ""]
        if pose is not None:
            lines += [pose_line(pose), sigma_line(pose), ""]
        lines += [source_line(s) for s in sources.values()]
        self.out.write("\x1b[H\x1b[J" + "\n".join(lines) + "\n")
        self.out.flush()


def run(args: argparse.Namespace) -> int:
    from mousedom.client import Client, ClientError

    if args.rate < 0:
        raise UserError(f"--rate must be at least 0, got {args.rate}")
    if args.count is not None and args.count < 1:
        raise UserError(f"--count must be at least 1, got {args.count}")
    try:
        client = Client(args.socket)
    except ClientError as e:  # no daemon there: one line, the client's own message
        raise UserError(str(e)) from None
    out = sys.stdout
    try:
        client.rate(args.rate)
        v = client.version
        header = (
            f"mousedom {v.get('release')} at {client.path}: model {v.get('model')}, "
            f"{v.get('rate_hz')} Hz, sensors {', '.join(v.get('sensors', []))}"
        )
        screen = Screen(out, out.isatty() and not args.json)
        if args.json:
            print(json.dumps(v), file=out, flush=True)
        elif not screen.tty:
            print(header, file=out, flush=True)
        n = 0
        for msg in client.messages():
            cls = msg.get("class")
            if args.json:
                print(json.dumps(msg), file=out, flush=True)
            elif cls == "SOURCE" and not screen.tty:
                print("source " + source_line(msg), file=out, flush=True)
            elif cls == "POSE" or (cls == "SOURCE" and screen.tty):
                screen.show(header, msg if cls == "POSE" else None, client.sources)
            if cls == "POSE":
                n += 1
                if args.count is not None and n >= args.count:
                    return 0
        print("mousedom: the daemon closed the connection", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 0
    finally:
        client.close()
