"""scripts/mutants.py stays in step with the code (issue 29): every mutant's text to mutate
occurs exactly once in its file, so no mutant goes STALE unnoticed when the code moves."""

from __future__ import annotations

import sys

import pytest
from conftest import REPO

sys.path.insert(0, str(REPO / "scripts"))
from mutants import MUTANTS  # noqa: E402


@pytest.mark.parametrize("mutant", MUTANTS, ids=[m.name for m in MUTANTS])
def test_each_mutant_still_finds_its_text_once(mutant):
    text = (REPO / mutant.path).read_text()
    assert text.count(mutant.old) == 1, (
        f"{mutant.name}: its text occurs {text.count(mutant.old)} times in {mutant.path}; "
        "update scripts/mutants.py with the code"
    )
    for test in mutant.tests:
        assert (REPO / test.split("::")[0]).is_file(), test
