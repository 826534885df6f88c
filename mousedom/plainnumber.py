"""Numbers as people and spreadsheets write them: ASCII decimal notation, nothing else.

Python's float() and int() also take "1_000", Arabic-Indic and full-width digits, padded
text, "nan" and "infinity": none is a measurement or a count a user meant to type.  The
hand-written CSV files (REF.csv, RUNS.csv) and the command line's numeric options take
numbers by this one rule."""

from __future__ import annotations

import re

FLOAT = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
INT = re.compile(r"[+-]?[0-9]+", re.ASCII)


def plain_float(text: str) -> float:
    """``text`` (surrounding blanks allowed) as a float; ValueError if it is not written in
    ASCII decimal notation (float() would take "1_0", "nan" or full-width digits)."""
    raw = text.strip()
    if not FLOAT.fullmatch(raw):
        raise ValueError(f"not a number: {text!r}")
    return float(raw)


def plain_int(text: str) -> int:
    """``text`` (surrounding blanks allowed) as a whole number in ASCII digits; ValueError
    otherwise."""
    raw = text.strip()
    if not INT.fullmatch(raw):
        raise ValueError(f"not a whole number: {text!r}")
    return int(raw)
