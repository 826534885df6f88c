"""`mousedom check-config`: load a rig config (and its calibration) and say what it holds."""

from __future__ import annotations

import argparse
import math

from mousedom.config import DEFAULT_CONFIG_PATH, load_config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check-config", help="validate a rig config and print what it holds")
    p.add_argument("--config", default=DEFAULT_CONFIG_PATH, help="rig YAML")
    p.add_argument(
        "--no-sources", action="store_true", help="allow mice without a source (replay rigs)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config, need_sources=not args.no_sources)
    print(f"{cfg.path}: {cfg.model} model, {cfg.integrator} integrator, {cfg.rate_hz:g} Hz")
    for m in cfg.mice:
        source = "evdev" if m.evdev else "serial" if m.serial else "replay" if m.replay else "none"
        print(
            f"  {m.name}: cpi {m.cpi_x:g}/{m.cpi_y:g}, mount ({m.mount.x:g}, {m.mount.y:g}) m, "
            f"yaw {math.degrees(m.mount.yaw):g} deg{', flipped' if m.flip else ''}, "
            f"source {source}"
        )
    if cfg.calibration:
        print(f"  calibration: {cfg.calibration}")
    return 0
