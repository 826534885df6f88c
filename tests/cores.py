"""Each core this checkout runs (mousedom/core.py), for tests that hold them equal: the
compiled one where it is built, and the Python, which is its reference."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from mousedom import core

# In CI the compiled core must be there (tests/test_core.py fails without it); elsewhere
# a checkout without a compiler tests the Python alone.
REQUIRED = os.environ.get("MOUSEDOM_REQUIRE_CORE") == "1"

# Tests that build the core themselves (sanitised, or into a wheel) need a C compiler;
# in CI a missing one fails them rather than skips them.
needs_gcc = pytest.mark.skipif(
    shutil.which(os.environ.get("CC", "gcc")) is None and not REQUIRED,
    reason="no C compiler here (CI has one: MOUSEDOM_REQUIRE_CORE=1)",
)


def names() -> list[str]:
    return ["c", "python"] if core.native is not None else ["python"]


@contextmanager
def using(name: str) -> Iterator[None]:
    """The code under test runs on core ``name`` ("c" or "python") inside the block."""
    saved = core.native
    if name == "c" and saved is None:
        raise RuntimeError("the compiled core is not built")
    core.native = saved if name == "c" else None
    try:
        yield
    finally:
        core.native = saved
