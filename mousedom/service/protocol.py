"""The socket protocol without the sockets: line framing, commands, message objects.

Newline-delimited JSON, each object with a ``class`` field (as gpsd does).  The server sends
VERSION on connect, then POSE at the output rate and SOURCE per sensor; clients send one
command object a line (``{"cmd": "reset"}``, ``{"cmd": "fix", "x": 1.0}``, ``{"cmd":
"status"}``, ``{"cmd": "rate", "hz": 10}``).  A bad line gets an ERROR and changes nothing.
Everything here is bytes and dicts in, bytes and dicts out, so it tests without I/O; the full
description with an example session is docs/protocol.md.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from mousedom import __version__, core

PROTO_MAJOR = 1
# 1: POSE has excluded, suspect and consistent; SOURCE state and reason
# 2: SOURCE scale, scale_spread, scale_applied and scale_warning (the learnt scale)
# 3: POSE gyro (bias, bias_sigma, agree, scale) and a SOURCE named gyro, on rigs with a gyro
# 4: SOURCE state "late" (held out while its counts come late; in neither POSE list)
PROTO_MINOR = 5

# Which keys each command takes; anything else is a mistake worth telling the client about.
COMMANDS: dict[str, tuple[str, ...]] = {
    "reset": ("x", "y", "theta"),
    "fix": ("x", "y", "theta"),
    "status": (),
    "rate": ("hz",),
}
POSE_MOVING = frozenset({"reset", "fix"})
MAX_CLIENT_HZ = 10000.0
POSE_LIMITS = {"x": 1e7, "y": 1e7, "theta": 1e4}  # metres (10,000 km), radians
# A command is one flat object: any nesting is a mistake, and deep nesting is an attack on
# the recursive JSON parser.  An id is echoed back, so it must be something we can encode.
MAX_DEPTH = 8
MAX_ID_CHARS = 128


class ProtocolError(ValueError):
    """A client line that is not a valid command; the message goes back in an ERROR.

    ``id`` is the command's id when the line was an object that had one, so that the
    client can tell which of its commands failed.
    """

    def __init__(self, message: str, id: Any = None) -> None:
        super().__init__(message)
        self.id = id


@dataclass(frozen=True)
class Command:
    name: str
    args: dict[str, float]
    id: Any = None  # echoed back in the reply so a client can match answers to questions


class TooLong:
    """Marker that LineBuffer yields in place of an over-long line (which it discards)."""

    def __init__(self, size: int) -> None:
        self.size = size

    def __repr__(self) -> str:
        return f"TooLong({self.size})"


class LineBuffer:
    """Splits a byte stream into lines of at most ``max_line`` bytes (newline excluded).

    A longer line is reported once as ``TooLong`` and skipped up to its newline, without
    ever holding more than ``max_line`` bytes: a client cannot make the daemon buffer
    without bound by never sending a newline.
    """

    def __init__(self, max_line: int) -> None:
        self.max_line = max_line
        self._buf = bytearray()
        self._skipping = 0  # bytes of an over-long line seen so far (0: not skipping)

    def feed(self, data: bytes) -> list[bytes | TooLong]:
        out: list[bytes | TooLong] = []
        start = 0
        while start < len(data):
            nl = data.find(b"\n", start)
            end = len(data) if nl < 0 else nl
            chunk = data[start:end]
            if self._skipping:
                self._skipping += len(chunk)
            else:
                self._buf += chunk
                if len(self._buf) > self.max_line:
                    self._skipping = len(self._buf)
                    self._buf.clear()
            if nl < 0:
                break
            if self._skipping:
                out.append(TooLong(self._skipping))
                self._skipping = 0
            else:
                out.append(bytes(self._buf).rstrip(b"\r"))
                self._buf.clear()
            start = nl + 1
        return out

    def finish(self) -> list[bytes | TooLong]:
        """The stream ended (EOF): a last line without its newline is a line all the same
        (``printf '{"cmd":"status"}' | nc -U``: the command was dropped unanswered)."""
        if self._skipping:
            out: list[bytes | TooLong] = [TooLong(self._skipping)]
            self._skipping = 0
            return out
        if not self._buf:
            return []
        line = bytes(self._buf).rstrip(b"\r")
        self._buf.clear()
        return [line]


def _number(name: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"{name}: {key} must be a number, got {json.dumps(value)[:40]}")
    try:
        v = float(value)  # an integer of 400 digits does not fit a float
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise ProtocolError(f"{name}: {key} must be finite")
    return v


def parse_command(line: bytes) -> Command:
    """One client line -> Command, or ProtocolError saying exactly what is wrong."""
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ProtocolError(f"byte offset {e.start}: not UTF-8") from None
    too_deep = _nesting_beyond(text, MAX_DEPTH)
    if too_deep is not None:
        raise ProtocolError(f"column {too_deep}: nested deeper than {MAX_DEPTH} levels")
    try:
        # Python's json accepts NaN/Infinity; the protocol is strict JSON.
        obj = json.loads(text, parse_constant=_reject_constant, object_pairs_hook=_unique_keys)
    except _KeyTwice as e:
        raise ProtocolError(f"key {e.args[0]!r} given twice") from None
    except json.JSONDecodeError as e:
        raise ProtocolError(f"invalid JSON at column {e.colno}: {e.msg}") from None
    except (RecursionError, ValueError) as e:  # e.g. an integer of more than 4300 digits
        raise ProtocolError(f"invalid JSON: {str(e)[:80]}") from None
    if not isinstance(obj, dict):
        raise ProtocolError('a command is a JSON object such as {"cmd": "status"}')
    cmd_id = _valid_id(obj.get("id"))
    try:
        return _command(obj, cmd_id)
    except ProtocolError as e:
        raise ProtocolError(str(e), cmd_id) from None


def _nesting_beyond(text: str, limit: int) -> int | None:
    """Column (1-based) where brackets outside strings nest deeper than ``limit``, or None.

    Checked before json.loads, whose recursion a line of 2000 "[" would exhaust."""
    if text.count("[") + text.count("{") <= limit:
        return None
    depth = 0
    in_string = escaped = False
    for i, ch in enumerate(text):
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > limit:
                return i + 1
        elif ch in "]}":
            depth -= 1
    return None


def _valid_id(value: Any) -> Any:
    """The command's id if it can be echoed back as it came (a short string, a finite
    number, true/false or null); anything else is refused without echoing it."""
    if value is None or isinstance(value, bool):
        return value
    # (a lone surrogate, "\ud800", is valid JSON text but no character: echoed, the reply
    # is a line strict parsers refuse)
    if isinstance(value, str) and len(value) <= MAX_ID_CHARS and _encodable(value):
        return value
    if isinstance(value, int) and abs(value) < 2**63:
        return value
    if isinstance(value, float) and math.isfinite(value):
        return value
    raise ProtocolError(
        f"id must be a string of at most {MAX_ID_CHARS} characters (no lone surrogate), a "
        "finite number (an integer below 2**63 in magnitude), true, false or null"
    )


def _encodable(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _command(obj: dict[str, Any], cmd_id: Any = None) -> Command:
    name = obj.get("cmd")
    if not isinstance(name, str):
        raise ProtocolError('missing "cmd" (one of: ' + ", ".join(COMMANDS) + ")")
    if name not in COMMANDS:
        raise ProtocolError(f"unknown command {name!r} (one of: {', '.join(COMMANDS)})")
    allowed = COMMANDS[name]
    args: dict[str, float] = {}
    for key, value in obj.items():
        if key in ("cmd", "id"):
            continue
        if key not in allowed:
            takes = ", ".join(allowed) if allowed else "no arguments"
            raise ProtocolError(f"{name}: unknown key {key!r} (takes {takes})")
        args[key] = _number(name, key, value)
    if name == "fix" and not args:
        raise ProtocolError("fix: give at least one of x, y, theta")
    for key, limit in POSE_LIMITS.items():
        if key in args and abs(args[key]) > limit:
            # Past these, float64 loses the millimetre (and the covariance its meaning).
            raise ProtocolError(f"{name}: {key} must be within +-{limit:g}")
    if name == "rate":
        if "hz" not in args:
            raise ProtocolError("rate: needs hz (poses per second; 0 stops POSE)")
        if not 0 <= args["hz"] <= MAX_CLIENT_HZ:
            raise ProtocolError(f"rate: hz must be between 0 and {MAX_CLIENT_HZ:g}")
    return Command(name=name, args=args, id=cmd_id)


class _KeyTwice(Exception):
    """A JSON object with a key given twice (json.loads would keep the last silently)."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """The object, where each key comes once: ``{"cmd": "status", "cmd": "reset"}`` was a
    reset answered "OK reset" (json.loads keeps the last), ``{"x": 1, "x": 2}`` took 2.
    Refused as the config refuses a key given twice."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _KeyTwice(key)
        out[key] = value
    return out


