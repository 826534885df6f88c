"""YAML with bounded work: every YAML text the program reads goes through here.

A config, a calibration file and a libinput recording's headers may all be hostile (a
SIGHUP reloads whatever is in /etc/mousedom).  PyYAML alone would build an alias bomb
(``&a [*a, *a, ...]`` eight levels deep: billions of nodes, while the daemon ignores
SIGTERM), recurse until RecursionError on deep nesting, spend quadratic time on integers of
ten thousand digits, or refuse trailing tabs that libyaml and every editor accept.  So
before anything is built, one pass over the parser's events (a state machine, no
recursion) measures nesting depth and the size that aliases would expand to, and refuses
what is beyond the limits with the line where it happens.  Errors are
``yaml.MarkedYAMLError``, so callers' usual handlers name the line.
"""

from __future__ import annotations

import errno
import os
import re
from typing import Any

import yaml

from mousedom import saferead

MAX_BYTES = 4 << 20  # a config or a recording's device header; event lists are not YAML-parsed
MAX_DEPTH = 32  # a rig config is 4 deep; libinput headers 5
MAX_NODES = 200_000  # nodes after alias expansion
MAX_INT_DIGITS = 100  # no integer in any of our files needs more
# A rig config and its calibration file: a SIGHUP parses them in the daemon's loop, with the
# pure-Python composer (it keeps every node's line), at about 20 us a node: 200,000 nodes
# stalled the loop 4.4 s (no POSE, SIGTERM unanswered).  A rig of 8 mice is some 200 nodes.
CONFIG_MAX_BYTES = 256 << 10
CONFIG_MAX_NODES = 10_000

try:  # libyaml's parser when present: faster, and the same events
    _Parser: Any = yaml.CSafeLoader
except AttributeError:  # pragma: no cover - depends on how PyYAML was built
    _Parser = yaml.SafeLoader

_OCTAL_LOOKING = re.compile(r"^[-+]?0[0-7_]+$")
_TRAILING_TAB = re.compile(r"[ \t]*\t[ \t]*$", re.MULTILINE)


class LimitError(yaml.MarkedYAMLError):
    """The text is beyond what this program will parse (size, depth, aliases, digits)."""


class Loader(yaml.SafeLoader):
    """SafeLoader whose integers are bounded in length (what the limit check cannot see)."""

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        _refuse_yaml11_number(node)
        if _OCTAL_LOOKING.match(str(node.value)):
            # YAML 1.1 (PyYAML's) reads 0450 as octal 296; YAML 1.2 and every person as 450.
            raise LimitError(
                problem=f"{node.value}: a number with a leading zero is ambiguous (YAML 1.1 "
                f"reads it as octal, {int(str(node.value).replace('_', ''), 8)}); write it "
                "without the zero, or quote it where an octal file mode is meant "
                '(mode: "0660")',
                problem_mark=node.start_mark,
            )
        digits = len(str(node.value))
        if digits > MAX_INT_DIGITS:
            raise LimitError(
                problem=f"an integer of {digits} characters (at most {MAX_INT_DIGITS})",
                problem_mark=node.start_mark,
            )
        return super().construct_yaml_int(node)

    def construct_yaml_float(self, node: yaml.ScalarNode) -> float:
        _refuse_yaml11_number(node)
        return super().construct_yaml_float(node)


def _refuse_yaml11_number(node: yaml.ScalarNode) -> None:
    """YAML 1.1 (PyYAML's) reads ``1:30`` as 90 (base 60: ``yaw: 1:30`` was a yaw of 90
    degrees) and ``1_00`` as 100; YAML 1.2 reads both as text.  Ambiguous, as the octal
    forms: refused with what each reading gives."""
    text = str(node.value)
    if ":" in text or "_" in text:
        form = "base-60 number" if ":" in text else "number with digit separators"
        raise LimitError(
            problem=f"{text}: a {form} is ambiguous (YAML 1.1 reads it as a number, YAML 1.2 "
            "as text); write the number plainly, or quote it where text is meant",
            problem_mark=node.start_mark,
        )


