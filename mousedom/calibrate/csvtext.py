"""Small CSV files written by hand or by a spreadsheet (REF.csv, RUNS.csv).

What both readers share: lines numbered as the user sees them, comments and blank lines
skipped, a byte-order mark tolerated, and numbers that must be finite, with every error
naming the file, line and column.
"""

from __future__ import annotations

import csv
import io
import math
import re

from mousedom import plainnumber as plain
from mousedom.errors import UserError, located

_NEWLINE = re.compile(r"\r\n|\r|\n")


def content_lines(text: str) -> list[tuple[int, str]]:
    """(1-based line number, line) of every line that is neither blank nor a # comment.

    Lines end at \\r\\n, \\n or \\r (universal newlines, as editors and spreadsheets
    number them); str.splitlines also ends lines at \\f, \\v, \\x1c-\\x1e, \\x85 and
    U+2028/9, which split a row in two and put every later line number off by one."""
    text = text.removeprefix("\ufeff")  # spreadsheets save CSV with a byte-order mark
    return [
        (i + 1, line)
        for i, line in enumerate(_NEWLINE.split(text))
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


# No value in these files comes near it (times are below 1e10 s, lengths below 1e4 m);
# beyond it sums and squares overflow to inf.
MAX_ABS = 1e12


def finite(raw: str, path: str | None, line: int, column: str, max_abs: float = MAX_ABS) -> float:
    """``raw`` as a finite float of at most ``max_abs`` in size, written in ASCII decimal
    notation, or a UserError naming file, line and column."""
    raw = raw.strip()
    if not plain.FLOAT.fullmatch(raw):
        try:
            infinite = not math.isfinite(float(raw))  # nan, inf, infinity
        except ValueError:
            infinite = False
        what = "not a finite number" if infinite else "not a number"
        raise UserError(located(path, line, f"{what}: {raw!r}", column))
    v = float(raw)
    if abs(v) > max_abs:
        raise UserError(
            located(path, line, f"not a plausible number: {raw!r} (at most {max_abs:g})", column)
        )
    return v
