"""The calibration YAML that a config references (``calibration: rig.calib.yaml``).

Schema (read by ``mousedom.config._apply_calibration``)::

    mice:
      left: {cpi: {x: 452.1, y: 455.2}, mount: {x: 0.0, y: 0.135, yaw: 0.0}, scale: 1.0}
    distance: {mice: [left, right], distance: 0.2701, stderr: 0.0002, runs: 4}
    umbmark: {e_max_syst: 0.114, ...}

Mount yaw is in degrees, like the config.  Top-level keys other than ``mice`` are
informational.  Each command merges its result into what is there (a CPI calibration
keeps the mounts, and so on) and the file is replaced atomically, so the daemon never
reads half a file on SIGHUP.
"""

from __future__ import annotations

import copy
import os
import sys
from collections.abc import Callable
from typing import Any

import yaml

from mousedom import saferead, safewrite, safeyaml
from mousedom.config import Config, load_config
from mousedom.errors import UserError

# What --write keeps of a file edited by hand: every value (a result is merged into them);
# not its comments (the file is written again from its data; notes belong in the config).
HEADER = (
    "# mousedom calibration: written by `mousedom calibrate ... --write`; values edited "
    "here are kept, comments are not\n"
)


def read_calibration(path: str) -> dict[str, Any]:
    """The calibration file as a dict; {} when it does not exist yet."""
    try:
        text = safeyaml.read_text(path)
    except FileNotFoundError:
        return {}
    except OSError as e:
        raise UserError(f"{path}: cannot read calibration: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise UserError(f"{path}: byte offset {e.start}: not UTF-8 text") from None
    try:
        data = safeyaml.load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else path
        raise UserError(f"{where}: invalid YAML: {getattr(e, 'problem', None) or e}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise UserError(f"{path}:1: a calibration file must be a mapping")
    if not isinstance(data.get("mice", {}), dict):
        raise UserError(f"{path}: mice: must be a mapping of mouse names")
    return data


def merge_mouse(data: dict[str, Any], name: str, **values: Any) -> dict[str, Any]:
    """A copy of ``data`` with ``values`` (cpi, mount, scale) merged into mice.<name>.

    Nested mappings (cpi: {x, y}, mount: {x, y, yaw}) are merged key by key, so a
    y-axis CPI calibration keeps the x value already there.
    """
    out = copy.deepcopy(data)
    mice = out.setdefault("mice", {})
    entry = mice.setdefault(name, {})
    if not isinstance(entry, dict):
        entry = mice[name] = {}
    for key, value in values.items():
        if isinstance(value, dict) and isinstance(entry.get(key), dict):
            entry[key] = {**entry[key], **value}
        else:
            entry[key] = value
    return out


def merge_section(data: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    """A copy of ``data`` with the top-level ``key`` set to ``value``."""
    out = copy.deepcopy(data)
    out[key] = value
    return out


def _plain(value: Any) -> Any:
    """numpy scalars and tuples -> plain Python, which safe_dump can write."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        return value.item()
    return value


def write_calibration(path: str, data: dict[str, Any], inputs: tuple[str | None, ...] = ()) -> None:
    """Replace ``path`` atomically with ``data`` as YAML."""
    text = HEADER + yaml.safe_dump(_plain(data), sort_keys=False, default_flow_style=None)
    replace_bytes(path, text.encode("utf-8"), inputs)


def replace_bytes(path: str, raw: bytes, inputs: tuple[str | None, ...] = ()) -> None:
    """Replace ``path`` atomically with ``raw`` (also to put an old file back); never
    through a link, never onto one of ``inputs`` (the config itself)."""
    safewrite.replace_bytes(path, raw, inputs, make_folder=True)


def store(config: Config, update: Callable[[dict[str, Any]], dict[str, Any]]) -> None:
    """Merge a result into the config's calibration file (``update`` maps the old data to
    the new), and check that the config still loads with it; if not, put the old file back.
    """
    path = config.calibration
    if path is None or config.path is None:
        # The commands refuse --write without a calibration file before any work, and a
        # config they load comes from its file: neither is missing here.
        raise UserError(f"{config.path or 'the config'}: no calibration file to write to")
    try:
        old: bytes | None = saferead.read_bytes(path)
    except OSError:
        old = None  # not written yet (read_calibration says why if it is unreadable)
    data = read_calibration(path)
    write_calibration(path, update(data), (config.path,))
    try:
        # what was written must load (checked as the calibration commands check a config)
        load_config(config.path, need_sources=False, need_model=False, need_mounts=False)
    except UserError as e:
        # Put the old file back: a daemon reloading on SIGHUP, or starting, must not
        # meet a calibration that this command knows to be broken.
        if old is None:
            os.unlink(path)
        else:
            replace_bytes(path, old, (config.path,))
        raise UserError(f"{path}: not written, the result does not load: {e}") from None
    print(f"written to {path}", file=sys.stderr)
