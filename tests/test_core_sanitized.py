"""The compiled core is memory-safe on any input (issue 28, item 4): built with
AddressSanitizer and UBSan and warnings as errors, and fuzzed for a bounded time against
the Python reference (scripts/fuzz_core.py; longer runs there).  ASan is checked to be
live in the fuzzed process, and every Python object is its own allocation
(PYTHONMALLOC=malloc), so a read one byte past a buffer fails the run."""

from __future__ import annotations

import os
import subprocess
import sys

import cores
from conftest import REPO

FUZZ_S = 15.0  # the suite's share; CI's fuzz budget for the core
# At least this many cases: on a loaded machine the run goes on (up to four times FUZZ_S)
# rather than fail for fuzzing less (714 cases in 15 s under a load of 5 on two cores).
MIN_CASES = 1000

needs_gcc = cores.needs_gcc


@needs_gcc
def test_the_core_fuzzed_under_asan_and_ubsan_is_safe_and_the_python(tmp_path):
    seed = 28 if os.environ.get("CI") else int.from_bytes(os.urandom(4), "little")
    done = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "fuzz_core.py"), "--seconds", str(FUZZ_S),
         "--min-cases", str(MIN_CASES), "--seed", str(seed), "--build-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=4 * FUZZ_S + 240,
    )  # fmt: skip
    assert done.returncode == 0, f"seed {seed}:\n{done.stdout}\n{done.stderr[-4000:]}"
    assert "no fault, all as the Python" in done.stdout
    cases = int(done.stdout.split("fuzz_core: ")[1].split()[0])
    assert cases >= MIN_CASES, done.stdout  # it did fuzz, not just start
