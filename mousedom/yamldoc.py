"""A YAML mapping read with its line numbers: typed access that names file, line and key.

``YamlDoc`` parses a text (within safeyaml's limits) to data plus the line of every key
path, and keeps the problems found while a caller reads it, so that one run reports every
mistake of a file, one line each, in file order.  ``Reader`` is typed access to one
mapping of it: numbers, integers, strings, choices, with unknown keys reported against
the mapping's own list of known keys (with "did you mean" where one is close).
``mousedom.config`` builds the rig's dataclasses on top of it.
"""

from __future__ import annotations

import difflib
import math
import re
from typing import Any

import yaml

from mousedom import safeyaml
from mousedom.errors import UserError, located


class ConfigError(UserError):
    """A config or calibration file is wrong; the message names file, line and key."""

    def __init__(
        self, message: str, exit_code: int | None = None, *, line: int | None = None
    ) -> None:
        super().__init__(message, exit_code)
        self.line = line  # the file's line it is about (None: unknown): orders the problems


_KEY_LINE = re.compile(r"^( *)(?:- )?([^\s#:][^:#]*?)\s*:(?:\s+(\S.*))?$")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def explain_yaml_error(text: str, e: yaml.MarkedYAMLError) -> tuple[int | None, str]:
    """(line, message) for a YAML syntax error, in the user's terms where PyYAML's are
    obscure: a tab in the indentation is named as such (PyYAML: "found character that
    cannot start any token"), and a key indented differently from its neighbours is named,
    with its line, where PyYAML reports the line after it ("did not find expected key",
    "mapping values are not allowed here")."""
    mark = e.problem_mark or e.context_mark
    line = mark.line + 1 if mark else None
    why = str(e.problem or e)
    if line is None:
        return line, why
    lines = text.splitlines()
    for k in range(min(line, len(lines)) - 1, -1, -1):
        lead = lines[k][: len(lines[k]) - len(lines[k].lstrip(" \t"))]
        if "\t" in lead:
            return k + 1, "a tab in the indentation (YAML indents with spaces only)"
        if k < line - 3:
            break
    if any(p in why for p in ("expected key", "mapping values are not allowed",
                              "expected <block end>")):  # fmt: skip
        # The line before the one reported, if it is a "key: value" more indented than the
        # reported one's siblings, is the culprit: one space too many.
        k = line - 2
        while k >= 0 and (not lines[k].strip() or lines[k].lstrip().startswith("#")):
            k -= 1
        here = lines[line - 1] if line - 1 < len(lines) else ""
        m = _KEY_LINE.match(lines[k]) if k >= 0 else None
        if m and m.group(3) and here.strip() and _indent(lines[k]) > _indent(here):
            return k + 1, (
                f"key {m.group(2).strip()!r} is indented {_indent(lines[k])} spaces, the key "
                f"after it {_indent(here)}: keys of one mapping line up (a space too many?)"
            )
        h = _KEY_LINE.match(here)
        if m and m.group(3) and h and _indent(here) > _indent(lines[k]):
            # a key under a key that already has a value: this line is the one out of line
            return line, (
                f"key {h.group(2).strip()!r} is indented {_indent(here)} spaces, the key "
                f"before it {_indent(lines[k])}: keys of one mapping line up (a space too many?)"
            )
    return line, why


_MERGE = "tag:yaml.org,2002:merge"


def key_line(lines: dict[tuple[str, ...], int], keys: tuple[str, ...]) -> int | None:
    """The line of a key path, or of its nearest parent written (``YamlDoc.lines``)."""
    for n in range(len(keys), -1, -1):
        if keys[:n] in lines:
            return lines[keys[:n]]
    return None


