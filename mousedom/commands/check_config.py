"""`mousedom check-config`: load a rig config (and its calibration) and say what it holds."""

from __future__ import annotations

import argparse
import math
import os
import sys

from mousedom.commands import _options as options
from mousedom.config import Config, ConfigError, GyroConfig, MouseConfig, load_config
from mousedom.errors import UserError
from mousedom.observability import blind_spots


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "check-config",
        help="validate a rig config and print what it holds",
        description="Load a rig config and its calibration file, check every key (each "
        "mistake is reported with file, line and key), and print the rig: model, rate, "
        "each mouse's CPI, mount and source, and the gyro's. Exit 0 when it would run.",
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


def _captures(cfg: Config) -> list[tuple[tuple[str, ...], str]]:
    """(key, file) of each capture the rig replays: the mice's and the gyro's."""
    out: list[tuple[tuple[str, ...], str]] = [
        (("mice", m.name, "replay"), m.replay) for m in cfg.mice if m.replay
    ]
    if cfg.gyro is not None and cfg.gyro.replay:
        out.append((("gyro", "replay"), cfg.gyro.replay))
    return out


def _devices(cfg: Config) -> list[tuple[str, str]]:
    """(key, path) of each device node or port the rig names by path: mice and gyro."""
    out = [(f"mice.{m.name}", dev) for m in cfg.mice if (dev := _device(m))]
    if cfg.gyro is not None and cfg.gyro.path:
        out.append(("gyro", cfg.gyro.path))
    return out


def _shared_paths(mice) -> list[tuple[str, list[str]]]:
    """Device paths that two or more mice name (after following links)."""
    by_path: dict[str, list[str]] = {}
    for m in mice:
        dev = _device(m)
        if dev:
            by_path.setdefault(os.path.realpath(dev), []).append(m.name)
    return [(p, names) for p, names in by_path.items() if len(names) > 1]


def _gyro(g: GyroConfig) -> str:
    """The gyro's line: where its rate comes from, how it is mounted, what it is used for."""
    if g.replay is not None:
        source = f"replay {g.replay}" + (f" device {g.replay_device!r}" if g.replay_device else "")
    elif g.ros2 is not None:
        r = g.ros2
        domain = r.domain_id if r.domain_id is not None else "$ROS_DOMAIN_ID"
        source = f"ROS 2 topic {r.topic} (domain {domain}, stamps {r.stamps})"
    else:
        match = ", ".join(f"{k} {v!r}" for k, v in (("path", g.path), ("name", g.name)) if v)
        source = f"IIO device ({match})"
    rate = f"{g.sample_hz:g} Hz" if g.sample_hz is not None else "the device's own rate"
    sign = "-" if g.sign < 0 else "+"
    heading = {"both": "the gyro and the mice", "gyro": "the gyro", "mice": "the mice"}[g.use]
    return (
        f"  gyro: {source}, axis {sign}{g.axis} along body z, {rate}, noise "
        f"{g.noise:g} rad/s/sqrt(Hz), heading from {heading}"
    )


def _limits(m) -> str:
    parts = []
    if m.max_speed is not None:
        parts.append(f"tracks up to {m.max_speed:g} m/s")
    if m.min_squal is not None:
        parts.append(f"SQUAL at least {m.min_squal}")
    return "; " + ", ".join(parts) if parts else ""


def _print_rig(cfg: Config) -> None:
    """What the rig holds, a line a part: the mice, the gyro, fault tolerance (with what
    the layout hides from it), the ROS 2 output."""
    for m in cfg.mice:
        print(
            f"  {m.name}: cpi {m.cpi_x:g}/{m.cpi_y:g}, mount ({m.mount.x:g}, {m.mount.y:g}) m, "
            f"yaw {math.degrees(m.mount.yaw):g} deg{', flipped' if m.flip else ''}, "
            f"{m.report_hz:g} Hz, source {_source(m)}{_limits(m)}"
        )
    if cfg.gyro is not None:
        print(_gyro(cfg.gyro))
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
    _print_rig(cfg)
    shared = _shared_paths(cfg.mice)
    if shared:
        path, names = shared[0]
        raise UserError(
            f"{cfg.path}: mice {' and '.join(names)} name one device, {path}: one device "
            "cannot be two mice (the daemon would keep the second out)"
        )
    for keys, capture in _captures(cfg):
        if not os.path.isfile(capture):  # `mousedom run` would stop on it: not valid yet
            raise UserError(cfg.locate(keys, f"{capture}: capture file not found"))
    if _captures(cfg):
        # The devices in them, as replay and run map them onto the mice: a replay.device
        # that is not in its file passed here and stopped `replay` and `run`.
        from mousedom.capture import assign

        assign(cfg, [], require_all=False)
    if cfg.calibration:
        state = "applied" if os.path.exists(cfg.calibration) else "not written yet"
        print(f"  calibration: {cfg.calibration} ({state})")
    absent = [(key, dev) for key, dev in _devices(cfg) if not os.path.exists(dev)]
    for key, dev in absent:
        print(f"  note: {key}: {dev} does not exist on this machine")
    if absent and args.require_devices:
        raise UserError(f"{cfg.path}: {len(absent)} device(s) absent (--require-devices)", 1)
    return 0
