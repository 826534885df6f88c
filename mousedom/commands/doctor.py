"""``mousedom doctor``: does it work, and if not, what to do.

One line per finding, in the order a rig is brought up: the config (found, parses, its
warnings and notes), the devices (the input directory, which device each mouse's rule
matches, permissions and the group to join), the calibration file, the daemon's socket
(connect, then a short read: POSE rate against the config's, each mouse's state, learnt
scale warnings), the ROS 2 output (can a DDS participant start; with a live daemon, does
its odometry arrive), the Prometheus endpoint where the config asks for one (the extra
installed, and the running daemon serving it), and the core in use.  Each line is OK,
WARN or FAIL, and a WARN or FAIL says what to do.  Exit 1 on any FAIL; warnings alone exit 0.

Nothing here re-implements a rule: it asks the parts that own them (``load_config`` and
its plausibility warnings, ``observability.blind_spots``, ``sources.discovery`` and
``list``'s matching, the ``Client`` and its ``access_hint``, ``service.ros2out``).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.machinery
import json
import math
import os
import sys
from dataclasses import dataclass

from mousedom import invocation, safeyaml
from mousedom.commands import _options as options
from mousedom.commands._doctor_base import FAIL, OK, PACKAGE, WARN, Check, Lines
from mousedom.commands._doctor_daemon import (
    Live,
    check_daemon,
    check_metrics,
    pose_rate,
    read_live,
    socket_path,
)
from mousedom.commands._doctor_devices import check_devices
from mousedom.commands._doctor_ros2 import Ros2Probe
from mousedom.config import DEFAULT_CONFIG_PATH, Config, ConfigError, load_config
from mousedom.errors import UserError

# The checks live by subject in _doctor_devices, _doctor_daemon (the daemon and its metrics)
# and _doctor_ros2; this module runs them in order.  Their names stay reachable from here.
__all__ = [
    "FAIL",
    "OK",
    "WARN",
    "Check",
    "Found",
    "Lines",
    "Live",
    "Ros2Probe",
    "check_calibration",
    "check_config",
    "check_core",
    "check_daemon",
    "check_devices",
    "check_metrics",
    "diagnose",
    "pose_rate",
    "read_live",
    "register",
    "render",
    "run",
    "socket_path",
]


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "doctor",
        help="check that it all works (config, devices, daemon, ROS 2) and say what to do",
        description="Check, in order: the rig config; the input devices and which one each "
        "mouse's rule matches (and the group to join when one is closed to this user); the "
        "calibration file; the running daemon (its POSE rate, each mouse's state); the ROS 2 "
        "output; the core in use. Each line says OK, WARN or FAIL and what to do. Exit 1 if "
        "anything FAILs.",
    )
    p.add_argument(
        "-c",
        "--config",
        metavar="RIG.yaml",
        help=f"the rig config (default {DEFAULT_CONFIG_PATH}, as for run; if that does not "
        "exist, the one the running daemon reports)",
    )
    p.add_argument("--socket", metavar="PATH", help="daemon socket (default: found as run does)")
    p.add_argument(
        "--timeout",
        type=options.number,
        default=1.5,
        metavar="S",
        help="how long to read the running daemon, and to listen for its ROS 2 odometry "
        "(default 1.5)",
    )
    p.add_argument("--json", action="store_true", help="the checks as a JSON document")
    options.add_root(p)
    p.set_defaults(func=run)


# --------------------------------------------------------------------------- 1. config


@dataclass
class Found:
    """The config doctor checks, how it was found, and what loading it gave."""

    path: str | None
    how: str = ""  # "--config", "the daemon's default", "the running daemon's"
    config: Config | None = None
    calibration_error: str | None = None  # the config is fine, its calibration file is not


def check_config(found: Found) -> list[Check]:
    """Found, parses (each mouse with a source), and what check-config warns of and notes."""
    from mousedom.observability import blind_spots

    lines = Lines("config")
    demo = invocation.command("run", "--demo")
    if found.path is None:
        lines.fail(
            f"no config: {DEFAULT_CONFIG_PATH} (the daemon's default) does not exist, and no "
            "daemon answers to say which one it runs",
            f"give --config RIG.yaml (config/examples/ has rigs to start from), or try the "
            f"demo: {demo}",
        )
        return lines
    where = f"{found.path} ({found.how})"
    try:
        cfg = load_config(found.path)
    except ConfigError as e:
        text = str(e)
        if "config file not found" in text:
            lines.fail(text, f"give --config RIG.yaml, or try the demo: {demo}")
        elif not text.startswith(found.path) and _loads_without_calibration(found.path):
            lines.ok(f"{where}: parses; its calibration file does not (below)")
            found.calibration_error = text
        elif _loads_without_sources(found.path):
            lines.fail(text, "the daemon needs a source for each mouse (evdev, serial or "
                       "replay): this rig is for captures and calibration only")  # fmt: skip
        else:
            lines.fail(text, "fix what the message names (`mousedom check-config` says the same)")
        return lines
    found.config = cfg
    n = len(cfg.mice)
    lines.ok(
        f"{where}: {cfg.model} model, {cfg.rate_hz:g} Hz, {n} {'mouse' if n == 1 else 'mice'} "
        f"({', '.join(cfg.names)})",
        path=cfg.path,
        rate_hz=cfg.rate_hz,
    )
    for w in cfg.warnings:  # values that look like the wrong unit (mousedom.plausible)
        lines.warn(w, "correct it if it is not what you meant (if it is, nothing to do)")
    if cfg.robust.enabled:  # what the layout hides from the fault test, as check-config notes
        mounts = [(m.name, m.mount.x, m.mount.y) for m in cfg.mice]
        r = cfg.robust
        for note in blind_spots(cfg.model, mounts, r.relative_noise, r.false_alarm):
            lines.ok(f"note: {note}")
    return lines


def _loads_without_sources(path: str) -> bool:
    try:
        load_config(path, need_sources=False)
    except UserError:
        return False
    return True


def _loads_without_calibration(path: str) -> bool:
    """Whether the error came from the calibration file: the config's text, its
    ``calibration:`` line left out, loads."""
    try:
        lines = safeyaml.read_text(path).splitlines(keepends=True)
        text = "".join(ln for ln in lines if not ln.startswith("calibration:"))
        from mousedom.config import parse_config

        parse_config(text, path)
    except (UserError, OSError, UnicodeDecodeError):
        return False
    return True


# --------------------------------------------------------------------------- 3. calibration


def check_calibration(found: Found) -> list[Check]:
    lines = Lines("calibration")
    cfg = found.config
    if found.calibration_error:
        lines.fail(found.calibration_error, "fix the file, or write it again (`mousedom "
                   "calibrate ... --write`): the daemon does not start with it")  # fmt: skip
    if cfg is None:
        return lines
    if not cfg.calibration:
        lines.ok("none named (the config's CPI and mounts are used as written)")
        return lines
    path = cfg.calibration
    if not os.path.exists(path):
        lines.warn(f"{path}: named, not written yet: the config's own CPI and mounts are used",
                   "calibrate the rig (docs/calibration.md); `mousedom calibrate cpi ... "
                   "--write` writes this file")  # fmt: skip
        return lines
    # load_config has read and applied it (it refuses the config otherwise): say what it holds.
    try:
        doc = safeyaml.load(safeyaml.read_text(path)) or {}
        covered = {str(k): sorted(v or {}) for k, v in (doc.get("mice") or {}).items()}
    except (OSError, ValueError, AttributeError, UnicodeDecodeError):
        covered = {}
    held = ", ".join(f"{n} ({'/'.join(keys) or 'nothing'})" for n, keys in covered.items())
    lines.ok(f"{path}: read and applied: {held or 'no mouse in it'}", path=path)
    left = [n for n in cfg.names if n not in covered]
    if left and covered:
        lines.warn(f"{', '.join(left)}: not in the calibration file (the config's values stand)",
                   "calibrate them too, if the rig has changed")  # fmt: skip
    return lines


# --------------------------------------------------------------------------- 7. the core


def compiled_modules() -> list[str]:
    """The compiled extension modules inside the mousedom package, as module names."""
    suffixes = sorted(importlib.machinery.EXTENSION_SUFFIXES, key=len, reverse=True)
    out = []
    for p in sorted(PACKAGE.rglob("*")):
        suffix = next((s for s in suffixes if p.name.endswith(s)), None)
        if suffix:
            rel = p.relative_to(PACKAGE.parent).as_posix()[: -len(suffix)]
            out.append(rel.replace("/", "."))
    return out


def check_core(live: Live | None) -> list[Check]:
    lines = Lines("core")
    said = live.version.get("core") if live is not None else None
    tail = f"; the running daemon says: {said}" if said else ""
    modules = compiled_modules()
    if not modules:
        lines.ok(f"python (no compiled core built){tail}")
    elif os.environ.get("MOUSEDOM_CORE", "").strip() == "python":
        lines.ok(f"python (MOUSEDOM_CORE=python; built: {', '.join(modules)}){tail}")
    else:
        for module in modules:
            try:
                importlib.import_module(module)
            except ImportError as e:
                lines.warn(f"python: the compiled {module} does not load ({e})",
                           "rebuild it: pip install --force-reinstall mousedom (with gcc and "
                           "the Python headers, docs/install.md)")  # fmt: skip
                return lines
        lines.ok(f"compiled ({', '.join(modules)}){tail}")
    return lines


# --------------------------------------------------------------------------- the report


def find_config(given: str | None, socket_given: str | None) -> Found:
    """--config; else the daemon's default; else the config the running daemon reports."""
    if given:
        return Found(given, "--config")
    if os.path.exists(DEFAULT_CONFIG_PATH):
        return Found(DEFAULT_CONFIG_PATH, "the daemon's default")
    path = socket_path(None, socket_given)
    if os.path.exists(path):
        runs = read_live(path, 0.1).status.get("config")
        if isinstance(runs, str) and runs:
            return Found(runs, "the running daemon's")
    return Found(None)


