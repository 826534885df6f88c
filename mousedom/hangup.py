"""A SIGHUP that comes before the daemon's own handlers: kept as a reload, not fatal.

Python's default for SIGHUP ends the process: a reload asked in the first half second of
`mousedom run` (its imports, the config, the sensors) killed the daemon with no word.
``hold`` is called first thing for `run` (cli.main); the daemon, once its handlers are in,
asks ``pending`` and reloads if one came (the config may have changed after it was read).
"""

from __future__ import annotations

import signal

_seen: list[int] = []


def hold() -> None:
    """From now on a SIGHUP is remembered, until the daemon's handler replaces this one."""
    signal.signal(signal.SIGHUP, lambda signum, frame: _seen.append(signum))


def pending() -> bool:
    """Whether a SIGHUP came while held."""
    return bool(_seen)
