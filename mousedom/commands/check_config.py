"""`mousedom check-config`: load a rig config (and its calibration) and say what it holds."""

from __future__ import annotations

import argparse
import math
import os
import sys

from mousedom.commands import _options as options
from mousedom.config import ConfigError, MouseConfig, load_config
from mousedom.errors import UserError
from mousedom.observability import blind_spots


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "check-config",
        help="validate a rig config and print what it holds",
        description="Load a rig config and its calibration file, check every key (each "
        "mistake is reported with file, line and key), and print the rig: model, rate, "
        "and each mouse's CPI, mount and source. Exit 0 when it would run.",
    )
    options.add_default_config(p)
    p.add_argument(
        "--require-devices",
        action="store_true",
        help="exit 1 when a configured device or serial port is absent on this machine "
        "(by default that is a note: the config may be for the robot, not this machine)",
    )
    p.add_argument(
        "--no-sources", action="store_true", help="allow mice without a source (replay rigs)"
    )
    p.set_defaults(func=run)


def _source(m: MouseConfig) -> str:
    if m.evdev:
        e = m.evdev
        keys = ("path", "name", "phys", "uniq", "vendor", "product")
        match = ", ".join(f"{k} {getattr(e, k)!r}" for k in keys if getattr(e, k) is not None)
        return f"evdev ({match or 'any'}{'' if e.grab else ', not grabbed'})"
    if m.serial:
        s = m.serial
        return f"serial {s.port} ({s.baud} baud, k {s.k}, sensor {s.sensor_cpi} cpi)"
    if m.replay:
        return f"replay {m.replay}" + (f" device {m.replay_device!r}" if m.replay_device else "")
    return "none"


def _device(m: MouseConfig) -> str | None:
    """The device node or serial port a mouse names, when it names one by path."""
    if m.evdev and m.evdev.path:
        return m.evdev.path
    if m.serial and "://" not in m.serial.port:  # pyserial URLs (loop://) are no file
        return m.serial.port
    return None


def _shared_paths(mice) -> list[tuple[str, list[str]]]:
    """Device paths that two or more mice name (after following links)."""
    by_path: dict[str, list[str]] = {}
    for m in mice:
        dev = _device(m)
        if dev:
            by_path.setdefault(os.path.realpath(dev), []).append(m.name)
    return [(p, names) for p, names in by_path.items() if len(names) > 1]


def _limits(m) -> str:
    parts = []
    if m.max_speed is not None:
        parts.append(f"tracks up to {m.max_speed:g} m/s")
    if m.min_squal is not None:
        parts.append(f"SQUAL at least {m.min_squal}")
    return "; " + ", ".join(parts) if parts else ""


def run(args: argparse.Namespace) -> int:
    try:
        cfg = load_config(args.config, need_sources=not args.no_sources)
    except ConfigError as e:
        if args.no_sources:
            raise
        # The only problem may be mice without a source: say how to check such a rig.
        try:
            load_config(args.config, need_sources=False)
        except UserError:
            raise e from None
        raise UserError(f"{e} (a rig for captures only: add --no-sources)") from None
    for w in cfg.warnings:  # values that look like the wrong unit (mousedom.plausible)
        print(f"mousedom: warning: {w}", file=sys.stderr)
    print(f"{cfg.path}: {cfg.model} model, {cfg.integrator} integrator, {cfg.rate_hz:g} Hz")
    for m in cfg.mice:
        print(
            f"  {m.name}: cpi {m.cpi_x:g}/{m.cpi_y:g}, mount ({m.mount.x:g}, {m.mount.y:g}) m, "
            f"yaw {math.degrees(m.mount.yaw):g} deg{', flipped' if m.flip else ''}, "
            f"{m.report_hz:g} Hz, source {_source(m)}{_limits(m)}"
        )
    r = cfg.robust
    print(
        "  fault tolerance: "
        + (
            f"on (false alarm {r.false_alarm:g} per window, relative noise {r.relative_noise:g}, "
            f"re-admission after {r.readmit_s:g} s)"
            if r.enabled
            else "off (robust: false)"
        )
    )
    if r.enabled:  # what the layout hides from the fault test (mousedom.observability)
        mounts = [(m.name, m.mount.x, m.mount.y) for m in cfg.mice]
        for note in blind_spots(cfg.model, mounts, r.relative_noise, r.false_alarm):
            print(f"  note: {note}")
    if cfg.ros2 is not None:
        from mousedom.service.ros2conv import topic

        o = cfg.ros2
        domain = o.domain_id if o.domain_id is not None else "$ROS_DOMAIN_ID"
        print(
            f"  ROS 2 output: {topic(o, o.odom_topic)} ({o.odom_frame} -> {o.base_frame}), "
            f"domain {domain}, stamps {o.stamps}"
            + (f", tf {topic(o, o.tf_topic)}" if o.publish_tf or o.publish_map_tf else "")
        )
    shared = _shared_paths(cfg.mice)
    if shared:
        path, names = shared[0]
        raise UserError(
            f"{cfg.path}: mice {' and '.join(names)} name one device, {path}: one device "
            "cannot be two mice (the daemon would keep the second out)"
        )
    missing = [m for m in cfg.mice if m.replay and not os.path.isfile(m.replay)]
    if missing:  # `mousedom run` would stop on it: not a valid rig yet
        m = missing[0]
        raise UserError(f"{cfg.path}: mice.{m.name}.replay: {m.replay}: capture file not found")
    if cfg.calibration:
        state = "applied" if os.path.exists(cfg.calibration) else "not written yet"
        print(f"  calibration: {cfg.calibration} ({state})")
    absent = [(m, dev) for m in cfg.mice if (dev := _device(m)) and not os.path.exists(dev)]
    for m, dev in absent:
        print(f"  note: mice.{m.name}: {dev} does not exist on this machine")
    if absent and args.require_devices:
        raise UserError(f"{cfg.path}: {len(absent)} device(s) absent (--require-devices)", 1)
    return 0
