"""The options several subcommands share, spelled one way: ``-c/--config RIG.yaml``,
``-o/--output FILE`` and ``--root DIR``, each with its help and its default shown."""

from __future__ import annotations

import argparse
import sys
from typing import BinaryIO

from mousedom.config import DEFAULT_CONFIG_PATH
from mousedom.errors import UserError
from mousedom.plainnumber import plain_float, plain_int


def add_config(
    p: argparse.ArgumentParser,
    what: str = "the rig config",
    *,
    required: bool = False,
    default: str | None = None,
) -> None:
    """``-c/--config RIG.yaml``; ``default`` is shown in the help (None: no default)."""
    if required:
        tail = " (required)"
    elif default:
        tail = f" (default {default})"
    else:
        tail = ""
    p.add_argument(
        "-c", "--config", metavar="RIG.yaml", required=required, default=default,
        help=what + tail,
    )  # fmt: skip


def add_default_config(p: argparse.ArgumentParser, what: str = "the rig config") -> None:
    """``-c/--config RIG.yaml`` defaulting to the robot's config in /etc."""
    add_config(p, what, default=DEFAULT_CONFIG_PATH)


def add_output(
    p: argparse.ArgumentParser, what: str, *, required: bool = False, metavar: str = "FILE"
) -> None:
    """``-o/--output FILE``."""
    p.add_argument("-o", "--output", metavar=metavar, required=required, help=what)


def add_root(p: argparse.ArgumentParser) -> None:
    """``--root DIR``: the input devices of a fake or mounted tree (list, doctor)."""
    p.add_argument(
        "--root",
        metavar="DIR",
        help="read DIR/dev/input, DIR/sys/class/input and DIR/run/udev/data instead of "
        "the real ones (containers, tests)",
    )


NON_FINITE = ("nan", "inf", "infinity")


def number(text: str) -> float:
    """An argparse type: a number in ASCII decimal notation (``plainnumber``); float()
    would take "1_000", full-width digits and "nan" (each option checks its own range)."""
    try:
        return plain_float(text)
    except ValueError as e:
        if text.strip().lower().lstrip("+-") in NON_FINITE:
            return float(text)  # the option's range check says what it takes
        raise argparse.ArgumentTypeError(str(e)) from None


def whole(text: str) -> int:
    """An argparse type: a whole number in ASCII digits."""
    try:
        return plain_int(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def binary_stdout() -> BinaryIO:
    """stdout for ``-o -`` (a capture to a pipe: ssh, gzip), refused where it cannot be
    one: closed (started with ``>&-``) or a terminal."""
    if sys.stdout is None:
        raise UserError("-o -: stdout is closed; redirect it, or give a file name")
    if sys.stdout.isatty():
        raise UserError("-o -: stdout is a terminal; redirect it, or give a file name")
    return sys.stdout.buffer
