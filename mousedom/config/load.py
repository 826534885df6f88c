"""A rig config's text -> ``Config``: the top-level keys, the small sections (robust,
wheels), the calibration overlay, the checks across sections; and reading the file."""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path

from mousedom import plausible, safeyaml
from mousedom.config import names
from mousedom.config.gyro import read_gyro
from mousedom.config.mice import apply_calibration, read_mouse
from mousedom.config.outputs import (
    ROS_TOPIC_MAX,
    Ros2Config,
    ServerConfig,
    read_outputs,
    read_server,
)
from mousedom.config.rig import (
    Config,
    GyroConfig,
    MouseConfig,
    RobustConfig,
    WheelsConfig,
    default,
)
from mousedom.fusion.choices import INTEGRATORS, MODELS
from mousedom.yamldoc import ConfigError, Reader, YamlDoc

DEFAULT_CONFIG_PATH = "/etc/mousedom/mousedom.yaml"
TOP_KEYS = ("rate_hz", "model", "integrator", "mice", "server", "wheels", "calibration",
            "robust", "outputs", "late_report_s", "gyro")  # fmt: skip


def _robust(r: Reader) -> RobustConfig:
    v = r.raw("robust")
    if isinstance(v, bool):  # `robust: false` turns it off (for comparison)
        return RobustConfig(enabled=v)
    s = r.sub("robust", ("enabled", "false_alarm", "relative_noise", "readmit_s",
                         "late_s", "learn_scale", "scale_limit"))  # fmt: skip
    d = RobustConfig()
    robust = RobustConfig(
        enabled=s.boolean("enabled", d.enabled),
        false_alarm=s.number("false_alarm", d.false_alarm, within=(1e-12, 0.5)),
        relative_noise=s.number("relative_noise", d.relative_noise, within=(0.0, 1.0)),
        readmit_s=s.number("readmit_s", d.readmit_s, within=(0.0, 3600.0)),
        late_s=s.number("late_s", d.late_s, within=(0.0, 60.0)),
        learn_scale=s.boolean("learn_scale", d.learn_scale),
        scale_limit=s.number("scale_limit", d.scale_limit, within=(0.0, 0.5)),
    )
    s.finish()
    return robust


def _wheels(r: Reader) -> WheelsConfig:
    w = r.sub("wheels", ("radius", "radius_left", "radius_right", "track", "ticks_per_rev"))
    # both wheels', unless said; checked where written (a bad one was named radius_left)
    radius = w.number("radius", positive=True) if w.has("radius") else None
    wheels = WheelsConfig(
        radius_left=w.number("radius_left", radius, positive=True),
        radius_right=w.number("radius_right", radius, positive=True),
        track=w.number("track", positive=True),
        ticks_per_rev=w.number("ticks_per_rev", positive=True),
    )
    w.finish()
    return wheels


def _written(doc: YamlDoc, prefix: tuple[str, ...], key: object) -> tuple[str, ...]:
    """The key path of a key YAML read as no text (``true``, ``null``, ``7``) as written,
    where the doc's lines know it (they hold keys as written)."""
    for path in doc.lines:
        if len(path) == len(prefix) + 1 and path[:-1] == prefix:
            if path[-1] == str(key) or safeyaml.load(path[-1]) == key:
                return path
    return (*prefix, str(key))


