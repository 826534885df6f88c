"""Conditions of healthy rigs that are not faults (issue 31): USB polling gaps, late and
long-tailed arrival stamps, a noisier mouse, a CPI off from the one configured; each a
``Condition`` on a ``scenarios`` rig, run as a ``scenarios.Trial``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from mousedom.config import Config
from mousedom.fusion import sim
from mousedom.fusion.drives import drive
from mousedom.fusion.scenarios import Fault, Trial, apply, config, measure, rig

CONDITIONS = ("healthy", "usb-gaps", "late-stamps", "stamp-delay", "noisy", "cpi-error")


@dataclass(frozen=True)
class Condition:
    """What a healthy rig meets that is not a fault (issue 31), built by ``condition``.
    Each part acts on one mouse; None picks it from the rig: the slowest mouse for gaps,
    the fastest for stamps, the first for noise and CPI."""

    name: str = "healthy"
    seed: int = 0  # the gaps' draws
    gap_mouse: str | None = None
    gap_rate: float = 0.0  # gaps per second (0: none)
    gap_length: float = 0.03  # seconds, each gap's mean length
    gap_jitter: float = 0.3  # lengths uniform within this fraction of gap_length
    stamp_mouse: str | None = None
    stamp_tail: float = 0.0  # mean (s) of an exponential extra arrival delay
    stamp_delay: float | None = None  # uniform arrival delay (s) instead of the rig's
    noise_mouse: str | None = None
    noise_factor: float = 1.0  # the mouse's simulated noise, times the rig's
    cpi_mouse: str | None = None
    cpi_error: float = 0.0  # the true CPI is the nominal times (1 + cpi_error)
    cpi_axes: str = "xy"  # which axes' CPI is off

    def mouse(self, part: str, base: sim.Rig) -> str:
        """The mouse ``part`` ("gap", "stamp", "noise", "cpi") acts on in ``base``."""
        chosen = getattr(self, f"{part}_mouse")
        if chosen is not None:
            return chosen
        if part == "gap":
            return min(base.mice, key=lambda m: m.report_hz).name
        if part == "stamp":
            return max(base.mice, key=lambda m: m.report_hz).name
        return base.mice[0].name


_CONDITION_DEFAULTS: dict[str, dict[str, float]] = {
    "healthy": {},
    "usb-gaps": {"gap_length": 0.03},  # and a rate of 1 to 5 a second, drawn from the seed
    "late-stamps": {"stamp_tail": 0.003},
    "stamp-delay": {"stamp_delay": 0.003},
    "noisy": {"noise_factor": 5.0},
    "cpi-error": {"cpi_error": 0.1},
}


def condition(name: str, seed: int = 0, **params: Any) -> Condition:
    """The condition ``name`` (CONDITIONS, or several joined by "+", e.g.
    "usb-gaps+late-stamps") with its default parameters, any of which ``params`` (Condition's
    fields) overrides: usb-gaps ~30 ms gaps at a rate drawn from the seed between 1 and 5
    a second on the slowest mouse; late-stamps exponential extra stamp delays of mean 3 ms
    on the fastest mouse; stamp-delay uniform stamp delays up to 3 ms on it; noisy the first
    mouse 5 times noisier than simulated (the config keeps its sigma); cpi-error the first
    mouse's true CPI 10 % over the nominal one the config believes."""
    values: dict[str, Any] = {}
    for part in name.split("+"):
        if part not in _CONDITION_DEFAULTS:
            raise ValueError(f"unknown condition {part!r}; choose of {', '.join(CONDITIONS)}")
        values.update(_CONDITION_DEFAULTS[part])
        if part == "usb-gaps":
            values["gap_rate"] = float(np.random.default_rng((4000, seed)).uniform(1.0, 5.0))
    values.update(params)
    return Condition(name, seed, **values)


