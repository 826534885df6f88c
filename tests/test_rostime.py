"""The system clock's lead over CLOCK_MONOTONIC, as ROS 2 stamps are converted with it."""

import time

import pytest

from mousedom.service.rostime import system_lead


def _clocks(reads: list[tuple[float, float, float]]):
    """A monotonic and a wall clock giving, per try, (monotonic, wall, monotonic)."""
    seq = [v for r in reads for v in r]
    pos = [0]

    def take() -> float:
        pos[0] += 1
        return seq[pos[0] - 1]

    return take, take


@pytest.mark.parametrize("lost", [0, 1, 2])
def test_a_read_that_lost_the_cpu_is_not_the_one_kept(lost):
    """True lead 1000 s; the process loses the CPU for 20 ms inside every try but one:
    the tightly bracketed try gives the lead to microseconds, wherever it falls."""
    reads = []
    for i in range(3):
        a = 5.0 + i
        if i == lost:
            reads.append((a, a + 1000.0 + 1e-6, a + 2e-6))
        else:  # the wall clock read 20 ms after the first monotonic one
            reads.append((a, a + 1000.0 + 0.02, a + 0.02 + 1e-6))
    wall, clock = _clocks(reads)
    assert system_lead(wall, clock) == pytest.approx(1000.0, abs=2e-6)


def test_a_clean_first_read_is_enough():
    wall, clock = _clocks([(1.0, 11.0, 1.0)])  # one try: more reads would run off the list
    assert system_lead(wall, clock) == 10.0


def test_on_this_machine_it_is_the_clocks_lead():
    assert system_lead() == pytest.approx(time.time() - time.monotonic(), abs=0.05)
