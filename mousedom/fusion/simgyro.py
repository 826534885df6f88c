"""A simulated MEMS gyro about the body's z axis, with exact truth (issue 30).

Each sample stamped t is the average of the sensed rate over the sample period before it
(what a gyro's digital low-pass filter and decimation give, to first order), so the
samples' sum times the period is the integral of the sensed rate: the tracker's windows
can be checked against the exact turn.  The sensed rate is

    (1 + scale_error) * true rate + bias(t) + white noise,   saturated, quantised

with the bias a random walk from its initial value (plus any jumps: a fault).

The defaults are an InvenSense MPU-6050 at FS_SEL = 0 (datasheet PS-MPU-6000A-00 rev. 3.4,
table 6.1): rate noise spectral density 0.005 deg/s/sqrt(Hz), full scale +-250 deg/s at
131 LSB per deg/s, sensitivity tolerance +-3 % (scale_error, 0 by default: a test sets
it).  The datasheet gives no bias stability figure; 0.5 deg/s of bias left after a
start-up calibration and a random walk of 0.001 deg/s/sqrt(s) are assumptions of the
order consumer MEMS gyros show (Allan deviation plots of MPU-6050 class parts), stated
here so that a test can change them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SimGyro:
    """A gyro's figures, SI units (rad/s, rad/s/sqrt(Hz), rad/s/sqrt(s))."""

    sample_hz: float = 200.0
    density: float = math.radians(0.005)  # white rate noise density
    bias: float = math.radians(0.5)  # at the start of the drive
    bias_walk: float = math.radians(0.001)  # random walk density of the bias
    scale_error: float = 0.0  # (1 + scale_error) * true rate
    full_scale: float = math.radians(250.0)  # |rate| beyond reads as this
    lsb: float = math.radians(1.0 / 131.0)  # one count of the raw reading
    phase: float = 0.0  # seconds: the first sample's offset in its period
    bias_jumps: tuple[tuple[float, float], ...] = ()  # (t, rad/s added from t on): faults


@dataclass
class GyroSamples:
    """Stamps (s) and yaw rates (rad/s, CCW positive); ``bias`` is the true bias of each
    sample (for tests), ``saturated`` where the reading was clipped."""

    t: np.ndarray
    rate: np.ndarray
    bias: np.ndarray
    saturated: np.ndarray


def sample(
    gyro: SimGyro,
    heading: np.ndarray,
    times: np.ndarray,
    rng: np.random.Generator,
) -> GyroSamples:
    """The gyro's samples at ``times`` (their stamps), given the true ``heading`` at each
    time and one period before it (shape (n, 2): [theta(t - P), theta(t)])."""
    period = 1.0 / gyro.sample_hz
    true_rate = (heading[:, 1] - heading[:, 0]) / period
    n = len(times)
    bias = gyro.bias + np.cumsum(rng.normal(0.0, gyro.bias_walk * math.sqrt(period), n))
    for t_jump, delta in gyro.bias_jumps:
        bias = bias + np.where(times >= t_jump, delta, 0.0)
    white = rng.normal(0.0, gyro.density * math.sqrt(gyro.sample_hz), n)
    sensed = (1.0 + gyro.scale_error) * true_rate + bias + white
    saturated = np.abs(sensed) >= gyro.full_scale
    sensed = np.clip(sensed, -gyro.full_scale, gyro.full_scale)
    rate = np.round(sensed / gyro.lsb) * gyro.lsb
    return GyroSamples(t=times, rate=rate, bias=bias, saturated=saturated)
