"""Rig configuration: YAML in, frozen validated dataclasses out.

Every mistake becomes one ``ConfigError`` naming the file, the line and the key, e.g.
``rig.yaml:7: mice.left.cpi: must be a positive number, got -3``.  The YAML is parsed to
a node tree first so that each value keeps the line it came from.

A config may reference a calibration file (``calibration: rig.calib.yaml``, relative to
the config).  Values found there (per-mouse CPI and mount) override those of the config;
``mousedom calibrate ... --write`` writes that file, and the daemon rereads it on SIGHUP.
A referenced calibration file that does not exist yet is not an error: nothing has been
calibrated so far.
"""

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from mousedom import safeyaml
from mousedom.errors import UserError, located

MODELS = ("lsq", "diff-drive", "bonarini")
INTEGRATORS = ("exact", "taylor", "euler", "midpoint")
DEFAULT_CONFIG_PATH = "/etc/mousedom/mousedom.yaml"


class ConfigError(UserError):
    """A config or calibration file is wrong; the message names file, line and key."""


@dataclass(frozen=True)
class Mount:
    """Sensor position in the body frame (metres) and yaw from body x to mouse forward."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0  # radians (the YAML says degrees)


@dataclass(frozen=True)
class EvdevMatch:
    """How a config entry finds its evdev device; any given field must match."""

    path: str | None = None  # a /dev/input/by-path/... or by-id/... link, or a node
    name: str | None = None
    phys: str | None = None
    vendor: int | None = None
    product: int | None = None
    uniq: str | None = None
    grab: bool = True


@dataclass(frozen=True)
class SerialSource:
    """An ADNS-3080 downsampler on a serial port (any pyserial URL)."""

    port: str
    baud: int = 115200
    k: int = 12  # sensor frames accumulated per packet
    sensor_cpi: int = 1600  # 1600 or 400, set in the sensor by the firmware


@dataclass(frozen=True)
class MouseConfig:
    name: str
    cpi_x: float
    cpi_y: float
    mount: Mount
    flip: bool = False  # mirrored sensor: REL_X points left instead of right
    sigma: float = 0.5  # measurement noise per axis per window, in counts (for weighting)
    report_hz: float = 125.0  # nominal report rate: bounds how far back a report reaches
    evdev: EvdevMatch | None = None
    serial: SerialSource | None = None
    replay: str | None = None  # capture file (absolute, or resolved against the config)
    replay_device: str | None = None  # device name inside a multi-device capture


@dataclass(frozen=True)
class WheelsConfig:
    """Wheel-encoder geometry for the McGill reference model."""

    radius_left: float
    radius_right: float
    track: float
    ticks_per_rev: float


@dataclass(frozen=True)
class ServerConfig:
    socket: str | None = None  # None: /run/mousedom/mousedom.sock as root, else XDG dir
    mode: int = 0o660
    group: str | None = None
    control_uids: tuple[int, ...] = (0,)
    control_gids: tuple[int, ...] = ()
    max_clients: int = 32
    queue_lines: int = 256
    max_line: int = 4096


@dataclass(frozen=True)
class Config:
    rate_hz: float
    model: str
    integrator: str
    mice: tuple[MouseConfig, ...]
    server: ServerConfig = field(default_factory=ServerConfig)
    wheels: WheelsConfig | None = None
    calibration: str | None = None  # absolute path of the calibration file, if any
    path: str | None = None  # where this config was read from

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.mice)

    def mouse(self, name: str) -> MouseConfig:
        for m in self.mice:
            if m.name == name:
                return m
        raise KeyError(name)

    def index(self, name: str) -> int:
        return self.names.index(name)


# --------------------------------------------------------------------------- YAML with lines


class _Doc:
    """Parsed YAML plus the line number (1-based) of every key path."""

    def __init__(self, path: str | None, text: str) -> None:
        self.path = path
        self.lines: dict[tuple[str, ...], int] = {}
        self.problems: list[ConfigError] = []
        self.need_mounts = True
        try:
            node, loader = safeyaml.compose(text)
            try:
                self.data = loader.construct_document(node) if node is not None else None
            finally:
                loader.dispose()
        except yaml.MarkedYAMLError as e:
            mark = e.problem_mark or e.context_mark
            line = mark.line + 1 if mark else None
            raise ConfigError(located(path, line, f"invalid YAML: {e.problem or e}")) from None
        except yaml.YAMLError as e:
            raise ConfigError(located(path, None, f"invalid YAML: {e}")) from None
        if node is not None:
            self._index(node, ())

    def _index(self, node: yaml.Node, prefix: tuple[str, ...]) -> None:
        self.lines.setdefault(prefix, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            seen: set[str] = set()
            for key_node, value_node in node.value:
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
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                self._index(item, prefix + (str(i),))

    def error(self, keys: tuple[str, ...], message: str) -> ConfigError:
        line = None
        for n in range(len(keys), -1, -1):
            if keys[:n] in self.lines:
                line = self.lines[keys[:n]]
                break
        if line is None and not keys[:1]:
            line = 1  # an empty file: its first line
        where = ".".join(k if k.isprintable() else repr(k) for k in keys)
        e = ConfigError(located(self.path, line, message, where or None))
        e.line = line  # type: ignore[attr-defined]
        return e

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
        ordered = sorted(self.problems, key=lambda e: getattr(e, "line", None) or 0)
        text = "\n".join(dict.fromkeys(str(e) for e in ordered))  # each once, by line
        raise ConfigError(text)


class _Reader:
    """Typed access to one mapping of a _Doc; complains about unknown keys."""

    def __init__(
        self, doc: _Doc, value: Any, keys: tuple[str, ...], known: tuple[str, ...] = ()
    ) -> None:
        if value is None:
            value = {}
        if not isinstance(value, dict):
            raise doc.error(keys, f"must be a mapping, got {_show(value)}")
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

    def sub(self, key: str, known: tuple[str, ...] = ()) -> _Reader:
        return _Reader(self.doc, self.raw(key), self.keys + (key,), known)

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
            raise self.err(key, f"must be a number of sensible size, got {_show(v)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(key, f"must be a number, got {_show(v)}")
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
                raise self.err(key, f"must be an integer, got {_show(v)}") from None
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(key, f"must be an integer, got {_show(v)}")
        if minimum is not None and v < minimum:
            raise self.err(key, f"must be at least {minimum}, got {v}")
        return v

    def string(self, key: str, default: str | None = None) -> str | None:
        v = self.raw(key, default)
        if v is not None and not isinstance(v, str):
            raise self.err(key, f"must be a string, got {_show(v)}")
        if v is not None and "\0" in v:  # no path, name or group holds one
            raise self.err(key, f"must not contain a NUL character, got {_show(v)}")
        return v

    def boolean(self, key: str, default: bool) -> bool:
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise self.err(key, f"must be true or false, got {_show(v)}")
        return v

    def choice(self, key: str, options: tuple[str, ...], default: str) -> str:
        v = self.raw(key, default)
        if v not in options:
            raise self.err(key, f"must be one of {', '.join(options)}, got {_show(v)}")
        return v

    def finish(self) -> None:
        """Sections read without a ``known`` list: their unknown keys, all of them."""
        for k in self.value:
            if k not in self.used:
                self.doc.keep(
                    self.err(str(k), "unknown key (check the spelling; see docs/config.md)")
                )


TOP_KEYS = ("rate_hz", "model", "integrator", "mice", "server", "wheels", "calibration")
MOUSE_KEYS = ("cpi", "mount", "flip", "sigma", "report_hz", "evdev", "serial", "replay")
SERVER_KEYS = ("socket", "mode", "group", "control_uids", "control_gids", "max_clients",
               "queue_lines", "max_line")  # fmt: skip


def _show(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


# --------------------------------------------------------------------------- sections


def _cpi(r: _Reader, key: str, default: tuple[float, float] | None) -> tuple[float, float]:
    v = r.raw(key)
    if v is None:
        if default is None:
            raise r.err(key, "is required (counts per inch, a number or {x: .., y: ..})")
        return default
    if isinstance(v, dict):
        sub = r.sub(key, ("x", "y"))
        cx = sub.number("x", positive=True)
        cy = sub.number("y", positive=True)
        sub.finish()
        return cx, cy
    c = r.number(key, positive=True)
    return c, c


def _mount(r: _Reader, default: Mount | None) -> Mount:
    if not r.has("mount"):
        if default is None:
            raise r.err("mount", "is required ({x: metres, y: metres, yaw: degrees})")
        return default
    m = r.sub("mount", ("x", "y", "yaw"))
    base = default or Mount()
    x = m.number("x", base.x)
    y = m.number("y", base.y)
    yaw = math.radians(m.number("yaw", math.degrees(base.yaw)))
    m.finish()
    return Mount(x, y, yaw)


def _evdev(r: _Reader) -> EvdevMatch:
    e = r.sub("evdev", ("path", "name", "phys", "vendor", "product", "uniq", "grab"))
    match = EvdevMatch(
        path=e.string("path"),
        name=e.string("name"),
        phys=e.string("phys"),
        vendor=e.integer("vendor") if e.has("vendor") else None,
        product=e.integer("product") if e.has("product") else None,
        uniq=e.string("uniq"),
        grab=e.boolean("grab", True),
    )
    e.finish()
    if not (match.path or match.name or match.phys or match.vendor is not None or match.uniq):
        raise r.err("evdev", "needs at least one of path, name, phys, vendor/product, uniq")
    return match


def _serial(r: _Reader) -> SerialSource:
    s = r.sub("serial", ("port", "baud", "k", "sensor_cpi"))
    port = s.string("port")
    if not port:
        raise s.err("port", "is required (a device such as /dev/ttyUSB0 or a pyserial URL)")
    src = SerialSource(
        port=port,
        baud=s.integer("baud", 115200, minimum=1),
        k=s.integer("k", 12, minimum=1),
        sensor_cpi=s.integer("sensor_cpi", 1600),
    )
    if src.sensor_cpi not in (400, 1600):
        raise s.err("sensor_cpi", f"must be 400 or 1600, got {src.sensor_cpi}")
    if src.k > 255:
        raise s.err("k", f"must be at most 255, got {src.k}")
    s.finish()
    return src


def _mouse(doc: _Doc, name: str, value: Any, base_dir: Path) -> MouseConfig | None:
    """One mouse; None when it has problems (all kept in ``doc``, each part tried)."""
    r = _Reader(doc, value, ("mice", name), MOUSE_KEYS)

    def required(key: str, read: Any) -> Any:
        # "mount: is required" is noise next to "mownt: unknown key (did you mean mount?)"
        if not r.has(key) and key in r.suggested:
            return None
        return doc.attempt(read)

    cpi = required("cpi", lambda: _cpi(r, "cpi", None))
    mount = required("mount", lambda: _mount(r, None if doc.need_mounts else Mount()))
    flip = doc.attempt(r.boolean, "flip", False)
    sigma = doc.attempt(r.number, "sigma", 0.5, positive=True)
    report_hz = doc.attempt(r.number, "report_hz", 125.0, within=(1.0, 100000.0))
    sources = [k for k in ("evdev", "serial", "replay") if r.has(k)]
    if len(sources) > 1:
        doc.keep(r.err(sources[1], f"a mouse has one source; {sources[0]} is given already"))
    source: dict[str, Any] = {}
    if r.has("evdev"):
        source["evdev"] = doc.attempt(_evdev, r)
    elif r.has("serial"):
        source["serial"] = doc.attempt(_serial, r)
    elif r.has("replay"):
        source["replay"] = doc.attempt(_replay, r, base_dir)
    parts = [cpi, mount, flip, sigma, report_hz, *source.values()]
    if any(p is None for p in parts):
        return None
    mouse = MouseConfig(
        name=name, cpi_x=cpi[0], cpi_y=cpi[1], mount=mount, flip=flip, sigma=sigma,
        report_hz=report_hz,
    )  # fmt: skip
    if "evdev" in source:
        mouse = replace(mouse, evdev=source["evdev"])
    elif "serial" in source:
        mouse = replace(mouse, serial=source["serial"])
        if not r.has("report_hz"):
            # The downsampler sends one packet per K sensor polls of 1250 us (firmware/).
            mouse = replace(mouse, report_hz=1e6 / (source["serial"].k * 1250.0))
    elif "replay" in source:
        file, device = source["replay"]
        mouse = replace(mouse, replay=str(base_dir / file), replay_device=device)
    return mouse


def _replay(r: _Reader, base_dir: Path) -> tuple[str, str | None]:
    v = r.raw("replay")
    if isinstance(v, dict):
        rr = r.sub("replay", ("file", "device"))
        file = rr.string("file")
        device = rr.string("device")
    else:
        file, device = r.string("replay"), None
    if not file:
        raise r.err("replay", "needs a capture file")
    return file, device


def _server(r: _Reader) -> ServerConfig:
    s = r.sub("server", SERVER_KEYS)
    mode = s.raw("mode", 0o660)
    if isinstance(mode, str):
        try:
            mode = int(mode, 8)
        except ValueError:
            raise s.err(
                "mode", f"must be an octal file mode such as '0660', got {mode!r}"
            ) from None
    if isinstance(mode, bool) or not isinstance(mode, int) or not 0 <= mode <= 0o777:
        raise s.err("mode", f"must be a file mode between 0 and 0777, got {_show(mode)}")

    def ids(key: str, default: tuple[int, ...]) -> tuple[int, ...]:
        v = s.raw(key, list(default))
        if not isinstance(v, list) or not all(isinstance(i, int) and i >= 0 for i in v):
            raise s.err(key, f"must be a list of numeric ids, got {_show(v)}")
        return tuple(v)

    server = ServerConfig(
        socket=s.string("socket"),
        mode=mode,
        group=s.string("group"),
        control_uids=ids("control_uids", (0,)),
        control_gids=ids("control_gids", ()),
        max_clients=s.integer("max_clients", 32, minimum=1),
        queue_lines=s.integer("queue_lines", 256, minimum=1),
        max_line=s.integer("max_line", 4096, minimum=64),
    )
    s.finish()
    return server


def _wheels(r: _Reader) -> WheelsConfig:
    w = r.sub("wheels", ("radius", "radius_left", "radius_right", "track", "ticks_per_rev"))
    radius = w.number("radius", 0.0) if w.has("radius") else None
    wheels = WheelsConfig(
        radius_left=w.number("radius_left", radius, positive=True),
        radius_right=w.number("radius_right", radius, positive=True),
        track=w.number("track", positive=True),
        ticks_per_rev=w.number("ticks_per_rev", positive=True),
    )
    w.finish()
    return wheels


# --------------------------------------------------------------------------- calibration


def _apply_calibration(mice: tuple[MouseConfig, ...], path: Path) -> tuple[MouseConfig, ...]:
    try:
        text = safeyaml.read_text(path)
    except FileNotFoundError:
        return mice
    except OSError as e:
        raise ConfigError(
            located(str(path), None, f"cannot read calibration: {e.strerror}")
        ) from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: byte offset {e.start}: not UTF-8 text") from None
    doc = _Doc(str(path), text)
    top = _Reader(doc, doc.data, ())
    section = top.sub("mice")
    by_name = {m.name: m for m in mice}
    for name in section.value:
        if name not in by_name:
            raise section.err(str(name), "calibration for a mouse the config does not have")
        r = section.sub(str(name))
        m = by_name[name]
        cpi_x, cpi_y = _cpi(r, "cpi", (m.cpi_x, m.cpi_y))
        by_name[name] = replace(m, cpi_x=cpi_x, cpi_y=cpi_y, mount=_mount(r, m.mount))
        r.raw("scale")  # informational, written by `calibrate mounts`
        r.finish()
    section.finish()
    for key in top.value:  # other sections (distance, notes) are informational
        top.used.add(key)
    doc.raise_problems()
    return tuple(by_name[m.name] for m in mice)


# --------------------------------------------------------------------------- entry points


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
    doc = _Doc(path, text)
    doc.need_mounts = need_mounts
    base_dir = Path(path).resolve().parent if path else Path.cwd()
    if doc.data is None:
        raise doc.error((), "the file is empty: a rig config needs at least `mice:`")
    top = _Reader(doc, doc.data, (), TOP_KEYS)
    # Each section is read even when another failed, so that one run names every mistake.
    rate_hz = doc.attempt(top.number, "rate_hz", 100.0, within=(0.1, 10000.0)) or 100.0
    model = doc.attempt(top.choice, "model", MODELS, "lsq") or "lsq"
    integrator = doc.attempt(top.choice, "integrator", INTEGRATORS, "exact") or "exact"
    mice_raw = top.raw("mice")
    if not isinstance(mice_raw, dict) or not mice_raw:
        doc.keep(doc.error(("mice",), "needs at least one mouse (a mapping of name: settings)"))
        mice_raw = {}
    read = [
        doc.attempt(_mouse, doc, str(name), value, base_dir) for name, value in mice_raw.items()
    ]
    server = (doc.attempt(_server, top) if top.has("server") else None) or ServerConfig()
    wheels = doc.attempt(_wheels, top) if top.has("wheels") else None
    calibration = doc.attempt(top.string, "calibration")
    calibration_path = str(base_dir / calibration) if calibration else None
    doc.raise_problems()
    mice = tuple(m for m in read if m is not None)

    if calibration_path:
        mice = _apply_calibration(mice, Path(calibration_path))

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
        text = safeyaml.read_text(p)  # bounded: a reload must not swallow a 10 GB file
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