def _ros2_across(
    doc: YamlDoc, ros2: Ros2Config | None, gyro: GyroConfig | None, mice: tuple[MouseConfig, ...]
) -> GyroConfig | None:
    """The ROS 2 output's rules across sections: the gyro as the output makes it (returned),
    the mice's counts topics within ROS 2's length."""
    if ros2 is None:
        return gyro
    if gyro is not None and gyro.ros2 is not None:
        # One robot, one ROS 2 graph: a gyro read from ROS 2 is on the output's domain
        # unless it names its own, and its reader's node in the output's namespace (two
        # robots on one domain would otherwise both announce /mousedom_gyro).
        gyro = replace(gyro, ros2=replace(gyro.ros2, output_domain=ros2.domain_id,
                                          namespace=ros2.namespace))  # fmt: skip
    if ros2.counts:
        # each mouse's counts topic (ros2conv.counts_topic under the namespace) within
        # ROS 2's length, as the output's own topics are (config.outputs)
        for m in mice:
            full = f"{ros2.namespace}/mousedom/{names.ros_token(m.name)}/counts"
            if len(full) > ROS_TOPIC_MAX:
                raise doc.error(("mice", m.name), f"its ROS 2 counts topic is {len(full)} "
                                f"characters, over ROS 2's {ROS_TOPIC_MAX} (outputs.ros2."
                                "counts: a shorter name)")  # fmt: skip
    return gyro


def queue_lines_needed(sensors: int) -> int:
    """The least ``server.queue_lines`` for a rig of ``sensors`` sensors.  The server answers
    a client's command while its owed lines fill less than half the queue (back-pressure,
    server.Server._answer_some); a ``status`` answer and what goes ahead of it (each
    sensor's SOURCE waiting, the latest POSE) add up to 2 x sensors + 2 lines, so half the
    queue must hold that and a few more (a VERSION, an ERROR): below it, a client that read
    as fast as it could was dropped for a full queue, and with 1 no command was ever
    answered."""
    return 4 * (sensors + 2)


