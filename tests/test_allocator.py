"""mousedom.allocator: malloc keeps freed arrays for reuse in batch commands."""

import resource
import subprocess
import sys

import numpy as np

from mousedom import allocator


def _faults_of_block_loop() -> int:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(20):
        a = np.ones(1 << 17)  # 1 MB: above glibc's default mmap threshold
        a.cumsum()
        del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def test_freed_arrays_come_back_without_page_faults():
    """After keep_freed_memory, a loop that allocates and frees 1 MB arrays touches the
    same pages again: next to no page faults (without it, each array is fresh pages).
    In a child process, so that this test's own heap history does not decide it."""
    code = (
        "import sys; sys.path.insert(0, '.');"
        "from tests.test_allocator import _faults_of_block_loop as f;"
        "from mousedom.allocator import keep_freed_memory as k;"
        "before = f(); ok = k(); f(); after = f(); print(before, ok, after)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    before, ok, after = out.stdout.split()
    assert ok == "True"
    assert int(before) > 200  # 20 arrays of 256 pages, each first touched
    assert int(after) < 20


def test_it_is_idempotent():
    assert allocator.keep_freed_memory() is True
    assert allocator.keep_freed_memory() is True
