#!/usr/bin/env python3
"""Fuzz the compiled core under AddressSanitizer and UBSan (issue 28, item 4).

    python scripts/fuzz_core.py [--seconds 60] [--seed N] [--build-dir DIR]

Builds csrc/*.c with ``-fsanitize=address,undefined -fno-sanitize-recover=all`` and
warnings as errors (``-Wall -Wextra -Werror``) into a scratch directory, then runs this
script again in a child with the ASan runtime preloaded (Python itself is not
instrumented) and that build in place of ``mousedom._core``.  The child feeds the core
random bytes, mouse-like event streams and extreme carried states, cut at random byte
offsets, and checks every result against the Python reference (``FrameAssembler`` with
the core off); calls the window functions with random and hostile lists
(scripts/fuzz_core_window.py); and scans evemu event lines, near misses and random bytes
(against ``general_events``).  A read or write out of bounds, undefined behaviour (a
signed overflow, a misaligned load) or a result unlike the Python's ends it with a
non-zero exit status.
tests/test_core_sanitized.py runs it for a bounded time in the suite; longer runs here.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import random
import shutil
import struct
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer"]
WARN = ["-Wall", "-Wextra", "-Werror"]


def build(out_dir: Path) -> Path:
    """The sanitized extension module, as ``_core<EXT_SUFFIX>`` in ``out_dir``."""
    out = out_dir / f"_core{sysconfig.get_config_var('EXT_SUFFIX')}"
    cmd = [
        os.environ.get("CC", "gcc"), "-shared", "-fPIC", "-O1", "-g", "-ffp-contract=off",
        "-fno-builtin-sin", "-fno-builtin-cos",
        *SANITIZE, *WARN, f"-I{sysconfig.get_paths()['include']}",
        *sorted(str(c) for c in (REPO / "csrc").glob("*.c")), "-lm", "-o", str(out),
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        sys.exit(f"fuzz_core: the sanitized build failed:\n{done.stderr}")
    return out


def runtime() -> str:
    """The ASan runtime to preload into an uninstrumented Python."""
    cc = os.environ.get("CC", "gcc")
    lib = subprocess.run([cc, "-print-file-name=libasan.so"], capture_output=True, text=True)
    path = lib.stdout.strip()
    if lib.returncode != 0 or not os.path.isabs(path) or not os.path.exists(path):
        sys.exit(f"fuzz_core: {cc} has no libasan.so (install gcc's sanitizer runtime)")
    return path


# --------------------------------------------------------------------------- the child


def _record(rnd: random.Random) -> bytes:
    kind = rnd.random()
    if kind < 0.6:  # a mouse: REL_X, REL_Y, SYN_REPORT, sometimes SYN_DROPPED
        t, c = rnd.choice([(2, 0), (2, 1), (0, 0), (0, 0), (0, 3), (0, 2), (1, 272), (4, 4)])
    else:
        t, c = rnd.getrandbits(16), rnd.getrandbits(16)
    value = rnd.choice([rnd.randint(-50, 50), rnd.randint(-(2**31), 2**31 - 1)])
    sec = rnd.choice([rnd.randint(0, 5), rnd.randint(-(2**63), 2**63 - 1)])
    usec = rnd.choice([rnd.randint(0, 999_999), rnd.randint(-(2**63), 2**63 - 1)])
    return struct.pack("<qqHHi", sec, usec, t, c, value)


def _stream(rnd: random.Random) -> bytes:
    if rnd.random() < 0.3:
        return rnd.randbytes(rnd.randint(0, 24 * 60))
    return b"".join(_record(rnd) for _ in range(rnd.randint(0, 80)))


def _cuts(data: bytes, rnd: random.Random) -> list[bytes]:
    offsets = sorted(rnd.randint(0, len(data)) for _ in range(rnd.randint(0, 6)))
    bounds = [0, *offsets, len(data)]
    return [data[a:b] for a, b in zip(bounds, bounds[1:], strict=False)]


def _big(rnd: random.Random) -> int:
    return rnd.choice([0, rnd.randint(-100, 100), 2**63 - 1, -(2**63), rnd.getrandbits(70)])


def _carried(rnd: random.Random) -> tuple:
    """A frame left open by an earlier read, as FrameAssembler can hold one (sums only
    with motion in it, no counts without events), its sums sometimes extreme: the core
    must decline those, not overflow."""
    events = rnd.randint(0, 4)
    nonsyn = rnd.randint(0, events)
    motion = nonsyn > 0 and rnd.random() < 0.7
    dropped = events > nonsyn and rnd.random() < 0.3
    dx, dy = (_big(rnd), _big(rnd)) if motion else (0, 0)
    return dx, dy, motion, dropped, events, nonsyn, rnd.random() if events else 0.0


def _ingest_same(sanitized, rnd: random.Random, reference) -> bool:
    """CountFunction.ingest_small's loop on random reports and knots, both cores: the
    same knots and results (or the core declines, with the knots untouched)."""
    n = rnd.randint(1, 40)
    stamp = lambda: round(rnd.uniform(-1.0, 1.0), rnd.choice([3, 4, 9]))  # noqa: E731
    t = sorted(stamp() for _ in range(n))
    for _ in range(rnd.randint(0, 3)):
        t[rnd.randrange(n)] = stamp()

    def axis() -> list:
        kind = rnd.random()
        if kind < 0.6:
            return [rnd.choice([rnd.randint(-40, 40), rnd.randint(-(2**31), 2**31)])
                    for _ in range(n)]  # fmt: skip
        if kind < 0.9:
            return [rnd.uniform(-1e6, 1e6) for _ in range(n)]
        return [rnd.choice([1, 2.5, True, 2**63, -(2**64)]) for _ in range(n)]

    dx, dy = axis(), axis()
    nk = 2 * rnd.randint(0, 3)
    kt = sorted(stamp() for _ in range(nk))
    kx = [float(rnd.randint(-99, 99)) for _ in range(nk)]
    ky = [float(rnd.randint(-99, 99)) for _ in range(nk)]
    period = rnd.choice([0.001, 0.008])
    rest = (rnd.choice([kt[-1] if kt else 0.0, stamp(), -math.inf]),
            rnd.choice([stamp(), -math.inf]), period,
            max(period, rnd.choice([0.0, 0.15])), period / 2)  # fmt: skip
    c_lists, py_lists = [kt[:], kx[:], ky[:]], [kt[:], kx[:], ky[:]]
    got = sanitized.ingest_small(t, dx, dy, *c_lists, *rest)
    if got is None:
        return c_lists == [kt, kx, ky]
    try:
        want = reference(t, dx, dy, *py_lists, *rest)
    except TypeError:
        return False  # the core took what Python cannot add
    same = [struct.pack("<d", v) if isinstance(v, float) else v for v in got]
    ref = [struct.pack("<d", v) if isinstance(v, float) else v for v in want]
    bits = [[struct.pack("<d", v) for v in lst] for lst in c_lists]
    ref_bits = [[struct.pack("<d", v) for v in lst] for lst in py_lists]
    return same == ref and bits == ref_bits


_NEAR_MISSES = ("", "E:", "e: ", "E:  ", "..", "\t", "  ", "\r", "--", "+-", " x", "#", "x",
                "\x00", "\xff", "0" * 13, "1" * 10, "f" * 5, "\n", "E: 1.5 2 3 4")  # fmt: skip


def _evemu_line(rnd: random.Random) -> list[str]:
    """A valid evemu event line of random widths, as its pieces."""

    def run(chars: str, lo: int, hi: int) -> str:
        return "".join(rnd.choice(chars) for _ in range(rnd.randint(lo, hi)))

    hexd = "0123456789abcdefABCDEF"
    return ["E: ", run("0123456789", 1, 12), ".", run("0123456789", 1, 9), " ",
            run(hexd, 1, 4), " ", run(hexd, 1, 4), " ", rnd.choice(["", "-", "+"]),
            run("0123456789", 1, 9),
            rnd.choice(["", " ", "\t# EV_REL / REL_X 5", "  # c", " \r", "\t#"]), "\n"]  # fmt: skip


def _evemu_block(rnd: random.Random) -> bytes:
    """Lines of evemu events, now and then one piece a near miss, or random bytes."""
    if rnd.random() < 0.1:
        return rnd.randbytes(rnd.randint(0, 200))
    lines = [_evemu_line(rnd) for _ in range(rnd.randint(0, 30))]
    for _ in range(rnd.choice((0, 0, 1, 2))):
        if lines:
            line = rnd.choice(lines)
            line[rnd.randrange(len(line))] = rnd.choice(_NEAR_MISSES)
    return "".join("".join(line) for line in lines).encode("latin-1")


def _evemu_same(sanitized, rnd: random.Random) -> bool:
    """The compiled scanner against ``general_events`` on one block, cut anywhere."""
    from mousedom.capture.evemu_lines import general_events, native_events

    block = _evemu_block(rnd)
    block = block[: rnd.randint(0, len(block))] if rnd.random() < 0.2 else block
    want = general_events(block, 1)
    got = native_events(sanitized, block, 1)
    if (want is None) != (got is None):
        return False
    if want is not None and got is not None:
        EVEMU["taken"] += 1
        return all(getattr(want, k).tobytes() == getattr(got, k).tobytes()
                   for k in ("t", "typ", "code", "value", "line"))  # fmt: skip
    EVEMU["refused"] += 1
    return True


EVEMU = {"taken": 0, "refused": 0}


def child(seconds: float, seed: int, min_cases: int = 0) -> int:
    sys.path.insert(0, str(REPO))
    from fuzz_core_window import TALLY, window_same  # (scripts/, this script's directory)

    from mousedom import core
    from mousedom.fusion.countfunction import _ingest_loop
    from mousedom.sources.events import FrameAssembler

    spec = importlib.util.spec_from_file_location("_core", os.environ["FUZZ_CORE_MODULE"])
    assert spec is not None and spec.loader is not None
    sanitized = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sanitized)
    maps = Path("/proc/self/maps").read_text()
    if "libasan" not in maps:
        print("fuzz_core: the ASan runtime is not loaded", file=sys.stderr)
        return 2
    rnd = random.Random(seed)
    start = time.monotonic()
    end, cap = start + seconds, start + 4 * seconds
    cases = 0
    # (at least ``min_cases``, as long as four times the time allows: on a loaded machine
    # the run takes longer rather than fuzzing less)
    while (now := time.monotonic()) < end or (cases < min_cases and now < cap):
        chunks = _cuts(_stream(rnd), rnd)
        carried = _carried(rnd)
        results = []
        for native in (sanitized, None):
            core.native = native
            a = FrameAssembler()
            (a._open_dx, a._open_dy, a._open_motion, a._open_dropped, a._open_events,
             a._open_nonsyn, a._open_t) = carried  # fmt: skip
            out, rest = [], b""
            for chunk in chunks:
                t, dx, dy, rest = a.feed_bytes(rest + chunk)
                out.append((struct.pack(f"<{len(t)}d", *t), dx, dy, rest))
            out.append(a.stats.as_dict())
            results.append(out)
        # the raw call too, on any state, with no Python in between
        sanitized.feed_bytes(chunks[-1] if chunks else b"", carried)
        if not _ingest_same(sanitized, rnd, _ingest_loop):
            print(f"fuzz_core: case {cases} (seed {seed}): ingest_small differs from the "
                  "Python", file=sys.stderr)  # fmt: skip
            return 1
        if results[0] != results[1]:
            print(f"fuzz_core: case {cases} (seed {seed}) differs from the Python", file=sys.stderr)
            return 1
        for _ in range(4):
            if not _evemu_same(sanitized, rnd):
                print(f"fuzz_core: case {cases} (seed {seed}): evemu_events differs from "
                      "general_events", file=sys.stderr)  # fmt: skip
                return 1
        for _ in range(4):
            differs = window_same(sanitized, rnd)
            if differs is not None:
                print(f"fuzz_core: case {cases} (seed {seed}): {differs}", file=sys.stderr)
                return 1
        cases += 1
    calls = sum(TALLY.values())
    took = time.monotonic() - start
    print(f"fuzz_core: {cases} cases in {took:.1f} s, seed {seed}: no fault, all as the Python; "
          f"window calls {calls}: " + ", ".join(f"{v} {k}" for k, v in TALLY.items())
          + f"; evemu blocks {EVEMU['taken']} taken, {EVEMU['refused']} refused")  # fmt: skip
    if EVEMU["taken"] < cases or EVEMU["refused"] < cases // 4:
        print("fuzz_core: too few evemu blocks taken or refused to compare", file=sys.stderr)
        return 1
    if calls and TALLY["compared"] < calls // 4:
        print("fuzz_core: the core declined most window calls: too few compared", file=sys.stderr)
        return 1
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument(
        "--min-cases",
        type=int,
        default=0,
        help="go on past --seconds (up to four times) until this many cases",
    )
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--build-dir", type=Path, default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    seed = args.seed if args.seed is not None else random.SystemRandom().getrandbits(32)
    if args.child:
        return child(args.seconds, seed, args.min_cases)
    scratch = args.build_dir or Path(tempfile.mkdtemp(prefix="fuzz-core-"))
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        module = build(scratch)
        env = {
            **os.environ,
            "LD_PRELOAD": runtime(),
            "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1",  # Python's own arenas "leak"
            # every object its own malloc, with ASan's red zones around it: reads past a
            # bytes object's end are caught, not lost inside a pymalloc arena
            "PYTHONMALLOC": "malloc",
            "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1",
            "FUZZ_CORE_MODULE": str(module),
            "MOUSEDOM_CORE": "python",  # the child chooses the core per call itself
        }
        cmd = [sys.executable, __file__, "--child", "--seconds", str(args.seconds),
               "--min-cases", str(args.min_cases), "--seed", str(seed)]  # fmt: skip
        return subprocess.run(cmd, env=env, check=False).returncode
    finally:
        if args.build_dir is None:
            shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
