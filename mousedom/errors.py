"""Errors that reach the user as one clear line instead of a traceback."""

from __future__ import annotations


class UserError(Exception):
    """A problem with the user's input (file, config, command line).

    The CLI prints ``str(error)`` and exits with ``exit_code``; no traceback.
    Messages should name the file and line, key or byte offset at fault.
    """

    exit_code = 2

    def __init__(self, message: str, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


def escaped(text: str) -> str:
    """Text from outside (a device's name, a capture's line) as one line for a terminal:
    its control characters escaped as Python writes them (``\\x1b``, ``\\n``).  A name
    with a newline broke a listing's layout, one with ESC sent the terminal a sequence (a
    window title, a cleared screen) when printed raw."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def located(path: str | None, line: int | None, message: str, key: str | None = None) -> str:
    """Format ``file:line: key: message`` leaving out the parts that are unknown."""
    where = str(path) if path else "<input>"
    if line is not None:
        where += f":{line}"
    if key:
        return f"{where}: {key}: {message}"
    return f"{where}: {message}"
