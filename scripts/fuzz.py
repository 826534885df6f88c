#!/usr/bin/env python3
"""Fuzz every parser of mousedom for a while: ``scripts/fuzz.py --cases N --seed S``.

Cases come from ``tests/fuzz_targets.py`` (valid inputs in many dresses with a known
truth, and damaged ones) and ``tests/fuzz_hostile.py``, spread evenly over the targets:
evemu, libinput, native, round trips (convert -> native -> read back), libinput in other
layouts of the same YAML, decompression bombs, hostile stamps through a real pipe, ADNS
bytes, config YAML, REF/RUNS CSV, protocol lines.  The closing line is the figure:

    fuzz: N cases, C crashes, H hangs, W wrong counts (seed S, T s)

A crash is any exception but a one-line UserError; a hang is a case over the time limit;
a wrong count is a valid case refused, or accepted with counts in != reported + lost.
The first few failures are printed with their target, kind and seed, so that
``--only TARGET --seed S --cases 1`` reproduces one.  Exit status 1 if any.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO))

from fuzz_targets import HANG_S, TARGETS, make_case, run_case  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=10000, help="cases in all (default 10000)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--only", choices=TARGETS, action="append", help="fuzz these targets only")
    p.add_argument(
        "--hang", type=float, default=HANG_S, help=f"seconds a case may take ({HANG_S:g})"
    )
    p.add_argument("--show", type=int, default=5, help="failures printed in full (default 5)")
    args = p.parse_args(argv)
    targets = args.only or list(TARGETS)
    counts: Counter[str] = Counter()
    kinds: Counter[tuple[str, str]] = Counter()
    shown = 0
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="mousedom-fuzz-") as tmp:
        for i in range(args.cases):
            target = targets[i % len(targets)]
            seed = args.seed + i // len(targets)
            case = make_case(target, seed)
            result = run_case(case, tmp, args.hang)
            counts[result.outcome] += 1
            kinds[(target, result.outcome)] += 1
            if result.outcome in ("crash", "hang", "wrong") and shown < args.show:
                shown += 1
                print(f"{result.outcome}: {target} {case.kind} seed {seed}: {result.detail}")
            for name in os.listdir(tmp):
                os.unlink(os.path.join(tmp, name))
    elapsed = time.monotonic() - start
    for target in targets:
        row = ", ".join(
            f"{k} {kinds[(target, k)]}"
            for k in ("ok", "refused", "crash", "hang", "wrong")
            if kinds[(target, k)]
        )
        print(f"  {target}: {row}")
    print(
        f"fuzz: {args.cases} cases, {counts['crash']} crashes, {counts['hang']} hangs, "
        f"{counts['wrong']} wrong counts (seed {args.seed}, {elapsed:.0f} s)"
    )
    return 1 if counts["crash"] or counts["hang"] or counts["wrong"] else 0


if __name__ == "__main__":
    sys.exit(main())