class YamlDoc:
    """Parsed YAML plus the line number (1-based) of every key path."""

    def __init__(self, path: str | None, text: str) -> None:
        self.path = path
        self.lines: dict[tuple[str, ...], int] = {}
        self.problems: list[ConfigError] = []
        self.need_mounts = True
        try:
            node, loader = safeyaml.compose(text)
            try:
                # Indexed as written, before construction folds each merge key's (<<) pairs
                # into its mapping, where a key that overrides a merged one looked given twice.
                if node is not None:
                    self._index(node, ())
                self.data = loader.construct_document(node) if node is not None else None
            finally:
                loader.dispose()
        except yaml.MarkedYAMLError as e:
            line, why = explain_yaml_error(text, e)
            raise ConfigError(located(path, line, f"invalid YAML: {why}")) from None
        except yaml.YAMLError as e:
            raise ConfigError(located(path, None, f"invalid YAML: {e}")) from None

    def _index(self, node: yaml.Node, prefix: tuple[str, ...]) -> None:
        self.lines.setdefault(prefix, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            seen: set[str] = set()
            merged: list[yaml.Node] = []
            for key_node, value_node in node.value:
                if key_node.tag == _MERGE:
                    merged.append(value_node)
                    continue
                key = str(key_node.value)
                line = key_node.start_mark.line + 1
                if key in seen:
                    # YAML keeps the last of two equal keys; a second `left:` silently
                    # replacing the first mouse would be a wrong answer later.
                    first = self.lines[prefix + (key,)]
                    where = ".".join(prefix + (key,))
                    raise ConfigError(
                        located(self.path, line, f"given twice (first on line {first})", where)
                    )
                seen.add(key)
                self.lines[prefix + (key,)] = line
                self._index(value_node, prefix + (key,))
            for value_node in merged:
                self._index_merged(value_node, prefix, seen)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                self._index(item, prefix + (str(i),))

    def _index_merged(self, node: yaml.Node, prefix: tuple[str, ...], seen: set[str]) -> None:
        """A merge key's mapping (or list of them, the first winning): its keys where the
        mapping does not give them itself, at the lines they are written on."""
        for mapping in node.value if isinstance(node, yaml.SequenceNode) else [node]:
            if not isinstance(mapping, yaml.MappingNode):
                continue  # (construction refuses it, with its line)
            for key_node, value_node in mapping.value:
                if key_node.tag == _MERGE:
                    self._index_merged(value_node, prefix, seen)
                    continue
                key = str(key_node.value)
                if key not in seen:
                    seen.add(key)
                    self.lines[prefix + (key,)] = key_node.start_mark.line + 1
                    self._index(value_node, prefix + (key,))

    def error(self, keys: tuple[str, ...], message: str) -> ConfigError:
        line = key_line(self.lines, keys)
        if line is None and not keys[:1]:
            line = 1  # an empty file: its first line
        where = ".".join(k if k.isprintable() else repr(k) for k in keys)
        return ConfigError(located(self.path, line, message, where or None), line=line)

    # Every problem of a file is reported at once: sections are read one by one, each
    # failure is kept here, and parse_config raises them all together at the end.
    def keep(self, error: ConfigError) -> None:
        self.problems.append(error)

    def attempt(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        """fn(*args, **kwargs), or None with its ConfigError kept for the end."""
        try:
            return fn(*args, **kwargs)
        except ConfigError as e:
            self.keep(e)
            return None

    def raise_problems(self) -> None:
        if not self.problems:
            return
        ordered = sorted(self.problems, key=lambda e: e.line or 0)
        text = "\n".join(dict.fromkeys(str(e) for e in ordered))  # each once, by line
        raise ConfigError(text)


class Reader:
    """Typed access to one mapping of a YamlDoc; complains about unknown keys."""

    def __init__(
        self, doc: YamlDoc, value: Any, keys: tuple[str, ...], known: tuple[str, ...] = ()
    ) -> None:
        if value is None:
            value = {}
        if not isinstance(value, dict):
            raise doc.error(keys, f"must be a mapping, got {shown(value)}")
        self.doc, self.value, self.keys = doc, value, keys
        self.used: set[str] = set()
        self.known = known
        self.suggested: set[str] = set()  # known keys offered for misspelt ones
        if known:
            # Said first, each on its own line: a misspelt key (`mownt:`) is the real
            # mistake behind "mount: is required", which may follow.
            for k in value:
                if str(k) not in known:
                    doc.keep(self._unknown(str(k)))
            self.used.update(str(k) for k in value)

    def has(self, key: str) -> bool:
        return key in self.value

    def raw(self, key: str, default: Any = None) -> Any:
        self.used.add(key)
        return self.value.get(key, default)

    def sub(self, key: str, known: tuple[str, ...] = ()) -> Reader:
        return Reader(self.doc, self.raw(key), self.keys + (key,), known)

    def _unknown(self, key: str) -> ConfigError:
        close = difflib.get_close_matches(key, self.known, n=1, cutoff=0.6)
        if close:
            self.suggested.add(close[0])
            hint = f"did you mean {close[0]}?"
        else:
            hint = f"known here: {', '.join(self.known)};"
        return self.err(key, f"unknown key ({hint} see docs/config.md)")

    def err(self, key: str | None, message: str) -> ConfigError:
        return self.doc.error(self.keys + ((key,) if key else ()), message)

    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        positive: bool = False,
        within: tuple[float, float] | None = None,
    ) -> float:
        v = self.raw(key, default)
        if v is None:
            raise self.err(key, "is required")
        if isinstance(v, int) and not isinstance(v, bool) and abs(v) > 1e300:
            raise self.err(key, f"must be a number of sensible size, got {shown(v)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(key, f"must be a number, got {shown(v)}")
        if positive and v <= 0:
            raise self.err(key, f"must be a positive number, got {v}")
        if within and not within[0] <= v <= within[1]:
            raise self.err(key, f"must be between {within[0]:g} and {within[1]:g}, got {v}")
        return float(v)

    def integer(self, key: str, default: int | None = None, *, minimum: int | None = None) -> int:
        v = self.raw(key, default)
        if isinstance(v, str):
            try:
                v = int(v, 0)
            except ValueError:
                raise self.err(key, f"must be an integer, got {shown(v)}") from None
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(key, f"must be an integer, got {shown(v)}")
        if minimum is not None and v < minimum:
            raise self.err(key, f"must be at least {minimum}, got {v}")
        return v

    def string(self, key: str, default: str | None = None) -> str | None:
        v = self.raw(key, default)
        if v is not None and not isinstance(v, str):
            raise self.err(key, f"must be a string, got {shown(v)}")
        if v is not None and "\0" in v:  # no path, name or group holds one
            raise self.err(key, f"must not contain a NUL character, got {shown(v)}")
        return v

    def boolean(self, key: str, default: bool) -> bool:
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise self.err(key, f"must be true or false, got {shown(v)}")
        return v

    def choice(self, key: str, options: tuple[str, ...], default: str) -> str:
        v = self.raw(key, default)
        if v not in options:
            raise self.err(key, f"must be one of {', '.join(options)}, got {shown(v)}")
        return v

    def finish(self) -> None:
        """Sections read without a ``known`` list: their unknown keys, all of them."""
        for k in self.value:
            if k not in self.used:
                self.doc.keep(
                    self.err(str(k), "unknown key (check the spelling; see docs/config.md)")
                )


def shown(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."
