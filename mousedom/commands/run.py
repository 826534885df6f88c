"""``mousedom run``: the daemon in the foreground (systemd runs exactly this)."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import logging
import os
import sys
from typing import TYPE_CHECKING

from mousedom import invocation
from mousedom.commands import _options as options
from mousedom.config import (
    DEFAULT_CONFIG_PATH,
    Config,
    ConfigError,
    MetricsConfig,
    Ros2Config,
    load_config,
)
from mousedom.errors import UserError

if TYPE_CHECKING:
    from mousedom.service.output import Output

log = logging.getLogger(__name__)

# syslog priorities (sd-daemon(3)): journald reads a "<N>" prefix on each stderr line.
_PRIORITY = {
    logging.DEBUG: 7,
    logging.INFO: 6,
    logging.WARNING: 4,
    logging.ERROR: 3,
    logging.CRITICAL: 2,
}


class JournalFormatter(logging.Formatter):
    """``<priority>logger: message``: journald stamps and levels each line itself."""

    def format(self, record: logging.LogRecord) -> str:
        prio = _PRIORITY.get(record.levelno, 6)
        text = super().format(record)
        # One record may span lines (tracebacks): prefix each so none loses its level.
        return "\n".join(f"<{prio}>{line}" for line in text.splitlines())


def configure_logging(verbose: bool, environ: dict[str, str] | None = None) -> None:
    """Under systemd (JOURNAL_STREAM set) log with priority prefixes, else level names."""
    env = os.environ if environ is None else environ
    root = logging.getLogger()
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    if env.get("JOURNAL_STREAM"):
        formatter: logging.Formatter = JournalFormatter("%(name)s: %(message)s")
    else:
        formatter = logging.Formatter("%(levelname)s %(name)s: %(message)s")
    if not root.handlers:
        root.addHandler(logging.StreamHandler(sys.stderr))
    for handler in root.handlers:
        handler.setFormatter(formatter)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run",
        help="run the odometry daemon (socket publisher)",
        description="Read the configured mice, fuse them and publish the pose on a Unix "
        "socket until SIGTERM/SIGINT; SIGHUP reloads the config and calibration.",
    )
    options.add_config(p, f"the rig config (default {DEFAULT_CONFIG_PATH})")
    p.add_argument("--socket", metavar="PATH", help="Unix socket path (default: see docs)")
    p.add_argument(
        "--demo",
        action="store_true",
        help="run on the bundled capture of a simulated rig, replayed in real time, looping",
    )
    p.add_argument(
        "--record",
        metavar="FILE",
        help="also write every sensor report to FILE (native capture, for mousedom replay)",
    )
    p.add_argument(
        "--ros2",
        action="store_true",
        help="also publish /odom, /tf and /diagnostics to ROS 2 over DDS (the config's "
        "outputs.ros2, or its defaults; domain $ROS_DOMAIN_ID; needs mousedom[ros2])",
    )
    p.add_argument(
        "--metrics",
        action="store_true",
        help="also serve Prometheus metrics over HTTP (the config's outputs.metrics, or "
        "127.0.0.1:9464; needs mousedom[metrics]; docs/metrics.md)",
    )
    p.add_argument(
        "--record-mcap",
        metavar="OUT.mcap",
        help="also write the poses as a ROS 2 MCAP recording (Foxglove, ros2 bag)",
    )
    p.add_argument(
        "--verbose", action="store_true", default=argparse.SUPPRESS, help="debug logging"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mousedom import hangup
    from mousedom.service.daemon import Daemon, make_source
    from mousedom.service.socketfile import default_socket_path

    configure_logging(bool(getattr(args, "verbose", False)))
    config = _config(args)
    for w in config.warnings:  # values that look like the wrong unit
        log.warning("%s", w)
    if config.metrics is not None:  # its install hint before any sensor is opened
        from mousedom.service.metrics import require

        require()
    from mousedom.safewrite import refuse_shared_outputs

    refuse_shared_outputs([("--record", args.record), ("--record-mcap", args.record_mcap)])
    outputs: list[Output] = []
    try:
        _start_outputs(args, config, outputs)
        socket_path = args.socket or config.server.socket or default_socket_path()
        factory = functools.partial(make_source, loop=True) if args.demo else make_source
        # (this process is the daemon's: its heap is frozen from the collector's scans)
        daemon = Daemon(config, socket_path, source_factory=factory, record=args.record,
                        outputs=outputs, freeze_heap=True,
                        pending_reload=hangup.pending)  # fmt: skip
        return daemon.run()
    finally:
        for out in outputs:
            try:
                out.close()
            except UserError as e:
                log.error("%s", e)


def _config(args: argparse.Namespace) -> Config:
    """The rig: the demo's, or the file's, with what --ros2 and --metrics turn on."""
    if args.demo:
        if args.config:
            raise UserError("--demo and --config exclude each other")
        from mousedom.demo import demo_config

        config = demo_config()
        log.info("demo: a simulated rig replayed in real time, in a loop (%s)", config.path)
    else:
        path = args.config or DEFAULT_CONFIG_PATH
        try:
            config = load_config(path)
        except ConfigError as e:
            if args.config is None and not os.path.exists(path):
                demo = invocation.command("run", "--demo")
                raise ConfigError(f"{e} (give --config FILE, or try: {demo})") from None
            raise
    if args.ros2 and config.ros2 is None:
        config = dataclasses.replace(config, ros2=Ros2Config())
    if args.metrics and config.metrics is None:
        config = dataclasses.replace(config, metrics=MetricsConfig())
    return config


def _start_outputs(args: argparse.Namespace, config: Config, outputs: list[Output]) -> None:
    """The optional outputs the config and the options ask for, appended to ``outputs``
    as each starts (so that the caller closes those that did if a later one fails)."""
    if config.ros2 is not None:
        from mousedom.service.ros2out import Ros2Output, Ros2Unavailable

        try:
            outputs.append(Ros2Output(config.ros2, config.names, config.rate_hz, config.mice))
        except Ros2Unavailable as e:
            if not config.ros2.optional:
                raise
            log.error("%s; going on without it (outputs.ros2.optional)", e)
    if config.foxglove is not None:
        from mousedom.service.foxgloveout import FoxgloveOutput

        outputs.append(FoxgloveOutput(config.foxglove, config.names, config.mice))
    if args.record_mcap:
        from mousedom.capture.assignment import config_inputs
        from mousedom.service.mcapout import McapRecorder, system_offset

        inputs = config_inputs(config)
        outputs.append(McapRecorder(args.record_mcap, config.ros2 or Ros2Config(),
                                    config.names, config.rate_hz, inputs,
                                    offset=system_offset(config.ros2), live=True))  # fmt: skip
