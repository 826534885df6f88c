"""The ``mice:`` section: each mouse's CPI, mount, source and limits; and the calibration
file whose CPI and mounts override the config's."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from mousedom import plausible, safeyaml
from mousedom.config.rig import (
    ADNS3080_MAX_SPEED,
    ADNS3080_MIN_SQUAL,
    EvdevMatch,
    Mount,
    MouseConfig,
    SerialSource,
    default,
)
from mousedom.errors import located
from mousedom.yamldoc import ConfigError, Reader, YamlDoc

MOUSE_KEYS = ("cpi", "mount", "flip", "sigma", "report_hz", "evdev", "serial", "replay",
              "max_speed", "min_squal")  # fmt: skip


# Hard limits, beyond the plausible ranges that only warn (mousedom.plausible): values past
# these are no rig, and break the arithmetic.  A CPI of 1e-300 overflows a count to inf (a
# replay's traceback); a mount of 1e308 overflows the geometry; a sigma 1e8 times another
# mouse's makes the weighted normal equations singular (a reload that killed the daemon).
# Sigma within 0.01-10,000 counts keeps the weights' ratio at 1e12, four decades short of
# that; a count's rounding alone is 0.29 counts, so no mouse is known 0.01 counts well.
CPI_LIMITS = (1.0, 1e6)
SIGMA_LIMITS = (0.01, 1e4)
MOUNT_LIMIT_M = 1000.0


def _cpi(r: Reader, key: str, default: tuple[float, float] | None) -> tuple[float, float]:
    v = r.raw(key)
    if v is None:
        if default is None:
            raise r.err(key, "is required (counts per inch, a number or {x: .., y: ..})")
        return default
    if isinstance(v, dict):
        sub = r.sub(key, ("x", "y"))
        cx = sub.number("x", positive=True, within=CPI_LIMITS)
        cy = sub.number("y", positive=True, within=CPI_LIMITS)
        sub.finish()
        return cx, cy
    c = r.number(key, positive=True, within=CPI_LIMITS)
    return c, c


def _mount(r: Reader, default: Mount | None) -> Mount:
    # `mount:` with nothing after it is no mount given (a line left to fill in): it was
    # read as (0, 0, 0), where leaving the key out is an error.  `mount: {}` says each of
    # x, y and yaw is its default, 0, as `{x: 0.1}` says y and yaw are.
    if not r.has("mount") or r.raw("mount") is None:
        if default is None:
            what = "is empty" if r.has("mount") else "is required"
            raise r.err("mount", f"{what} ({{x: metres, y: metres, yaw: degrees}})")
        return default
    m = r.sub("mount", ("x", "y", "yaw"))
    base = default or Mount()
    x = m.number("x", base.x, within=(-MOUNT_LIMIT_M, MOUNT_LIMIT_M))
    y = m.number("y", base.y, within=(-MOUNT_LIMIT_M, MOUNT_LIMIT_M))
    yaw = math.radians(m.number("yaw", math.degrees(base.yaw)))
    m.finish()
    return Mount(x, y, yaw)


def _evdev(r: Reader) -> EvdevMatch:
    e = r.sub("evdev", ("path", "name", "phys", "vendor", "product", "uniq", "grab"))
    match = EvdevMatch(
        path=e.string("path"),
        name=e.string("name"),
        phys=e.string("phys"),
        vendor=e.integer("vendor") if e.has("vendor") else None,
        product=e.integer("product") if e.has("product") else None,
        uniq=e.string("uniq"),
        grab=e.boolean("grab", default(EvdevMatch, "grab", bool)),
    )
    e.finish()
    for key, value in (("vendor", match.vendor), ("product", match.product)):
        if value is not None and not 0 <= value <= 0xFFFF:  # (never matches a device)
            raise e.err(key, f"must be a USB id of 16 bits (0 to 0xffff), got {value:#x}")
    if not (match.path or match.name or match.phys or match.uniq
            or match.vendor is not None or match.product is not None):  # fmt: skip
        raise r.err("evdev", "needs at least one of path, name, phys, vendor/product, uniq")
    return match


def _serial(r: Reader) -> SerialSource:
    s = r.sub("serial", ("port", "baud", "k", "sensor_cpi"))
    port = s.string("port")
    if not port:
        raise s.err("port", "is required (a device such as /dev/ttyUSB0 or a pyserial URL)")
    src = SerialSource(
        port=port,
        baud=s.integer("baud", default(SerialSource, "baud", int), minimum=1),
        k=s.integer("k", default(SerialSource, "k", int), minimum=1),
        sensor_cpi=s.integer("sensor_cpi", default(SerialSource, "sensor_cpi", int)),
    )
    if src.sensor_cpi not in (400, 1600):
        raise s.err("sensor_cpi", f"must be 400 or 1600, got {src.sensor_cpi}")
    if src.k > 255:
        raise s.err("k", f"must be at most 255, got {src.k}")
    s.finish()
    return src


def read_replay(r: Reader, base_dir: Path) -> tuple[str, str | None]:
    """A ``replay:`` key (a file, or ``{file, device}``): the file as written and the
    device (None: the capture's only one, or the one the sensor's name picks)."""
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


def read_mouse(doc: YamlDoc, name: str, value: Any, base_dir: Path) -> MouseConfig | None:
    """One mouse; None when it has problems (all kept in ``doc``, each part tried)."""
    r = Reader(doc, value, ("mice", name), MOUSE_KEYS)

    def required(key: str, read: Any) -> Any:
        # "mount: is required" is noise next to "mownt: unknown key (did you mean mount?)"
        if not r.has(key) and key in r.suggested:
            return None
        return doc.attempt(read)

    cpi = required("cpi", lambda: _cpi(r, "cpi", None))
    mount = required("mount", lambda: _mount(r, None if doc.need_mounts else Mount()))
    flip = doc.attempt(r.boolean, "flip", default(MouseConfig, "flip", bool))
    sigma = doc.attempt(r.number, "sigma", default(MouseConfig, "sigma", float), positive=True,
                        within=SIGMA_LIMITS)  # fmt: skip
    report_hz = doc.attempt(r.number, "report_hz", default(MouseConfig, "report_hz", float),
                            within=(1.0, 100000.0))  # fmt: skip
    # Present or None: these two have no default for a USB mouse.
    max_speed = doc.attempt(r.number, "max_speed", positive=True) if r.has(
        "max_speed") else None  # fmt: skip
    min_squal = doc.attempt(r.integer, "min_squal", minimum=0) if r.has(
        "min_squal") else None  # fmt: skip
    sources = [k for k in ("evdev", "serial", "replay") if r.has(k)]
    if len(sources) > 1:
        doc.keep(r.err(sources[1], f"a mouse has one source; {sources[0]} is given already"))
    source: dict[str, Any] = {}
    if r.has("evdev"):
        source["evdev"] = doc.attempt(_evdev, r)
    elif r.has("serial"):
        source["serial"] = doc.attempt(_serial, r)
    elif r.has("replay"):
        source["replay"] = doc.attempt(read_replay, r, base_dir)
    parts = [cpi, mount, flip, sigma, report_hz, *source.values()]
    if any(p is None for p in parts):
        return None
    mouse = MouseConfig(
        name=name, cpi_x=cpi[0], cpi_y=cpi[1], mount=mount, flip=flip, sigma=sigma,
        report_hz=report_hz, max_speed=max_speed, min_squal=min_squal,
    )  # fmt: skip
    if "evdev" in source:
        mouse = replace(mouse, evdev=source["evdev"])
    elif "serial" in source:
        mouse = replace(mouse, serial=source["serial"])
        # The sensor's own limits are known; a USB mouse's are not (none unless set).
        if max_speed is None:
            mouse = replace(mouse, max_speed=ADNS3080_MAX_SPEED)
        if min_squal is None:
            mouse = replace(mouse, min_squal=ADNS3080_MIN_SQUAL)
        if not r.has("report_hz"):
            # The downsampler sends one packet per K sensor polls of 1250 us (firmware/).
            mouse = replace(mouse, report_hz=1e6 / (source["serial"].k * 1250.0))
    elif "replay" in source:
        file, device = source["replay"]
        mouse = replace(mouse, replay=str(base_dir / file), replay_device=device)
    return mouse


def apply_calibration(
    mice: tuple[MouseConfig, ...], path: Path
) -> tuple[tuple[MouseConfig, ...], list[str]]:
    """``mice`` with the CPI and mounts of the calibration file at ``path`` (schema:
    mousedom.calibrate.calfile), unchanged if the file does not exist yet; and warnings
    (``file:line: key: message``) for a calibrated CPI no mouse reports
    (``plausible.cpi_problem``), as the config's own CPI gets."""
    try:
        text = safeyaml.read_text(path, safeyaml.CONFIG_MAX_BYTES)
    except FileNotFoundError:
        return mice, []
    except OSError as e:
        raise ConfigError(
            located(str(path), None, f"cannot read calibration: {e.strerror}")
        ) from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: byte offset {e.start}: not UTF-8 text") from None
    doc = YamlDoc(str(path), text)
    top = Reader(doc, doc.data, ())
    section = top.sub("mice")
    by_name = {m.name: m for m in mice}
    warnings: list[str] = []
    for name in section.value:
        if name not in by_name:
            raise section.err(str(name), "calibration for a mouse the config does not have")
        r = section.sub(str(name), ("cpi", "mount", "scale"))
        m = by_name[name]
        cpi_x, cpi_y = _cpi(r, "cpi", (m.cpi_x, m.cpi_y))
        by_name[name] = replace(m, cpi_x=cpi_x, cpi_y=cpi_y, mount=_mount(r, m.mount))
        if r.has("cpi"):
            for v in dict.fromkeys((cpi_x, cpi_y)):
                problem = plausible.cpi_problem(v)
                if problem:
                    warnings.append(str(doc.error(("mice", str(name), "cpi"), problem)))
        r.raw("scale")  # informational, written by `calibrate mounts`
        r.finish()
    section.finish()
    for key in top.value:  # other sections (distance, notes) are informational
        top.used.add(key)
    doc.raise_problems()
    return tuple(by_name[m.name] for m in mice), warnings
