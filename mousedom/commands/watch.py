"""``mousedom watch``: the live pose, rates and sensor health of a running daemon."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from typing import Any, TextIO

from mousedom.commands import _options as options
from mousedom.commands import _watchview as view
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
    p.add_argument(
        "--rate", type=options.number, default=10.0, metavar="HZ", help="poses per second"
    )
    p.add_argument("--count", type=options.whole, metavar="N", help="stop after N poses")
    p.add_argument("--json", action="store_true", help="print the raw protocol lines")
    p.set_defaults(func=run)


def _color(out: TextIO) -> bool:
    """Colour only on a terminal that has it, and not when NO_COLOR is set (no-color.org)."""
    term = os.environ.get("TERM", "")
    return out.isatty() and term not in ("", "dumb") and "NO_COLOR" not in os.environ


class Screen:
    """Redraws the screen in place on a terminal; prints line by line otherwise."""

    MAX_PATH = 4000  # points kept for the sketch (thinned by half when full)

    def __init__(self, out: TextIO, tty: bool) -> None:
        self.out, self.tty = out, tty
        self.color = tty and _color(out)
        self.last: dict[str, Any] | None = None
        self.t_start: float | None = None
        self.path: list[tuple[float, float]] = []
        self.drawn = False

    def show(self, header: str, pose: dict[str, Any] | None, sources: dict[str, dict]) -> None:
        if pose is not None:
            self.last = pose
            if self.t_start is None:
                self.t_start = pose["t"]
            if pose.get("x") is not None and pose.get("y") is not None:
                self.path.append((pose["x"], pose["y"]))
                if len(self.path) > self.MAX_PATH:
                    self.path = self.path[::2]
        pose = self.last
        t_start = self.t_start if self.t_start is not None else 0.0
        if not self.tty:
            if pose is not None:
                print(view.pose_line(pose, t_start), file=self.out, flush=True)
            return
        size = shutil.get_terminal_size((100, 30))
        lines = view.screen(
            header, pose, sources, t_start, self.path, (size.columns, size.lines), self.color
        )
        # No newline after the last line: on the terminal's last row it would scroll the
        # screen up by one, and the header (then the position) off the top.
        self.out.write("\x1b[H\x1b[J" + "\n".join(lines))
        self.out.flush()
        self.drawn = True

    def close(self) -> None:
        """Leave the cursor under the screen, for the shell's prompt."""
        if self.drawn:
            self.out.write("\n")
            self.out.flush()


# The daemon sends every client each sensor's SOURCE once a second, whatever its POSE
# rate: this long without a line is a daemon that stopped, not a quiet one.
SILENCE_S = 10.0


def run(args: argparse.Namespace) -> int:
    from mousedom.client import Client, ClientError

    _check(args)
    try:
        client = Client(args.socket, timeout=SILENCE_S)
    except ClientError as e:  # no daemon there: one line, the client's own message
        raise UserError(str(e)) from None
    out = sys.stdout
    screen: Screen | None = None
    try:
        _ask_rate(client, args.rate)
        v = client.version
        header = _header(v, client.path)
        screen = Screen(out, out.isatty() and not args.json)
        if args.json:
            print(json.dumps(v), file=out, flush=True)
        elif not screen.tty:
            print(header, file=out, flush=True)
        n = 0
        for msg in client.messages():
            cls = msg.get("class")
            if cls == "VERSION":  # a reload changed the sensors, the rate or the model
                header = _header(msg, client.path)
            if args.json:
                print(json.dumps(msg), file=out, flush=True)
            elif cls in ("VERSION", "SOURCE") and not screen.tty:
                text = header if cls == "VERSION" else "source " + view.source_line(msg)
                print(text, file=out, flush=True)
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
    except ClientError as e:  # the daemon went away mid-command, or sent no protocol line
        raise UserError(str(e)) from None
    except TimeoutError:
        raise UserError(f"{client.path}: the daemon sent nothing for {SILENCE_S:g} s (it sends "
                        "each sensor's SOURCE every second): it is stopped, hung or "
                        "overloaded (`systemctl status mousedom`)") from None  # fmt: skip
    finally:
        if screen is not None:
            screen.close()
        client.close()


def _check(args: argparse.Namespace) -> None:
    if not args.rate >= 0 or args.rate == float("inf"):  # (NaN too)
        raise UserError(f"--rate must be a number of at least 0, got {args.rate}")
    if args.count is not None and args.count < 1:
        raise UserError(f"--count must be at least 1, got {args.count}")
    if args.count is not None and args.rate == 0:
        # rate 0 asks the daemon for no POSE at all: --count would wait for ever (the
        # daemon's SOURCE lines each second keep the silence check from ending it)
        raise UserError("--count counts poses, and --rate 0 asks for none; give a rate")


def _ask_rate(client: Any, hz: float) -> None:
    """``rate`` for this client, the daemon's refusal (0 to 10000, finite) one line."""
    from mousedom.client import CommandError

    try:
        client.rate(hz)
    except CommandError as e:
        raise UserError(f"--rate {hz:g}: the daemon refused it: {e}") from None


def _header(v: dict, path: str) -> str:
    """The line that says which daemon is watched (from its VERSION)."""
    return (
        f"mousedom {v.get('release')} at {path}: model {v.get('model')}, "
        f"{v.get('rate_hz')} Hz, sensors {', '.join(v.get('sensors', []))}"
    )
