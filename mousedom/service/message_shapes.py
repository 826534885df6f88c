"""What each message the daemon sends carries, as its clients read it (docs/protocol.md).

``problem(msg)`` says what is wrong with a message's shape, or None.  The client
(``mousedom.client``) holds every line to it, so that ``watch``, ``doctor`` and a user's
program meet a clear ``NotADaemon`` where something at the socket sends JSON of the wrong
shape, not a ``TypeError`` deep in a format string.  Keys a class does not list are free
(a newer daemon may add some), and a key may be absent unless what reads the class cannot
do without it (a POSE's pose and covariance: ``client.Pose``); a key that is there has its
type.  Unknown classes pass, for the same reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

Check = Callable[[Any], bool]


def _number(v: Any) -> bool:
    return type(v) in (int, float)  # (not bool, which is an int)


def _finite(v: Any) -> bool:
    return _number(v) and math.isfinite(v)


def _number_or_null(v: Any) -> bool:
    return v is None or _number(v)


def _count(v: Any) -> bool:
    return type(v) is int and v >= 0


def _text(v: Any) -> bool:
    return type(v) is str


def _text_or_null(v: Any) -> bool:
    return v is None or type(v) is str


def _flag(v: Any) -> bool:
    return type(v) is bool


def _names(v: Any) -> bool:
    return type(v) is list and all(type(n) is str for n in v)


def _matrix3(v: Any) -> bool:
    return (
        type(v) is list
        and len(v) == 3
        and all(type(r) is list and len(r) == 3 and all(map(_number_or_null, r)) for r in v)
    )


def _gyro(v: Any) -> bool:
    return type(v) is dict and all(
        _number_or_null(v.get(k)) for k in ("bias", "bias_sigma", "agree", "scale")
    )


def _pose(v: Any) -> bool:
    return type(v) is dict and all(_number_or_null(v.get(k)) for k in ("x", "y", "theta"))


# class -> key -> (required, check)
SHAPES: dict[str, dict[str, tuple[bool, Check]]] = {
    "VERSION": {
        "release": (False, _text),
        "proto_major": (False, _count),
        "proto_minor": (False, _count),
        "rate_hz": (False, lambda v: _finite(v) and v > 0),
        "model": (False, _text),
        "sensors": (False, _names),
        "control": (False, _flag),
        "core": (False, _text),
    },
    "POSE": {
        "t": (True, _finite),
        **{k: (True, _number_or_null) for k in ("x", "y", "theta", "vx", "vy", "omega")},
        "cov": (True, _matrix3),
        "used": (True, _count),
        "updating": (True, _flag),
        "missing": (False, _names),
        "excluded": (False, _names),
        "suspect": (False, _names),
        "consistent": (False, _flag),
        "gyro": (False, _gyro),
    },
    "SOURCE": {
        "name": (True, _text),
        "kind": (False, _text),
        "connected": (False, _flag),
        "live": (False, _flag),
        "reports": (False, _count),
        "dropped": (False, _count),
        "rate_hz": (False, _number_or_null),
        "age": (False, _number_or_null),
        "residual": (False, _number_or_null),
        "excluded": (False, _flag),
        "state": (False, _text_or_null),
        "reason": (False, _text_or_null),
        "error": (False, _text_or_null),
        "scale": (False, _number_or_null),
        "scale_spread": (False, _number_or_null),
        "scale_applied": (False, _flag),
        "scale_warning": (False, _text_or_null),
        "bias": (False, _number_or_null),
    },
    "STATUS": {
        "uptime": (False, _number_or_null),
        "config": (False, _text_or_null),
        "model": (False, _text),
        "rate_hz": (False, _number_or_null),
        "pose": (False, _pose),
    },
    "OK": {"cmd": (True, _text)},
    "ERROR": {"message": (True, _text)},
}


def problem(msg: dict[str, Any]) -> str | None:
    """What is wrong with the shape of a message (a dict), or None."""
    cls = msg.get("class")
    if type(cls) is not str:
        return "its class is not a string"
    for key, (required, check) in SHAPES.get(cls, {}).items():
        if key not in msg:
            if required:
                return f"a {cls} without {key!r}"
        elif not check(msg[key]):
            return f"a {cls} whose {key!r} is {_short(msg[key])}"
    return None


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."
