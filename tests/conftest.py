"""Shared test helpers.

Tests run the CLI as a real process (``python -m mousedom``) so that exit codes, stderr
and stdout are what a user sees.  The repository root goes on PYTHONPATH so this works
both from an installed venv and from a plain checkout.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# In CI the property tests run derandomized: the same (large) set of examples every run, so a
# red CI always means a change broke something, never that a new random example was drawn.
# On developer machines they keep exploring new examples.  No deadline in CI: the suite's
# workers share the machine's cores (README), and an example's time is the bench's business,
# not a test's (a slow example is no wrong one).
settings.register_profile(
    "ci",
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
if os.environ.get("CI"):
    settings.load_profile("ci")

REPO = Path(__file__).resolve().parent.parent


def _build_core_in_place() -> None:
    """The tests import mousedom from this checkout (the repository root is on sys.path),
    not from the venv, so the compiled core is built here, in place, when it is missing or
    older than its source: the tests then run the core the code in front of them has.
    Without a compiler the build fails quietly and the Python runs (tests/cores.py; CI
    requires the compiled core).  Before anything imports mousedom.  ``--force``: setuptools
    judges by its own copy in build/, which a source edited within the second of a build
    can look older than (the copy here keeps whole-second times), and would keep the
    core of before the edit."""
    sources = [*(REPO / "csrc").iterdir(), REPO / "setup.py"]
    built = list((REPO / "mousedom").glob("_core.*.so"))
    newest = max(p.stat().st_mtime for p in sources)
    if built and min(p.stat().st_mtime for p in built) >= newest:
        return
    subprocess.run(
        [sys.executable, "setup.py", "-q", "build_ext", "--inplace", "--force"],
        cwd=REPO, capture_output=True, timeout=300, check=False,
    )  # fmt: skip


if os.environ.get("MOUSEDOM_BUILD_CORE", "1") != "0":
    _build_core_in_place()


def _find_external_captures() -> Path:
    """The real recordings: a byte-exact copy of ../shared/captures/external is kept in
    tests/data/external (492 KB, MIT-licensed, provenance in its SOURCES.md), so that a
    clone anywhere tests against them; $MOUSEDOM_EXTERNAL_CAPTURES points elsewhere."""
    if os.environ.get("MOUSEDOM_EXTERNAL_CAPTURES"):
        return Path(os.environ["MOUSEDOM_EXTERNAL_CAPTURES"])
    return REPO / "tests" / "data" / "external"


EXTERNAL_CAPTURES = _find_external_captures()


def mousedom_env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(extra)
    return env


def dds_domain(low: int = 100, high: int = 230) -> int:
    """A DDS domain in [low, high) for a test whose participants share the host's loopback:
    random (what an earlier run left behind on its domain cannot reach this one), and one
    that no other worker draws where pytest-xdist runs the suite's workers side by side
    (README's test command), so that two tests' daemons never hear each other.  Tests in a
    network namespace of their own (test_ros2_interop) need none of this."""
    import random

    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
    mine = [d for d in range(low, high) if d % count == worker % count]
    if not mine:
        raise LookupError(f"no DDS domain in [{low}, {high}) for worker {worker} of {count}")
    return random.Random().choice(mine)


def a_group() -> str:
    """A group this machine has that the test user is not likely to be in (the fakes of
    /dev/input give their nodes to it)."""
    import grp

    for name in ("tty", "disk", "users", "daemon"):
        try:
            grp.getgrnam(name)
            return name
        except KeyError:
            continue
    raise LookupError("none of tty, disk, users, daemon is a group here")


def run_mousedom(
    *args: str, input: str | bytes | None = None, timeout: float = 120, **kw
) -> subprocess.CompletedProcess:
    """Run ``mousedom ARGS`` as a subprocess and return the completed process (text mode)."""
    text = not isinstance(input, bytes)
    return subprocess.run(
        [sys.executable, "-m", "mousedom", *args],
        input=input,
        capture_output=True,
        text=text,
        timeout=timeout,
        env=kw.pop("env", None) or mousedom_env(),
        **kw,
    )


def external_dir() -> Path:
    """The real recordings: CI always has them (missing there is a failure); elsewhere a
    $MOUSEDOM_EXTERNAL_CAPTURES that names no folder skips the test."""
    if not EXTERNAL_CAPTURES.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"{EXTERNAL_CAPTURES} is missing in CI")
        pytest.skip(f"{EXTERNAL_CAPTURES} not present ($MOUSEDOM_EXTERNAL_CAPTURES)")
    return EXTERNAL_CAPTURES


@pytest.fixture
def external_captures() -> Path:
    """external_dir() as a fixture."""
    return external_dir()