def _reject_constant(name: str) -> Any:
    raise json.JSONDecodeError(f"{name} is not JSON", name, 0)


# --------------------------------------------------------------------------- messages


def encode(message: dict[str, Any]) -> bytes:
    """One message as a JSON line.  NaN/inf are not JSON: they become null."""
    return (json.dumps(message, separators=(",", ":"), allow_nan=False) + "\n").encode()


def _finite(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def version_message(
    rate_hz: float, sensors: Iterable[str], control: bool, model: str
) -> dict[str, Any]:
    return {
        "class": "VERSION",
        "release": __version__,
        "proto_major": PROTO_MAJOR,
        "proto_minor": PROTO_MINOR,
        "rate_hz": rate_hz,
        "model": model,
        "sensors": list(sensors),
        "control": control,  # whether this peer may send reset/fix
        "core": core.NAME,  # which core fuses (1.4): "c", or "python (why)"
    }


def pose_message(
    t: float,
    pose: tuple[float, float, float],
    twist: tuple[float, float, float],
    cov: Any,
    used: int,
    updating: bool,
    missing: Iterable[str] = (),
    excluded: Iterable[str] = (),
    suspect: Iterable[str] = (),
    consistent: bool = True,
    gyro: Sequence[float] = (),
) -> dict[str, Any]:
    """A POSE: odometry-frame pose, body-frame velocities, covariance of (x, y, theta).

    ``updating`` is False when the model had no rank over this window: the pose was held,
    not guessed.  ``missing`` names the sensors that did not contribute because they are
    gone, ``excluded`` those the fault-tolerant fusion left out (their readings disagreed,
    or their sensor said they were not tracking), ``suspect`` those used but in doubt.
    ``consistent`` is False where the mice disagreed and nobody could be blamed (the
    covariance is inflated for that window).  With a gyro (``gyro``: the window's turn,
    bias, bias sigma, agreement statistic and scale, PoseRow.gyro), ``"gyro"`` gives its
    bias (rad/s), the bias's sigma, the chi-square (1 dof) of its agreement with the mice
    (null where it had no samples) and its scale error (it reads 1 + scale times the turn).
    """
    msg = {
        "class": "POSE",
        "t": round(float(t), 6),
        "x": _finite(pose[0]),
        "y": _finite(pose[1]),
        "theta": _finite(pose[2]),
        "vx": _finite(twist[0]),
        "vy": _finite(twist[1]),
        "omega": _finite(twist[2]),
        "cov": [[_finite(c) for c in row] for row in cov],
        "used": int(used),
        "updating": bool(updating),
        "missing": list(missing),
        "excluded": list(excluded),
        "suspect": list(suspect),
        "consistent": bool(consistent),
    }
    if len(gyro):
        _, bias, sigma, stat, scale = gyro
        msg["gyro"] = {"bias": _finite(bias), "bias_sigma": _finite(sigma),
                       "agree": _finite(stat), "scale": _finite(scale)}  # fmt: skip
    return msg


def _json_float(v: float) -> str:
    # json.dumps writes a float as float.__repr__; NaN and inf are not JSON: null.
    v = float(v)
    return repr(v) if v - v == 0.0 else "null"


@functools.lru_cache(maxsize=64)
def _json_names(names: tuple[str, ...]) -> str:
    return json.dumps(list(names), separators=(",", ":"))


_POSE_FINITE = (
    '{"class":"POSE","t":%r,"x":%r,"y":%r,"theta":%r,"vx":%r,"vy":%r,"omega":%r,'
    '"cov":[[%r,%r,%r],[%r,%r,%r],[%r,%r,%r]],"used":%d,"updating":%s,"missing":%s,'
    '"excluded":%s,"suspect":%s,"consistent":%s}\n'
)
_POSE_ANY = _POSE_FINITE.replace("%r", "%s")  # values already written by _json_float
_GYRO = ',"gyro":{"bias":%s,"bias_sigma":%s,"agree":%s,"scale":%s}}\n'


def encode_pose(
    t: float,
    pose: tuple[float, float, float],
    twist: tuple[float, float, float],
    cov: list[list[float]],
    used: int,
    updating: bool,
    missing: tuple[str, ...] = (),
    excluded: tuple[str, ...] = (),
    suspect: tuple[str, ...] = (),
    consistent: bool = True,
    gyro: Sequence[float] = (),
) -> bytes:
    """``encode(pose_message(...))`` byte for byte, without the dict and the generic JSON
    encoder: the daemon writes one per window (tests check both give the same bytes).
    Arguments are Python floats, ints and bools (``ndarray.tolist()``).  The compiled core
    writes the line where every number is finite and there is no gyro (csrc/poseline.c);
    what it declines is written here."""
    native = core.native
    if native is not None and not len(gyro):
        line = native.pose_line(round(float(t), 6), pose, twist, cov, used, updating,
                                _json_names(missing), _json_names(excluded),
                                _json_names(suspect), consistent)  # fmt: skip
        if line is not None:
            return line
    c0, c1, c2 = cov
    # float() of each (numpy scalars would write as np.float64(...)), by map: a few
    # bytecodes for the 16 values instead of a call each (this runs every window).
    values = (round(float(t), 6), *map(float, (*pose, *twist, *c0, *c1, *c2)))
    template = _POSE_FINITE
    written: tuple[object, ...] = values
    # One sum is NaN or inf if a value is (or if finite values overflow it): then each
    # value is written on its own, null where JSON has no number.
    if not math.isfinite(sum(values)):
        template, written = _POSE_ANY, tuple(_json_float(v) for v in values)
    line = template % (
        *written,
        int(used),
        "true" if updating else "false",
        _json_names(missing),
        _json_names(excluded),
        _json_names(suspect),
        "true" if consistent else "false",
    )
    if len(gyro):  # the rig's gyro: before the closing brace
        _, bias, sigma, stat, scale = gyro
        values = (bias, sigma, stat, scale)
        line = line[:-2] + _GYRO % tuple(_json_float(float(v)) for v in values)
    return line.encode()


def source_message(health: dict[str, Any], **extra: Any) -> dict[str, Any]:
    """A SOURCE from a SourceHealth.as_dict() plus what the daemon knows (age, residual)."""
    msg: dict[str, Any] = {"class": "SOURCE"}
    for key, value in {**health, **extra}.items():
        msg[key] = _finite(value) if isinstance(value, float) else value
    return msg


def error_message(text: str, id: Any = None) -> dict[str, Any]:
    msg: dict[str, Any] = {"class": "ERROR", "message": text}
    if id is not None:
        msg["id"] = id
    return msg


def ok_message(cmd: str, id: Any = None, **extra: Any) -> dict[str, Any]:
    msg: dict[str, Any] = {"class": "OK", "cmd": cmd, **extra}
    if id is not None:
        msg["id"] = id
    return msg
