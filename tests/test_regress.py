"""Regression cases kept as gpsd keeps them: recorded input plus the expected output.

Each folder of ``tests/regress/`` holds a case: ``cmd`` (the arguments of one ``mousedom``
command, split as a shell splits them, run in a copy of the folder), the input files it
names, and ``expected``: the exit status, stdout and stderr the command must give, with
the copy's path written ``<case>`` and the repository's ``<repo>``.  A case records one
bug that was found (its ``cmd`` says which in a ``#`` line) and the answer it must get now.

Regenerate after a deliberate change of output with ``MOUSEDOM_REGEN=1 python -m pytest
tests/test_regress.py``, and read the diff before committing it.
"""

from __future__ import annotations

import os
import shlex
import shutil
from pathlib import Path

import pytest
from conftest import REPO, run_mousedom

CASES = Path(__file__).resolve().parent / "regress"


def _cases() -> list[str]:
    return sorted(p.name for p in CASES.iterdir() if (p / "cmd").is_file())


def _args(case: Path) -> list[str]:
    lines = [ln for ln in (case / "cmd").read_text().splitlines() if not ln.startswith("#")]
    return shlex.split(" ".join(lines))


def _render(code: int, out: str, err: str, work: Path) -> str:
    text = f"exit {code}\n--- stdout\n{out}--- stderr\n{err}"
    return text.replace(str(work), "<case>").replace(str(REPO), "<repo>")


@pytest.mark.parametrize("name", _cases())
def test_regression_case(name, tmp_path):
    case = CASES / name
    work = tmp_path / name
    shutil.copytree(case, work)
    proc = run_mousedom(*_args(case), cwd=work, timeout=60)
    got = _render(proc.returncode, proc.stdout, proc.stderr, work)
    expected = case / "expected"
    if os.environ.get("MOUSEDOM_REGEN"):
        expected.write_text(got)
    assert expected.is_file(), f"{expected}: missing (MOUSEDOM_REGEN=1 writes it)"
    assert got == expected.read_text()
    assert "Traceback" not in proc.stderr


def test_there_are_cases():
    assert len(_cases()) >= 10