def parse_config(
    text: str,
    path: str | None = None,
    *,
    need_sources: bool = True,
    need_model: bool = True,
    need_mounts: bool = True,
) -> Config:
    """Parse and validate a config given as text.

    ``need_sources=False`` lets mice leave out where they come from (replay and
    calibration supply captures on the command line instead).  A tool that does not fuse
    validates only what it uses: ``need_model=False`` skips the check that the model can
    be solved from the mice (one mouse on a calibration jig is a fine rig for
    ``calibrate cpi``), ``need_mounts=False`` lets mice leave out their mount (taken as
    the body origin).
    """
    doc = YamlDoc(path, text)
    doc.need_mounts = need_mounts
    base_dir = Path(path).resolve().parent if path else Path.cwd()
    if doc.data is None:
        raise doc.error((), "the file is empty: a rig config needs at least `mice:`")
    top = Reader(doc, doc.data, (), TOP_KEYS)
    # Each section is read even when another failed, so that one run names every mistake;
    # a value that failed is None, and raise_problems below raises before it is used.
    rate_hz = doc.attempt(top.number, "rate_hz", default(Config, "rate_hz", float),
                          within=(0.1, 10000.0))  # fmt: skip
    model = doc.attempt(top.choice, "model", MODELS, default(Config, "model", str))
    integrator = doc.attempt(top.choice, "integrator", INTEGRATORS,
                             default(Config, "integrator", str))  # fmt: skip
    late = doc.attempt(top.number, "late_report_s", default(Config, "late_report_s", float),
                       within=(0.0, 1.0))  # fmt: skip
    mice_raw = top.raw("mice")
    if not isinstance(mice_raw, dict) or not mice_raw:
        doc.keep(doc.error(("mice",), "needs at least one mouse (a mapping of name: settings)"))
        mice_raw = {}
    for name in mice_raw:
        # A key YAML reads as no text (`true:`, `null:`, `1:`) was the mouse "True",
        # "None" or "1"; an empty one, a mouse with no name in any column or topic.
        if not isinstance(name, str):
            doc.keep(doc.error(_written(doc, ("mice",), name),
                               f"a mouse's name must be text, got {name!r}: quote it"))  # fmt: skip
        elif not name.strip():
            doc.keep(doc.error(("mice", name), "a mouse's name is empty"))
        elif not name.isprintable():  # (a newline split every log line naming it in two)
            doc.keep(doc.error(("mice", name), "a mouse's name may not hold control "
                                               "characters (a newline, a tab...)"))  # fmt: skip
    read = [
        doc.attempt(read_mouse, doc, str(name), value, base_dir)
        for name, value in mice_raw.items()
        if isinstance(name, str) and name.strip() and name.isprintable()
    ]
    server = (doc.attempt(read_server, top) if top.has("server") else None) or ServerConfig()
    wheels = doc.attempt(_wheels, top) if top.has("wheels") else None
    robust = (doc.attempt(_robust, top) if top.has("robust") else None) or RobustConfig()
    outputs = doc.attempt(read_outputs, top) if top.has("outputs") else None
    ros2, foxglove, metrics = outputs or (None, None, None)
    gyro = (doc.attempt(read_gyro, top, need_sources=need_sources, base_dir=base_dir)
            if top.has("gyro") else None)  # fmt: skip
    calibration = doc.attempt(top.string, "calibration")
    if calibration is not None and not calibration.strip():  # (it read as no file at all)
        doc.keep(top.err("calibration", "is empty: a file name, or leave the key out"))
    calibration_path = str(base_dir / calibration) if calibration else None
    doc.raise_problems()
    mice = tuple(m for m in read if m is not None)
    clashed = names.clash([m.name for m in mice])
    if clashed:
        raise doc.error(("mice",), clashed)
    gyro = _ros2_across(doc, ros2, gyro, mice)
    sensors = len(mice) + (gyro is not None)
    least = queue_lines_needed(sensors)
    if server.queue_lines < least:
        raise doc.error(("server", "queue_lines"),
                        f"{server.queue_lines} lines cannot hold a status answer and what waits "
                        f"before it for {sensors} sensors: at least {least}")  # fmt: skip

    found = plausible.suspects([(m.name, m.cpi_x, m.cpi_y, m.mount.x, m.mount.y,
                                 math.degrees(m.mount.yaw)) for m in mice])  # fmt: skip
    warnings = tuple(
        str(doc.error(s.keys, s.message))
        for s in found  # file:line: key: message
    )
    if calibration_path:
        mice, calibrated = apply_calibration(mice, Path(calibration_path))
        warnings += tuple(calibrated)

    if need_sources:
        for m in mice:
            if not (m.evdev or m.serial or m.replay):
                doc.keep(doc.error(
                    ("mice", m.name),
                    "says nowhere where the mouse comes from (evdev, serial or replay)",
                ))  # fmt: skip
        doc.raise_problems()

    from mousedom.fusion.geometry import rank_problem  # late import: geometry is numeric

    problem = rank_problem(model, [(m.mount.x, m.mount.y) for m in mice], [m.name for m in mice])
    if problem and need_model:
        raise doc.error(("mice",), f"model {model}: {problem}")
    return Config(
        rate_hz=rate_hz,
        model=model,
        integrator=integrator,
        mice=mice,
        server=server,
        wheels=wheels,
        calibration=calibration_path,
        path=path,
        lines=dict(doc.lines),
        robust=robust,
        late_report_s=late,
        ros2=ros2,
        foxglove=foxglove,
        metrics=metrics,
        gyro=gyro,
        warnings=warnings,
    )


def load_config(
    path: str | os.PathLike[str],
    *,
    need_sources: bool = True,
    need_model: bool = True,
    need_mounts: bool = True,
) -> Config:
    """Read a config file; every problem is a ConfigError naming file, line and key."""
    p = str(path)
    try:
        text = safeyaml.read_text(
            p, safeyaml.CONFIG_MAX_BYTES
        )  # bounded: a reload must not swallow a 10 GB file
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a directory, not a config file") from None
    except OSError as e:
        raise ConfigError(f"{p}: cannot read config: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{p}: byte offset {e.start}: not UTF-8 text") from None
    return parse_config(
        text, p, need_sources=need_sources, need_model=need_model, need_mounts=need_mounts
    )
