"""Pacing with an injected clock: no test sleeps."""

from __future__ import annotations

import numpy as np
import pytest

from mousedom.capture.pacing import Pacer, paced
from mousedom.fusion.tracker import PoseBatch


class FakeClock:
    def __init__(self, now: float = 500.0) -> None:
        self.now = now
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, dt: float) -> None:
        assert dt > 0
        self.sleeps.append(dt)
        self.now += dt


def _batch(t):
    n = len(t)
    z = np.zeros(n)
    return PoseBatch(
        t=np.asarray(t, float),
        x=z,
        y=z,
        theta=z,
        vx=z,
        vy=z,
        omega=z,
        cov=np.zeros((n, 3, 3)),
        used=np.ones(n, int),
        ok=np.ones(n, bool),
        residual=np.zeros((n, 1, 2)),
        counts=np.zeros((n, 1, 2)),
        state=np.zeros((n, 1), np.int8),
        reason=np.zeros((n, 1), np.int8),
        consistent=np.ones(n, bool),
        qcov=np.zeros((n, 3, 3)),
    )


@pytest.mark.parametrize("speed", [0.5, 1.0, 4.0])
def test_windows_are_released_when_due(speed):
    clock = FakeClock()
    pacer = Pacer(speed, clock=clock, sleep=clock.sleep)
    released = []
    sink = paced(lambda b: released.append((float(b.t[0]), clock.now)), pacer)
    sink(_batch([10.0, 10.5, 11.0]))
    sink(_batch([13.0]))
    for t, at in released:
        assert at == pytest.approx(500.0 + (t - 10.0) / speed)
    assert sum(clock.sleeps) == pytest.approx(3.0 / speed)


def test_late_data_is_not_delayed_further():
    clock = FakeClock()
    pacer = Pacer(1.0, clock=clock, sleep=clock.sleep)
    pacer.wait(0.0)
    clock.now += 5.0  # the consumer was slow
    pacer.wait(2.0)
    assert clock.sleeps == []
    assert pacer.data_time(clock.now) == pytest.approx(5.0)


def test_speed_must_be_positive():
    with pytest.raises(ValueError):
        Pacer(0.0)
