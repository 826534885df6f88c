"""Every parser against the fuzz cases of ``fuzz_targets`` (issue 11: a bounded run here,
long runs with ``scripts/fuzz.py``).

Valid cases (random reports written in the many ways users hand files over) must be
accepted with counts in = reported + counted as lost; damaged ones may be refused with a
one-line UserError, and nothing may crash or hang."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import REPO
from fuzz_targets import TARGETS, make_case, run_case
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

# Every roundtrip case is valid by construction (fuzz_targets.make_case): the valid-case
# test below runs them and holds each to "ok", more than "ok or refused" here, so they are
# drawn there only.  A layout case takes half a second (a whole YAML document parsed):
# fewer draws here; the long runs are scripts/fuzz.py's.
FUZZED = tuple(t for t in TARGETS if t != "roundtrip")
FUZZ_EXAMPLES = {"layout": 40}


def _fuzz_one(tmp_path, target, seed):
    case = make_case(target, seed)
    result = run_case(case, str(tmp_path))
    assert result.outcome in ("ok", "refused"), (case.kind, result.outcome, result.detail)


@pytest.mark.parametrize("target", FUZZED)
def test_no_crash_hang_or_wrong_count(tmp_path, target):
    @settings(
        max_examples=FUZZ_EXAMPLES.get(target, 120),
        deadline=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture],
    )
    @given(seed=st.integers(0, 2**31))
    def fuzz(seed):
        _fuzz_one(tmp_path, target, seed)

    fuzz()


# Targets whose cases take a tenth of a second or more (a whole YAML document re-laid out;
# a capture written, converted and read back in every format): fewer seeds here (roundtrip
# took 67 s of the suite at 400), the long runs in scripts/fuzz.py.
SLOW = {"layout": 100, "roundtrip": 120}


@pytest.mark.parametrize("target", TARGETS)
def test_valid_cases_are_accepted_with_their_truth(tmp_path, target):
    """The valid generators themselves: every one is read back exactly (a generator that
    wrote nothing, or a runner that checked nothing, would pass the test above)."""
    seen = 0
    seeds = SLOW.get(target, 400)
    for seed in range(seeds):
        case = make_case(target, seed)
        if case.kind != "valid":
            continue
        seen += 1
        result = run_case(case, str(tmp_path))
        assert result.outcome == "ok", (seed, result.detail)
    assert seen > seeds // 5


def test_a_runner_notices_a_wrong_count(tmp_path):
    """The runner's check is not a formality: a case whose truth is off by one count is
    reported as wrong."""
    for seed in range(50):
        case = make_case("evemu", seed)
        if case.kind == "valid":
            break
    case.truth = (case.truth[0] + 1, case.truth[1])
    assert run_case(case, str(tmp_path)).outcome == "wrong"


def test_the_fuzz_script_prints_its_figure():
    proc = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "fuzz.py"), "--cases", "70", "--seed", "3"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    last = proc.stdout.strip().splitlines()[-1]
    assert last.startswith("fuzz: 70 cases, 0 crashes, 0 hangs, 0 wrong counts (seed 3")
