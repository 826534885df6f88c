"""The window functions of the compiled core under the fuzzer (scripts/fuzz_core.py):
random calls, well formed or hostile, each against its Python reference.

``close_knots``, ``body_counts``, ``linear``, ``advance`` and ``steady_window`` are handed
lists of random sizes (past the core's stack buffers too) and values (NaN, infinities,
-0.0, huge), and now and then a hostile leaf: an int, a string, None, a float subclass,
a list one short or one long; ``pose_line`` the same values and any text for the names.
The core must then decline (None, or False for ``steady_window``) or give exactly what
the Python gives; a result where the Python raises is a difference too.  Under
AddressSanitizer a read past any list is caught.
"""

from __future__ import annotations

import math
import random
import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from mousedom import core
from mousedom.fusion import onewindow, steady
from mousedom.fusion.countfunction import close_knots
from mousedom.fusion.noisemodel import _MEDIAN_CHI2_2
from mousedom.service.protocol import _json_names, encode_pose

SPECIAL = [math.nan, math.inf, -math.inf, -0.0, 0.0, 1e300, -1e-300, 5e-324]


def _float(rnd: random.Random) -> float:
    r = rnd.random()
    if r < 0.05:
        return rnd.choice(SPECIAL)
    if r < 0.3:
        return float(rnd.randint(-40, 40)) * 0.0025
    return rnd.uniform(-1.0, 1.0) * 10 ** rnd.randint(-6, 3)


def _floats(rnd: random.Random, n: int) -> list[float]:
    return [_float(rnd) for _ in range(n)]


def _hostile(rnd: random.Random, value: Any) -> Any:
    """``value`` with one leaf, or one list's length, changed into what no caller passes."""
    if not isinstance(value, (list, tuple)) or not value or rnd.random() < 0.3:
        return rnd.choice([1, "x", None, np.float64(0.5), True, [0.0], ()])
    items = list(value)
    k = rnd.randrange(len(items))
    r = rnd.random()
    if r < 0.2:
        items.pop(k)
    elif r < 0.4:
        items.append(items[k])
    else:
        items[k] = _hostile(rnd, items[k])
    if hasattr(value, "_fields"):  # a NamedTuple (steady.Rig): one field changed
        return type(value)(*items) if len(items) == len(value) else tuple(items)
    return tuple(items) if isinstance(value, tuple) else items


def _pairs(rnd: random.Random, n: int) -> list[list[float]]:
    return [_floats(rnd, 2) for _ in range(n)]


def _case(rnd: random.Random) -> tuple[str, tuple, tuple]:
    """(name, the core's arguments, the reference's arguments)."""
    name = rnd.choice(["close_knots", "body_counts", "linear", "advance", "steady_window",
                       "pose_line"])  # fmt: skip
    if name == "pose_line":
        names = [tuple(rnd.choice(["front", "é", '"', "\\", "\x00", "", "\ud800"])
                       for _ in range(rnd.randint(0, 3))) for _ in range(3)]  # fmt: skip
        head = (round(_float(rnd), 6), _floats(rnd, 3), tuple(_floats(rnd, 3)),
                [_floats(rnd, 3) for _ in range(3)],
                rnd.choice([0, 3, -1, 2**63 - 1, 2**63, -(2**63), 2**80]),
                rnd.random() < 0.5)  # fmt: skip
        consistent = rnd.random() < 0.5
        texts = [_json_names(n) for n in names]
        return name, (*head, *texts, consistent), (*head, *names, consistent)
    if name == "close_knots":
        n = rnd.choice([1, 2, 5, 63, 64, 65, 200])
        kt = sorted(_floats(rnd, n), key=lambda v: (math.isnan(v), v))
        args: tuple = (_float(rnd), kt, _floats(rnd, n), _floats(rnd, n),
                       rnd.choice([math.nan, _float(rnd)]))  # fmt: skip
        return name, args, args
    if name == "body_counts":
        n = rnd.randint(0, 9)
        args = ([[_floats(rnd, 2), _floats(rnd, 2)] for _ in range(n)],
                [tuple(_floats(rnd, 2)) for _ in range(n)])  # fmt: skip
        return name, args, args
    if name == "linear":
        m, k = rnd.randint(0, 9), rnd.randint(0, 4)
        args = (_floats(rnd, m), [_floats(rnd, k) for _ in range(m)],
                [_floats(rnd, m) for _ in range(k)])  # fmt: skip
        return name, args, args
    if name == "advance":
        method = rnd.choice(["exact", "taylor", "euler", "midpoint", "rk4", ""])
        m3 = [_floats(rnd, 3) for _ in range(3)]
        args = (_floats(rnd, 3), m3, _floats(rnd, 2), _floats(rnd, 3), _float(rnd),
                [_floats(rnd, 3) for _ in range(3)], method)  # fmt: skip
        return name, (*args, onewindow._SINC, onewindow._DSINC, onewindow._SWITCH), args
    n = rnd.choice([1, 2, 3, 4, 8, 64, 65])
    rig = steady.Rig(_pairs(rnd, n), _floats(rnd, n), _pairs(rnd, n),
                     *(_floats(rnd, n) for _ in range(5)))  # fmt: skip
    live = tuple(rnd.random() < 0.8 for _ in range(n))
    args = (
        _floats(rnd, 2 * n),
        _floats(rnd, 3),
        live,
        rig,
        _float(rnd),
        rnd.randint(-2, 2 * n),
        rnd.choice([None, _floats(rnd, n)]),
        [_floats(rnd, 4) for _ in range(n)],
        rnd.choice([None, _floats(rnd, n), [0.0] * n]),
    )  # fmt: skip (the cut spans)
    return name, (*args, _MEDIAN_CHI2_2), args


