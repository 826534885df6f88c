"""Small CSV files written by hand or by a spreadsheet (REF.csv, RUNS.csv).

What both readers share: lines numbered as the user sees them, comments and blank lines
skipped, a byte-order mark tolerated, and numbers that must be finite, with every error
naming the file, line and column.
"""

from __future__ import annotations

import csv
import io
import math

from mousedom.errors import UserError, located


def content_lines(text: str) -> list[tuple[int, str]]:
    """(1-based line number, line) of every line that is neither blank nor a # comment."""
    text = text.removeprefix("\ufeff")  # spreadsheets save CSV with a byte-order mark
    return [
        (i + 1, line)
        for i, line in enumerate(text.splitlines())
        if line.strip() and not line.lstrip().startswith("#")
    ]


def fields(line: str, path: str | None = None, lineno: int | None = None) -> list[str]:
    """The CSV fields of one line (quoted commas are kept inside their field); a line the
    csv module refuses (a field over its 131072-character limit, a NUL) is a UserError."""
    try:
        return next(csv.reader(io.StringIO(line)), [])
    except csv.Error as e:
        raise UserError(located(path, lineno, f"not a CSV line: {e}")) from None


def header_names(line: str, path: str | None = None, lineno: int | None = None) -> list[str]:
    """Column names of a header line, stripped and lower-cased."""
    return [c.strip().lower() for c in fields(line, path, lineno)]


def finite(raw: str, path: str | None, line: int, column: str) -> float:
    """``raw`` as a finite float, or a UserError naming file, line and column."""
    raw = raw.strip()
    try:
        v = float(raw)
    except ValueError:
        raise UserError(located(path, line, f"not a number: {raw!r}", column)) from None
    if not math.isfinite(v):
        raise UserError(located(path, line, f"not a finite number: {raw!r}", column))
    return v
