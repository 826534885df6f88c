"""How this program was started, so that a command it prints runs when pasted.

A newcomer runs ``.venv/bin/mousedom run --demo``, opens a new terminal (where the venv is
not active) and pastes the ``mousedom watch`` line the daemon printed: "command not
found".  So printed commands start with what will work there: plain ``mousedom`` only
when that name on $PATH is this very program, else its full path, or ``python -m
mousedom`` with this interpreter's full path.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys


def command(*args: str) -> str:
    """``mousedom ARGS`` as a line to paste into any shell of this machine."""
    return " ".join([*_program(), *(shlex.quote(a) for a in args)])


def _program() -> list[str]:
    argv0 = sys.argv[0] if sys.argv else ""
    if os.path.basename(argv0) == "mousedom" and os.path.isfile(argv0):
        here = os.path.realpath(argv0)
        found = shutil.which("mousedom")
        if found and os.path.realpath(found) == here:
            return ["mousedom"]
        return [shlex.quote(os.path.abspath(argv0))]
    # ``python -m mousedom`` (or an embedding): this interpreter, with its full path.
    return [shlex.quote(sys.executable or "python3"), "-m", "mousedom"]