def diagnose(
    config: str | None = None,
    socket: str | None = None,
    timeout: float = 1.5,
    root: str | None = None,
) -> list[Check]:
    """Every check, in order: config, devices, calibration, daemon, ROS 2, metrics, core."""
    found = find_config(config, socket)
    checks = check_config(found)
    cfg = found.config
    if found.path is not None and cfg is None and not found.calibration_error:
        checks.append(Check("devices", WARN, "not checked: the config did not load",
                            "fix the config first"))  # fmt: skip
    else:
        checks += check_devices(cfg, root)
    checks += check_calibration(found)
    path = socket_path(cfg, socket)
    ros2 = Ros2Probe(cfg, listen=timeout if os.path.exists(path) else 0.0)
    try:
        live = read_live(path, timeout, cfg.path if cfg else None)
        checks += check_daemon(live, cfg, timeout)
        checks += ros2.finish(live)
    finally:
        ros2.close()
    checks += check_metrics(cfg, live, timeout)
    checks += check_core(live)
    return checks


def render(checks: list[Check]) -> str:
    """The report as text: one line per check, what to do under each WARN and FAIL."""
    lines = []
    for c in checks:
        lines.append(f"{c.status:<4}  {c.check}: {c.message}")
        if c.hint and c.status != OK:
            lines.append(f"      -> {c.hint}")
    count = {s: sum(1 for c in checks if c.status == s) for s in (FAIL, WARN, OK)}
    verdict = "it works" if not count[FAIL] else "it does not work yet"
    lines.append(f"doctor: {verdict} ({count[FAIL]} FAIL, {count[WARN]} WARN, {count[OK]} OK)")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UserError(f"--timeout must be a positive number of seconds, got {args.timeout}")
    checks = diagnose(args.config, args.socket, args.timeout, args.root)
    failed = any(c.status == FAIL for c in checks)
    if args.json:
        doc = {"ok": not failed, "checks": [c.as_dict() for c in checks]}
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
    else:
        sys.stdout.write(render(checks))
    return 1 if failed else 0