REFERENCES: dict[str, Callable[..., Any]] = {
    "close_knots": close_knots,
    "body_counts": onewindow.body_counts,
    "linear": onewindow.linear,
    "advance": onewindow.advance,
    "steady_window": steady.steady_window,
    "pose_line": encode_pose,  # (its names as tuples, which the core takes as JSON text)
}
# Arguments never made hostile: pose_line's names (the core takes them as the JSON text
# the Python makes of the reference's tuples: one hostile value means two things).
KEEP = {"pose_line": (6, 7, 8)}


def _bits(v: Any) -> Any:
    """Floats as their bytes; any NaN as NaN (tests/test_core_window.py: NAN_BITS)."""
    if isinstance(v, float):  # any NaN as NaN (docstring)
        return "nan" if v != v else struct.pack("<d", v)
    if isinstance(v, (list, tuple)):
        return (type(v).__name__, [_bits(x) for x in v])
    return v


def _reference(name: str, args: tuple) -> tuple[Any, BaseException | None]:
    """The Python's result (core off), or the exception it raises."""
    saved, core.native = core.native, None
    try:
        return REFERENCES[name](*args), None
    except Exception as e:  # noqa: BLE001 (any refusal)
        return None, e
    finally:
        core.native = saved


# What window_same did, case by case: compared (the core gave a result, the same as the
# Python's), declined (the Python ran), refused (both raised).
TALLY = {"compared": 0, "declined": 0, "refused": 0}


def window_same(sanitized: Any, rnd: random.Random) -> str | None:
    """One random call of a window function on the sanitized core against the Python:
    None where they agree, else what differs."""
    name, native_args, ref_args = _case(rnd)
    keep = KEEP.get(name, ())
    if rnd.random() < 0.3:  # one argument hostile (the reference gets the same one)
        k = rnd.choice([i for i in range(len(ref_args)) if i not in keep])
        bad = _hostile(rnd, ref_args[k])
        ref_args = (*ref_args[:k], bad, *ref_args[k + 1 :])
        native_args = (*native_args[:k], bad, *native_args[k + 1 :])
    try:
        got = getattr(sanitized, name)(*native_args)
    except (TypeError, ValueError, OverflowError) as e:
        # refused at the door (an argument's type): the Python must refuse it too
        _, raised = _reference(name, ref_args)
        if raised is None:
            return f"{name}: the core raised {e!r} where the Python gives a result"
        TALLY["refused"] += 1
        return None
    if got is (False if name == "steady_window" else None):
        TALLY["declined"] += 1
        return None
    want, raised = _reference(name, ref_args)
    if raised is not None:
        return f"{name}: the core gave a result where the Python raised {raised!r}"
    if _bits(got) != _bits(want):
        return f"{name}: {got!r} against the Python's {want!r}"
    TALLY["compared"] += 1
    return None
