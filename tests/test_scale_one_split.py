"""A mouse off on one axis where a scale per axis for every mouse is more than the drive
tells apart (``ScaleLearner._one_split``): a scale per axis for that mouse alone.

A drive that never slides leaves every sideways axis against every forward one free, so
``fit_axes`` with every mouse split finds no axis plainly off, and the mouse's one scale
(some mean of its two axes) bent the healthy mice: on the named layouts, with one mouse
2-8 % off on one axis, 7 of 36 generated drives ended further off than with fault
handling off (one 302 mm against 27), and the sum of their end errors was 8.3 m (off
13.5 m).  Splitting one mouse alone is told apart where the geometry allows; where two
mice's splits fit the error about as well (a close pair, a line along x), neither is
split."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mousedom.fusion import conditions, scalelearn, scenarios, sim

COUNTS_PER_M = 1000 / 0.0254
LAYOUTS = ("triangle", "square", "wide", "pentagon", "kite", "close-pair-plus", "far-one",
           "line-along", "offset-ring")  # fmt: skip


def _learnt(layout: str, bad: int, axis: int, err: float, seed: int, blocks: int = 20):
    """A learner on ``layout`` fed ``blocks`` blocks of a drive that never slides
    (forward 0.05-0.15 m/s, turning either way), mouse ``bad``'s count ``axis`` reading
    1 + err times its motion, every count with 0.3 counts of noise.  Returns the learner
    and the mice it split at any block end."""
    pos = np.array([[m.x, m.y] for m in scenarios.rig(layout).mice])
    n = len(pos)
    base = np.repeat(np.eye(2)[None] / COUNTS_PER_M, n, axis=0)
    learner = scalelearn.ScaleLearner("lsq", base, pos, np.full(n, 1e-5), 0.01, 0.1)
    rng = np.random.default_rng(seed)
    ever = np.zeros(n, dtype=bool)
    for _ in range(blocks):
        w = learner.block
        q = np.stack([rng.uniform(0.5e-3, 1.5e-3, w), np.zeros(w),
                      rng.uniform(-1e-2, 1e-2, w)], axis=1)  # fmt: skip
        body = np.stack([q[:, None, 0] - q[:, None, 2] * pos[None, :, 1],
                         q[:, None, 1] + q[:, None, 2] * pos[None, :, 0]], axis=2)  # fmt: skip
        counts = body * COUNTS_PER_M
        counts[:, bad, axis] *= 1.0 + err
        counts += rng.normal(0, 0.3, counts.shape)
        assert learner.add(counts, np.ones((w, n), dtype=bool))
        ever |= learner.split
    return learner, ever


def _draw(layout: str, seed: int) -> tuple[int, int, float]:
    n = len(scenarios.rig(layout).mice)
    rng = np.random.default_rng((1, seed))
    return (
        int(rng.integers(n)),
        int(rng.integers(2)),
        float(rng.choice([-1, 1]) * rng.uniform(0.03, 0.07)),
    )


@pytest.mark.parametrize("layout", LAYOUTS)
def test_no_healthy_mouse_is_ever_split(layout):
    """Six generated errors per layout: at no block end is a mouse other than the one off
    split (before the margin, the wide rig split a healthy one in 5 of 6, bending every
    scale by 1-2 %)."""
    for seed in range(6):
        bad, axis, err = _draw(layout, seed)
        _, ever = _learnt(layout, bad, axis, err, seed)
        ever[bad] = False
        assert not ever.any(), (seed, bad, axis, err, ever)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_healthy_rig_is_never_split(layout):
    for seed in range(3):
        learner, ever = _learnt(layout, 0, 0, 0.0, 100 + seed)
        assert not ever.any(), (seed, ever)
        assert np.abs(learner.scale - 1.0).max() < 0.003, learner.scale


@pytest.mark.parametrize("layout", ["offset-ring", "square", "pentagon"])
def test_where_the_geometry_tells_the_mouse_its_axis_is_corrected(layout):
    """Where one mouse's split is told apart from the others' (an offset ring, a square, a
    pentagon), the mouse off is split in every draw but at most one, its off axis given the
    scale its counts need and the other axis and the healthy mice within 0.3 %."""
    right = 0
    for seed in range(6):
        bad, axis, err = _draw(layout, seed)
        learner, _ = _learnt(layout, bad, axis, err, seed)
        scale = learner.scale
        healthy = np.delete(scale, bad, axis=0)
        right += bool(
            learner.split[bad]
            and abs(scale[bad, axis] - 1.0 / (1.0 + err)) < 0.003
            and abs(scale[bad, 1 - axis] - 1.0) < 0.003
            and np.abs(healthy - 1.0).max() < 0.003
        )
    assert right >= 5, right


@pytest.mark.parametrize(
    ("layout", "mouse", "err", "axes", "seed", "before"),
    [
        ("offset-ring", "m0", -0.042, "y", 1273, 0.302),
        ("pentagon", "front", 0.071, "y", 6756, 0.489),
    ],
)
def test_a_drive_with_one_axis_off_ends_no_further_than_without_scales(
    layout, mouse, err, axes, seed, before
):
    """Two of the named-layout drives (30 s) that one scale per mouse ended far beyond
    fault handling off (``before``, metres; off 27 and 99 mm, told the true CPI 7 and 9
    mm): they end within 5 mm of off or better."""
    base = scenarios.rig(layout)
    cond = conditions.condition("cpi-error", seed, cpi_mouse=mouse, cpi_error=err, cpi_axes=axes)
    rig = conditions.apply_condition(base, cond, 30.0)
    result = sim.simulate(rig, scenarios.drive(30.0, seed), seed=seed)
    on = scenarios.measure(result, conditions.condition_config(base, cond)).position
    off = scenarios.measure(result, conditions.condition_config(base, cond, robust=False)).position
    assert on < off + 0.005 and on < 0.2 * before, (on, off)
    assert math.isfinite(on)