Loader.add_constructor("tag:yaml.org,2002:int", Loader.construct_yaml_int)
Loader.add_constructor("tag:yaml.org,2002:float", Loader.construct_yaml_float)
# YAML 1.1 (PyYAML's) reads 1e-4 and 1.6e3 as strings: its floats need a dot, and a sign
# after the e.  YAML 1.2 and every person read numbers (a gyro's noise density is written
# so; `cpi: 1.6e3` was "must be a number").
Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def read_text(path: str | os.PathLike[str], max_bytes: int = MAX_BYTES) -> str:
    """A YAML file's text, refusing before reading it when it is larger than the limit
    (an OSError with EFBIG, so callers' ``e.strerror`` says why)."""
    with saferead.open_regular(path) as f:  # a FIFO swapped in must not block a reload
        size = os.fstat(f.fileno()).st_size
        data = f.read(max_bytes + 1)
    if size > max_bytes or len(data) > max_bytes:
        raise OSError(
            errno.EFBIG, f"{max(size, len(data))} bytes is too large (at most {max_bytes})"
        )
    return data.decode("utf-8")


def prepare(text: str) -> str:
    """The text as it will be parsed: trailing tabs removed (PyYAML's pure-Python scanner
    refuses a tab after a value, libyaml accepts it; lines and columns of content stay)."""
    if "\t" in text:
        text = _TRAILING_TAB.sub("", text)
    return text


def check(text: str, *, max_bytes: int = MAX_BYTES, max_nodes: int = MAX_NODES) -> None:
    """Raise LimitError if parsing ``text`` would take more than the limits allow."""
    if len(text) > max_bytes:
        raise LimitError(
            problem=f"{len(text)} characters of YAML (at most {max_bytes})",
            problem_mark=yaml.Mark("<text>", 0, 0, 0, None, None),
        )
    try:
        _measure(text, max_nodes)
    except yaml.reader.ReaderError as e:
        # Not a MarkedYAMLError: say it with a line, as every other YAML error is said.
        line = text.count("\n", 0, e.position)
        raise LimitError(
            problem=f"character #x{e.character:04x} is not allowed in YAML (a control character)",
            problem_mark=yaml.Mark("<text>", e.position, line, 0, None, None),
        ) from None


def _measure(text: str, max_nodes: int) -> None:
    """One pass over the parser's events: depth, alias expansion and cycles."""
    depth = 0
    sizes: dict[str, int] = {}  # anchor -> nodes it stands for, aliases expanded
    open_counts: list[tuple[int, str | None]] = []  # (nodes so far, anchor) per open level
    total = 0
    for event in yaml.parse(text, Loader=_Parser):
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_DEPTH:
                raise LimitError(
                    problem=f"nested deeper than {MAX_DEPTH} levels",
                    problem_mark=event.start_mark,
                )
            open_counts.append((1, event.anchor))
            continue
        if isinstance(event, yaml.CollectionEndEvent):
            depth -= 1
            size, anchor = open_counts.pop()
        elif isinstance(event, yaml.ScalarEvent):
            size, anchor = 1, event.anchor
        elif isinstance(event, yaml.AliasEvent):
            if any(a == event.anchor for _, a in open_counts):
                # PyYAML builds a self-containing object, which every walk over it (line
                # indexing, repr, validation) would recurse into without end.
                raise LimitError(
                    problem=f"alias *{event.anchor} inside the node it names (a cycle)",
                    problem_mark=event.start_mark,
                )
            size, anchor = sizes.get(event.anchor, 1), None
        else:
            continue
        if anchor is not None:
            sizes[anchor] = size
        if open_counts:
            parent, parent_anchor = open_counts[-1]
            open_counts[-1] = (parent + size, parent_anchor)
        else:
            total += size
        if size > max_nodes or total > max_nodes:
            raise LimitError(
                problem=f"more than {max_nodes} nodes (aliases expanded)",
                problem_mark=event.start_mark,
            )


def load(text: str | bytes) -> Any:
    """``yaml.safe_load`` within the limits."""
    if isinstance(text, bytes):
        raw = text
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            line = raw.count(b"\n", 0, e.start)
            raise LimitError(
                problem=f"not UTF-8 text (byte {e.start} of this part)",
                problem_mark=yaml.Mark("<bytes>", e.start, line, 0, None, None),
            ) from None
    text = prepare(text)
    check(text)
    loader = Loader(text)
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()


def compose(text: str) -> tuple[yaml.Node | None, Loader]:
    """The node tree (for line numbers) and the loader that will construct it; the caller
    calls ``loader.construct_document(node)`` and ``loader.dispose()``.  Used for configs
    and calibration files: their limits (CONFIG_MAX_BYTES, CONFIG_MAX_NODES)."""
    text = prepare(text)
    check(text, max_bytes=CONFIG_MAX_BYTES, max_nodes=CONFIG_MAX_NODES)
    loader = Loader(text)
    try:
        return loader.get_single_node(), loader
    except BaseException:
        loader.dispose()
        raise
