"""Which capture device is which mouse of the config.

``parse_capture_arg`` reads one ``--capture`` argument; ``assign`` opens every capture
given (and the config's own ``replay:`` files) and maps one device onto each mouse:
by the name given on the command line, by the device's name, node or evdev rule, or as
the only device of its file that moves.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass

from mousedom.capture.base import GYRO_KIND, Capture, CaptureError, DeviceInfo
from mousedom.capture.evemu import companion
from mousedom.capture.sniff import open_capture
from mousedom.config import Config, EvdevMatch, MouseConfig
from mousedom.errors import escaped


def parse_capture_arg(arg: str) -> tuple[str | None, str]:
    """``NAME=FILE`` -> (NAME, FILE); ``FILE`` -> (None, FILE).

    A file whose own name holds ``=`` is taken whole when it exists.
    """
    name, sep, file = arg.partition("=")
    if not sep or os.path.exists(arg):
        return None, arg
    if not name or not file:
        raise CaptureError(f"--capture {arg!r}: expected NAME=FILE or FILE")
    return name, file


@dataclass
class Assignment:
    """Mouse ``mouse`` (index into config.mice) comes from ``capture.devices[device]``."""

    mouse: int
    capture: Capture
    device: int


class Assignments(list[Assignment]):
    """The mice's assignments, in the config's order, and the captures opened for the
    gyro alone (``gyro_only``: a file given without NAME= that holds a gyro and no mouse
    of the config, or the config's ``gyro.replay``); ``captures_of`` includes them."""

    def __init__(self, items: list[Assignment], gyro_only: list[Capture] | None = None) -> None:
        super().__init__(items)
        self.gyro_only = list(gyro_only or [])


def _evdev_matches(match: EvdevMatch, dev: DeviceInfo) -> bool:
    given = False
    for key in ("name", "phys", "uniq", "vendor", "product"):
        want = getattr(match, key)
        if want is None:
            continue
        given = True
        if getattr(dev, key) != want:
            return False
    return given


def _matches(mouse: MouseConfig, dev: DeviceInfo) -> bool:
    if mouse.replay_device is not None:
        # By name, or by the recorded device node: two identical mice share their name,
        # and a libinput recording keeps only name, ids and node to tell them apart.
        return mouse.replay_device in (dev.name, dev.extra.get("node"))
    if dev.mouse is not None:
        return dev.mouse == mouse.name
    if mouse.evdev is not None and _evdev_matches(mouse.evdev, dev):
        return True
    return dev.name == mouse.name


def _candidates(capture: Capture) -> list[int]:
    """Devices that can be mice: they move (or may), or they are serial sensors; never a
    gyro (``find_gyro`` is its rule)."""
    return [
        i
        for i, d in enumerate(capture.devices)
        if d.kind != GYRO_KIND and (d.kind == "serial" or d.rel_xy is not False)
    ]


def _node(capture: Capture, i: int) -> str:
    # A libinput record's node: key is the capture's text, printed in messages: escaped
    # (the names beside it are shown with repr, which escapes them already).
    node = capture.devices[i].extra.get("node")
    return f" ({escaped(str(node))})" if node else ""


def _describe(capture: Capture, devices: list[int]) -> str:
    return ", ".join(repr(capture.devices[i].name) + _node(capture, i) for i in devices) or "none"


def _matching(mouse: MouseConfig, capture: Capture, cands: list[int]) -> list[int]:
    """The candidates that match ``mouse``; the only mover when none does and no device is
    named that it could contradict."""
    hits = [i for i in cands if _matches(mouse, capture.devices[i])]
    if not hits and len(cands) == 1 and mouse.replay_device is None:
        return cands
    return hits


class _Assigner:
    """One ``assign`` call: the captures opened so far (each file once) and the mice
    assigned so far."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.cfg_name = config.path or "the config"
        self.opened: dict[str, Capture] = {}
        self.result: dict[int, Assignment] = {}
        self.gyro_only: list[Capture] = []

    def open(self, path: str) -> Capture:
        key = os.path.realpath(path)
        if key not in self.opened:
            self.opened[key] = open_capture(path)
        return self.opened[key]

    def put(self, mouse: int, cap: Capture, dev: int, why: str) -> None:
        name = self.config.mice[mouse].name
        if mouse in self.result:
            prev = self.result[mouse]
            raise CaptureError(
                f"mouse {name!r} is given twice: {prev.capture.path} "
                f"({prev.capture.devices[prev.device].name!r}) and {cap.path} ({why})"
            )
        dev_info = cap.devices[dev]
        if dev_info.rel_xy is False:
            raise CaptureError(
                f"{cap.path}: device {dev_info.name!r} has no REL_X/REL_Y motion: "
                f"not a mouse, cannot be {name!r}"
            )
        self.result[mouse] = Assignment(mouse, cap, dev)

    def by_name(self, name: str, path: str) -> None:
        """``--capture NAME=FILE``: the file's device for mouse NAME."""
        config, cfg_name = self.config, self.cfg_name
        cap = self.open(path)
        cands = _candidates(cap)
        if name not in config.names:
            raise CaptureError(
                f"--capture {name}={path}: {cfg_name} has no mouse {name!r} "
                f"(its mice: {', '.join(config.names)})"
            )
        mouse = config.index(name)
        wanted = config.mice[mouse].replay_device
        if wanted is not None and not any(_matches(config.mice[mouse], d) for d in cap.devices):
            raise CaptureError(
                f"--capture {name}={path}: {cfg_name} names device {wanted!r} for mouse "
                f"{name!r} (mice.{name}.replay.device), and the file holds "
                f"{_describe(cap, cands)}"
            )
        if len(cap.devices) == 1:
            self.put(mouse, cap, 0, "given by name")
            return
        hits = _matching(config.mice[mouse], cap, cands)
        if len(hits) != 1:
            raise CaptureError(
                f"--capture {name}={path}: the file holds {len(cands)} motion devices "
                f"({_describe(cap, cands)}) and {len(hits)} match mouse {name!r}; "
                f"name the device (or its node) in {cfg_name} (mice.{name}.replay.device)"
            )
        self.put(mouse, cap, hits[0], "given by name")

    def by_device(self, path: str) -> None:
        """``--capture FILE``: each of the file's devices to the mouse it matches."""
        config = self.config
        cap = self.open(path)
        cands = _candidates(cap)
        used = False
        for i in cands:
            hits = [k for k, m in enumerate(config.mice) if _matches(m, cap.devices[i])]
            if len(hits) > 1:
                raise CaptureError(
                    f"{path}: device {cap.devices[i].name!r}{_node(cap, i)} matches several "
                    f"mice ({', '.join(config.mice[k].name for k in hits)}); set "
                    "mice.NAME.replay.device to the device's name or node"
                )
            if hits:
                self.put(hits[0], cap, i, "matched")
                used = True
        if not used and any(d.kind == GYRO_KIND for d in cap.devices):
            self.gyro_only.append(cap)  # a gyro's capture (find_gyro takes it, or says so)
        elif not used:
            raise CaptureError(
                f"{path}: no device ({_describe(cap, cands)}) matches a mouse of "
                f"{self.cfg_name} ({', '.join(config.names)}); give it as NAME={path}"
            )

    def from_config(self, k: int, m: MouseConfig, replay: str) -> None:
        """Mouse ``k`` from its own ``replay:`` file."""
        cap = self.open(replay)
        cands = _candidates(cap)
        hits = _matching(m, cap, cands)
        if not hits and m.replay_device is not None:
            raise CaptureError(self.config.locate(
                ("mice", m.name, "replay", "device"),
                f"no device {m.replay_device!r} in {replay} (it holds {_describe(cap, cands)})",
            ))  # fmt: skip
        if len(hits) != 1:
            raise CaptureError(self.config.locate(
                ("mice", m.name, "replay"),
                f"{len(hits)} devices of {replay} match (it holds {_describe(cap, cands)}); "
                "set replay.device",
            ))  # fmt: skip
        self.put(k, cap, hits[0], "from the config")

    def check_all(self) -> None:
        """Every mouse of the config has its device."""
        missing = [m.name for k, m in enumerate(self.config.mice) if k not in self.result]
        if missing:
            raise CaptureError(
                f"no capture for mouse {', '.join(map(repr, missing))} of {self.cfg_name}: "
                "give --capture NAME=FILE for every mouse"
            )


def assign(
    config: Config, specs: list[tuple[str | None, str]], *, require_all: bool = True
) -> list[Assignment]:
    """Open the captures and map their devices onto the config's mice.

    ``specs`` are parsed ``--capture`` arguments; mice of the config with a ``replay:``
    source and no ``--capture`` of their own are read from that file.  Every mouse of the
    config must get exactly one device (unless ``require_all`` is false).
    """
    assigner = _Assigner(config)
    for name, path in specs:
        if name is not None:
            assigner.by_name(name, path)
        else:
            assigner.by_device(path)
    for k, m in enumerate(config.mice):
        if k not in assigner.result and m.replay:
            assigner.from_config(k, m, m.replay)
    if config.gyro is not None and config.gyro.replay is not None:
        cap = assigner.open(config.gyro.replay)  # the daemon's gyro replay, replayed alike
        held = [a.capture for a in assigner.result.values()] + assigner.gyro_only
        if all(cap is not c for c in held):
            assigner.gyro_only.append(cap)
    if require_all:
        assigner.check_all()
    return Assignments([assigner.result[k] for k in sorted(assigner.result)], assigner.gyro_only)


@dataclass
class GyroAssignment:
    """The config's gyro comes from ``capture.devices[device]``."""

    capture: Capture
    device: int


def gyro_devices(capture: Capture, device: str | None = None) -> list[int]:
    """The capture's gyros; of them, the one named ``device`` (its name or recorded node)."""
    found = [i for i, d in enumerate(capture.devices) if d.kind == GYRO_KIND]
    if device is None:
        return found
    devs = capture.devices
    return [i for i in found if device in (devs[i].name, devs[i].extra.get("node"))]


def find_gyro(config: Config, captures: list[Capture]) -> tuple[GyroAssignment | None, list[str]]:
    """The captures' gyro for the config's ``gyro:`` section, and warnings.

    A config without ``gyro:`` ignores a recorded gyro, with a warning (the mice replay
    as configured: comparing a run with and without its gyro is a reason to do so).  A
    config whose gyro no capture holds gets None and a warning: the replay then runs the
    config without its gyro (``Replay``), rather than wait for samples that never come.
    One gyro in the captures is the config's whatever its name (as the only mover of a
    file is its mouse); of several, the one named as the config's ``gyro.name``.  A config
    whose gyro is a capture's (``gyro.replay``, the daemon's) takes it from that file, as
    the daemon does (``GyroReplaySource``): its one gyro, or the one ``replay.device``
    names."""
    cfg_name = config.path or "the config"
    found = [(c, i) for c in captures for i in gyro_devices(c)]
    gyro = config.gyro
    if gyro is not None and gyro.replay is not None:
        key = os.path.realpath(gyro.replay)
        cap = next((c for c in captures if os.path.realpath(c.path) == key), None)
        hits = [] if cap is None else gyro_devices(cap, gyro.replay_device)
        if cap is None or len(hits) != 1:
            held = ", ".join(f"{cap.devices[i].name!r}{_node(cap, i)}"
                             for i in gyro_devices(cap)) if cap else ""  # fmt: skip
            raise CaptureError(
                f"{gyro.replay}: gyro.replay: {len(hits)} gyros match (the file holds "
                f"{held or 'none'}); name one with gyro.replay.device"
            )
        return GyroAssignment(cap, hits[0]), []
    if config.gyro is None:
        return None, [
            f"{c.path}: device {c.devices[i].name!r}{_node(c, i)} is a gyro and {cfg_name} "
            "has no gyro: section: its samples are ignored (add gyro: to fuse them)"
            for c, i in found
        ]
    if not found:
        return None, [
            f"{cfg_name} has a gyro: section but no capture holds a gyro: replayed without "
            "it, from the mice alone"
        ]
    if len(found) > 1:
        named = [(c, i) for c, i in found if c.devices[i].name == config.gyro.name]
        if len(named) != 1:
            held = ", ".join(f"{c.devices[i].name!r}{_node(c, i)} in {c.path}" for c, i in found)
            raise CaptureError(
                f"the captures hold {len(found)} gyros ({held}) and {len(named)} is named "
                f"as {cfg_name}'s gyro.name ({config.gyro.name!r}): give the captures of "
                "one gyro, or name it"
            )
        found = named
    return GyroAssignment(*found[0]), []


def captures_of(assignments: list[Assignment]) -> list[Capture]:
    """The opened captures, each once, in the order of the assignments (then those opened
    for the gyro alone, ``Assignments.gyro_only``)."""
    seen: list[Capture] = []
    for cap in [a.capture for a in assignments] + getattr(assignments, "gyro_only", []):
        if all(cap is not s for s in seen):
            seen.append(cap)
    return seen


def input_files(
    config_path: str | None, calibration: str | None, captures: Iterable[str]
) -> list[str]:
    """Every file a run reads, which no output of it may name: the config, its
    calibration, and each capture with the other half of an old evemu pair (.events and
    .desc) - the captures given on the command line and those the config's ``replay:``
    names alike."""
    files = [p for p in (config_path, calibration) if p]
    for path in captures:
        files.append(path)
        if path.endswith((".events", ".desc")):
            try:
                files += [p for p in companion(path) if p]
            except CaptureError:
                pass  # (a .desc without its events: the capture's own error says so)
    return files


def config_captures(config: Config) -> list[str]:
    """The captures a config's ``replay:`` keys name (the mice's, the gyro's)."""
    replays = [m.replay for m in config.mice if m.replay]
    if config.gyro is not None and config.gyro.replay:
        replays.append(config.gyro.replay)
    return replays


def config_inputs(config: Config) -> list[str]:
    """``input_files`` of a config: its own, its calibration and its ``replay:`` captures,
    for the writers of a live run (``run --record``, ``record``)."""
    return input_files(config.path, config.calibration, config_captures(config))


def mice_by_device(assignments: list[Assignment], capture: Capture) -> dict[int, tuple[int, ...]]:
    """Device index -> the mice it feeds, for one capture (one device may feed several)."""
    out: dict[int, tuple[int, ...]] = {}
    for a in assignments:
        if a.capture is capture:
            out[a.device] = out.get(a.device, ()) + (a.mouse,)
    return out