def apply_condition(base: sim.Rig, cond: Condition, duration: float) -> sim.Rig:
    """The rig as it truly is under ``cond`` for a drive of ``duration`` seconds."""
    names = {m.name for m in base.mice}
    for part in ("gap", "stamp", "noise", "cpi"):
        if cond.mouse(part, base) not in names:
            raise ValueError(f"condition {cond.name}: no mouse {cond.mouse(part, base)!r}")
    mice = []
    for m in base.mice:
        if m.name == cond.mouse("gap", base) and cond.gap_rate > 0:
            rng = np.random.default_rng((3000, cond.seed))
            gaps = sim.usb_gap_spans(rng, duration, cond.gap_rate, cond.gap_length, cond.gap_jitter)
            m = dataclasses.replace(m, usb_gaps=gaps)
        if m.name == cond.mouse("stamp", base):
            m = dataclasses.replace(m, stamp_tail=cond.stamp_tail)
            if cond.stamp_delay is not None:
                m = dataclasses.replace(m, stamp_delay=cond.stamp_delay)
        if m.name == cond.mouse("noise", base):
            m = dataclasses.replace(m, noise=m.noise * cond.noise_factor)
        if m.name == cond.mouse("cpi", base) and cond.cpi_error:
            f = 1.0 + cond.cpi_error
            m = dataclasses.replace(
                m,
                cpi_x=m.cpi_x * f if "x" in cond.cpi_axes else m.cpi_x,
                cpi_y=m.cpi_y * f if "y" in cond.cpi_axes else m.cpi_y,
            )
        mice.append(m)
    return dataclasses.replace(base, mice=tuple(mice))


class FaultyDrive(NamedTuple):
    """A drive with a fault under a condition, simulated (``faulty_drive``)."""

    base: sim.Rig  # the rig as configured (no fault, nominal CPI)
    cond: Condition
    fault: Fault
    traj: list[sim.Segment]
    result: sim.SimResult


def faulty_drive(
    layout: str, cond: Condition, fault: Fault, seed: int, duration: float
) -> FaultyDrive:
    """``drive(duration, seed)`` on ``layout`` as it truly is under ``cond``, with ``fault``
    on it: what the fault sweeps (scripts/fault_sweep.py) and their tests run, through
    ``condition_config(base, cond)`` and the informed reference
    (``scenarios.informed_dead(fault, base, traj)``)."""
    base = rig(layout)
    traj = drive(duration, seed)
    true = apply(apply_condition(base, cond, duration), fault)
    return FaultyDrive(base, cond, fault, traj, sim.simulate(true, traj, seed=seed))


def condition_config(
    base: sim.Rig, cond: Condition, robust: bool = True, told: bool = False
) -> Config:
    """The config the robot runs ``cond`` with: the nominal CPI (what ``base`` says) while
    the simulated mouse has the true one, unless ``told`` (the true CPI, as a user who had
    measured it would write)."""
    true = apply_condition(base, dataclasses.replace(cond, gap_rate=0.0), 0.0)
    nominal = {m.name: (m.cpi_x, m.cpi_y) for m in base.mice}
    return config(true, robust=robust, cpi=None if told else nominal)


def condition_trial(layout: str, cond: Condition | str, seed: int, duration: float) -> Trial:
    """``drive(duration, seed)`` on ``layout`` under ``cond`` (a Condition, or a name for
    ``condition(name, seed)``).  informed: plain least squares told the true CPI, on the
    same drive without the timing and noise conditions (for cpi-error alone: the same
    reports); clean: the default engine on the same drive without the condition at all."""
    if isinstance(cond, str):
        cond = condition(cond, seed)
    traj = drive(duration, seed)
    base = rig(layout)
    result = sim.simulate(apply_condition(base, cond, duration), traj, seed=seed)
    timing = (cond.gap_rate > 0, cond.stamp_tail > 0, cond.stamp_delay is not None)
    if any(timing) or cond.noise_factor != 1.0:
        cpi_only = Condition(
            "cpi-error", cpi_mouse=cond.cpi_mouse, cpi_error=cond.cpi_error, cpi_axes=cond.cpi_axes
        )
        informed_result = sim.simulate(apply_condition(base, cpi_only, duration), traj, seed=seed)
    else:
        informed_result = result
    return Trial(
        f"{layout} {cond.name}",
        measure(result, condition_config(base, cond)),
        measure(result, condition_config(base, cond, robust=False)),
        measure(informed_result, condition_config(base, cond, robust=False, told=True)),
        measure(sim.simulate(base, traj, seed=seed), config(base)),
        (),
        seed,
    )
