"""The ``mousedom`` command line: one subcommand per module of ``mousedom.commands``.

Each module there (but those whose name starts with ``_``: shared helpers) defines
``register(subparsers)`` which adds its parser and sets
``func`` (a callable taking the parsed namespace and returning an exit code).  Keeping
one module per subcommand keeps this file free of per-command code.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys

from mousedom import __version__, commands, hangup
from mousedom.errors import UserError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mousedom", description="Optical-mouse odometry for robots."
    )
    from mousedom import core

    parser.add_argument(
        "-V", "--version", action="version", version=f"mousedom {__version__} (core: {core.NAME})"
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging on stderr")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue  # shared helpers (_options), not subcommands
        module = importlib.import_module(f"mousedom.commands.{info.name}")
        module.register(sub)
    return parser


# Commands that handle SIGTERM and SIGHUP themselves (the daemon reloads on SIGHUP; record
# closes its file on either); every other one has them raised (hangup.stopping).
OWN_SIGNALS = ("run", "record")


def main(argv: list[str] | None = None) -> int:
    command = _subcommand(sys.argv[1:] if argv is None else argv)
    if command == "run":
        hangup.hold()  # a reload asked before the daemon's handlers are in is kept
    try:
        from mousedom import core  # noqa: F401  (MOUSEDOM_CORE is judged once, here first)
    except UserError as error:
        print(f"mousedom: error: {error}", file=sys.stderr)
        return error.exit_code
    try:
        if command in OWN_SIGNALS:
            return _main(argv)
        with hangup.stopping():
            return _main(argv)
    except KeyboardInterrupt:  # Ctrl-C while the commands are still being imported
        return 130
    except hangup.Terminated as stop:  # likewise
        hangup.die(stop.signum)
        return 128 + stop.signum


def _last_word(line: str) -> None:
    """A line on stderr that may be gone (a hangup closed the terminal)."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _subcommand(argv: list[str]) -> str | None:
    """The subcommand named (the first word not an option), before argparse runs."""
    return next((a for a in argv if not a.startswith("-")), None)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if getattr(args, "verbose", False) else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as error:
        print(f"mousedom: error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:  # Ctrl-C: one line (on a new one, past a live count line)
        _last_word(("\n" if sys.stderr.isatty() else "") + "mousedom: interrupted")
        return 130
    except hangup.Terminated as stop:  # what a file being written left is removed
        _last_word(f"mousedom: terminated ({stop.name})")
        hangup.die(stop.signum)
        return 128 + stop.signum
    except BrokenPipeError:
        # The reader of our stdout went away (e.g. `| head`); that is not an error of ours.
        sys.stderr.close()
        return 0
