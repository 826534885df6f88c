"""The package is type-clean and lint-clean (issue 27): mypy over mousedom/ with the config
in pyproject.toml ([tool.mypy]), and ruff over everything with its config (line length
100, complexity at most 15 per function: C901).  Both are in the ``test`` extra, so in CI
these run, never skip; what cannot be typed is narrowed where it enters our code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", *args], cwd=REPO, capture_output=True, text=True, timeout=600
    )


def test_mypy_finds_nothing_in_the_package():
    done = _run("mypy", "--no-error-summary")  # files and options: pyproject.toml
    assert done.returncode == 0, done.stdout + done.stderr


def test_ruff_finds_nothing_anywhere():
    done = _run("ruff", "check", "--no-cache", "mousedom", "tests", "scripts", "bench")
    assert done.returncode == 0, done.stdout + done.stderr
