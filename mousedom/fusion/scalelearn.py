"""Online scale calibration from the redundancy of three or more mice (issue 31, item 3).

This module holds the learner: its evidence, blocks, what it applies and gives back; the
fits themselves, pure functions of the evidence, are ``scalefit``'s.

A CPI a few per cent off hides inside each window's noise but is plain over many.  Stack
every mouse's body displacement as its config reads it, d_i = M_i c_i (M_i: counts to
body, c_i: its counts), and give each mouse a scale g_i: J g = (g_1 d_1, ..., g_N d_N).
A rigid rig's readings are A q for some twist q; P = I - A (A' W A)^-1 A' W keeps what no
twist explains (W: the config's sigmas).  With the true scales, P J g is only noise; so
the scales minimise g' S g, S = sum over the evidence of (P J)' W (P J), an N x N matrix
summed as windows close (forgetting with a half-life of ``HALF_LIFE_S``, so that a mouse
whose scale changes, on a new floor, is followed).  The evidence: groups of GROUP_S of
consecutive windows in which every mouse tracked, counts summed (a count read a few ms late
moves between neighbouring windows, not out of their sum, so timing noise cancels, where
it would bias a fit per window towards 0).

S has one null direction: all mice scaled together change no prediction (the common mode
is not observable: docs/calibration.md).  So g is the solution of (S + mu) g = mu 1, mu a
millionth of S's diagonal (the data decide everything but the common mode, which stays
near 1), divided by its median mouse (with one mouse wrong, a right one).  Its spread:
the residual g' S g per degree of freedom through the inverse of S off the null
direction.  One scale per mouse, both axes, for the fusion: a CPI is most often wrong for
a sensor as a whole, and per axis the sideways one (which reads the turn) is often too
weakly observable to trust within the seconds the fusion has.  The same evidence is also
kept per count axis, J's column per mouse split in two (S is then 2N x 2N), and
``scalefit.fit_axes`` gives a scale per axis with the spread of each and of their difference,
infinite where the drive does not tell an axis apart from the others: a mouse whose CPI
is off on one axis only reads, in one scale, as some mean of the two (of either sign),
and the misfit bends the healthy mice's scales.  So a mouse whose two axes differ plainly
is given a scale per axis, the others one each from the same fit (``_split_axes``);
`calibrate scales` reads the per-axis evidence over a whole drive.

The learnt scale is applied where plain (more than ``scalefit.PLAIN`` of its standard
deviations and ``_MIN_APPLIED`` from 1, after ``scalefit.MIN_GROUPS`` groups of evidence
(the first second's estimate is no better than its start), as noise applied to a mouse
that reads the turn is heading lost for good, and on healthy rigs the estimates sit within
a tenth of a per cent of 1, timing and rounding), clipped to ``bounds`` (a CPI within +-
``limit`` of the config's), by multiplying the mouse's counts (its counts-to-body
matrix) from the next block of windows on: a mouse 3 % off is corrected within the first
seconds of motion.
``robust.learn_scale: false`` leaves the counts as they are; the estimate is reported
either way (PoseBatch.scale, the replay summary and CSV), and a mouse 10 % or more off is
warned of (``warnings``): a CPI typo, or the wrong mouse's CPI.

Evidence comes in blocks of windows (``block``, BLOCK_S): the rows of a block are
kept and evaluated at once with numpy, the same operations for the daemon's one window at a
time and replay's arrays (the same scales, to the rounding in which the screen's float
path and its arrays differ).  Only windows the fault screen found consistent, with every
mouse tracking (used, not suspect), count.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from mousedom.fusion.scalefit import (
    CHANGE_SEGMENTS,
    MIN_GROUPS,
    PLAIN,
    AxisEvidence,
    axis_scales,
    change_point,
    fit,
    fit_axes,
    motion_columns,
    plain_change,
    projected,
    projector,
    reads,
    residual_per_dof,
    scales_differ,
    unexplained,
    widened,
)

GROUP_S = 0.1  # windows are summed over this long before they are compared
BLOCK_S = 0.5  # the scales are renewed this often
HALF_LIFE_S = 120.0  # seconds of evidence after which old sums count half
# A mouse reading this much more or less than the others (beyond the scale's uncertainty)
# is a clear CPI mistake: a CPI 10 % off is warned of, allowing for the estimate's noise.
WARN = 0.095
# A scale is applied where plain (``scalefit.PLAIN`` of its standard deviations from 1,
# after ``scalefit.MIN_GROUPS`` groups of evidence) and this far from 1: below, the
# estimate's own bias (timing, rounding)
_MIN_APPLIED = 0.005
# Once applied, a scale stays applied while this far out (hysteresis: a scale that crossed
# the edge of plain back and forth would give its turn and take it back at every renewal)
_KEEP_PLAIN = 2.0
_KEEP_APPLIED = 0.0035
_MIN_COUNTS = 40.0  # counts a mouse must read in a group for it to be evidence
# A block's own scale this far beyond the bounds (a fraction of the bound), and this many of
# its spreads, is a fault, not a CPI (``_faults``); from this many groups of the block.
FAULT_MARGIN = 0.15
FAULT_SIGMAS = 5.0
_FAULT_GROUPS = 3
_BEYOND_MIN = 0.01
# A faulty block's windows are given back at its own scale of the mouse only where that
# scale explains its readings: the block's residual per degree of freedom at most this
# many times the evidence's (``_in_proportion``)
_PROPORTION = 9.0
# A mouse given a scale per axis on its own (``_one_split``): its split explains this many
# times as much of what one scale each leaves unexplained as any other mouse's would
_ONE_SPLIT_MARGIN = 1.5
# The jackknife's segments of evidence (``jackknife``): a block each, the oldest two merged
# beyond this many (20 s of motion with every mouse tracking; older evidence is forgotten
# towards half by HALF_LIFE_S).
_SEGMENTS = 40
# The change test (``_changed``: ``scalefit.CHANGE_SEGMENTS`` recent segments of evidence
# against the older ones) needs this many older segments.
_CHANGE_OLDER = 4


def joined(chunks: Sequence[ArrayLike], dtype: DTypeLike) -> np.ndarray:
    """A block's rows as one array: the chunks (arrays from ``add``, one window's lists
    from ``add_row``) concatenated; a lone chunk (replay's blocks: the tracker splits its
    windows at block ends) as it is, for np.concatenate would copy it: so the caller's
    array, maybe, to read and keep no view of."""
    if len(chunks) == 1:
        return np.asarray(chunks[0], dtype=dtype)
    lists = [c for c in chunks if isinstance(c, list)]
    if len(lists) == len(chunks):
        # the daemon's blocks: a window's lists each, one array built from all their rows
        # (an array per window and their concatenation cost a tenth of a block's learning)
        return np.array([row for c in lists for row in c], dtype=dtype)
    return np.concatenate([np.asarray(c, dtype=dtype) for c in chunks])


class BlockGave(NamedTuple):
    """What a learnt block's windows gave the horizon (``_gave``), kept for the give-back
    of a mouse it or the next block finds faulty (``_give_back_faults``): each mouse's
    own turn and walk per unit scale, unforgotten (``unit`` (N, 2), ``local`` (N, 2, 2))
    and its steps turned summed (``steps`` (2,)); and the same window by window, for a
    give-back that must leave some windows out (the screen's take-backs, ``_not_taken``):
    the number of its first window (``ScaleLearner._serial``), each window's turn per
    unit scale (K, N, 2), its step turned by 90 degrees (K, 2), and what each mouse's
    count axes moved the body in it, world axes (K, N, 2, 2)."""

    unit: np.ndarray
    local: np.ndarray
    steps: np.ndarray
    first: int
    per: np.ndarray
    perp: np.ndarray
    straight: np.ndarray


class BlockFaults(NamedTuple):
    """What a block found (``ScaleLearner._faults``)."""

    faulty: list[int]  # the mice found faulty
    scale: np.ndarray | None  # the block's own scales, where its windows are given back at them
    beyond: bool  # its own scales put some mouse beyond the bounds: not learnt as a CPI


class ScaleLearner:
    """Each mouse's scale, learnt from the others (module docstring); kept per count axis
    (both the same) for the reports, which have a column per axis."""

    def __init__(
        self,
        model: str,
        to_body: np.ndarray,
        positions: np.ndarray,
        sigma: np.ndarray,
        window: float,
        limit: float,
    ) -> None:
        self.n = len(positions)
        self.base = np.asarray(to_body, dtype=float)  # (N, 2, 2) counts -> body, as configured
        self.positions = np.asarray(positions, dtype=float)
        self.limit = float(limit)
        self.block = max(10, math.ceil(BLOCK_S / window - 1e-9))
        self.forget = 0.5 ** (self.block * window / HALF_LIFE_S)
        self.group = max(1, round(GROUP_S / window))  # windows summed into one reading
        self.cols = (0, 2) if model == "diff-drive" else (0, 1, 2)
        # P = I - A (A' W A)^-1 A' W: what of the stacked displacements (2N,) no motion of
        # the rig explains, W the config's sigmas (all mice in use)
        n2 = 2 * self.n
        a = motion_columns(self.positions, self.cols)
        self.weight = np.repeat(1.0 / np.asarray(sigma, dtype=float) ** 2, 2)
        aw = a.T * self.weight
        self.project = projector(a, self.weight)
        # The heading row of that least squares (every mouse in use): what each reading
        # adds to a window's turn (_turn_owed)
        est = np.linalg.solve(aw @ a, aw) if self.n >= 3 else np.zeros((len(self.cols), n2))
        self.turn_row = est[-1]
        # and its body x and y rows (diff-drive: no sideways motion), as the share of body
        # axis o in what mouse i's count axis a reads, (i, a, o): what a scale moved (_gave)
        bxy = np.zeros((2, n2))
        bxy[: len(self.cols) - 1] = est[:-1]
        self._move_base = np.einsum("oib,iba->iao", bxy.reshape(2, self.n, 2), self.base)
        # _gave's per mouse and count axis (i, a): the turn row's body axis b times what
        # count axis a moves body axis b, (i, b, a); and _learn_held_out's counts per body
        # metre, both of the configuration (base never changes)
        self._turn_base = self.turn_row.reshape(self.n, 2)[:, :, None] * self.base
        self._base_inv = np.linalg.inv(self.base)
        self.gram = np.zeros((self.n, self.n))  # S, forgetting
        self._segments: list[np.ndarray] = []  # S in blocks (``jackknife``), forgetting
        self._segment_groups: list[float] = []  # the groups of each, forgetting alike
        self.changes = 0  # changes of scale found (``_changed``): evidence before dropped
        # of the last: the mice that changed, and each one's scale after over before
        self.changed: list[tuple[int, float]] = []
        self._segment_count = 0  # segments of evidence ever added (numbering them)
        # the recent blocks' parts of turn_unit and walk_unit (``_gave``), those that share
        # the number of the first segment that may follow them composed into one:
        # (first, forgetting, turn, walk, steps turned)
        self._recent_gave: list[tuple[int, float, np.ndarray, np.ndarray, np.ndarray]] = []
        # per count axis (``fit_axes``): S with a column per mouse and axis, 2N x 2N, and
        # its blocks, forgetting as S does (``_split_axes``: a mouse off on one axis is
        # given a scale per axis; `calibrate scales` reads it over a whole drive)
        self.split = np.zeros(self.n, dtype=bool)  # the mice given a scale per axis
        self.axis_gram = np.zeros((2 * self.n, 2 * self.n))
        self.axis_segments: list[np.ndarray] = []
        # per mouse, from the groups it was left out of: sum X.X, X.Y, Y.Y, groups
        self.held = np.zeros((4, self.n))
        self.groups = 0.0  # groups of evidence in S, forgetting
        self.estimate = np.ones((self.n, 2))  # the fit, unclipped
        self.spread = np.full((self.n, 2), np.inf)  # its standard deviation
        self.one = np.ones(self.n)  # one scale per mouse (``fit``) and its spread
        self.one_spread = np.full(self.n, np.inf)
        self.scale = np.ones((self.n, 2))  # applied: the fit clipped to bounds
        # this block's (counts, usable, held_out, q, steps, in_solve, heading): arrays from
        # add, one window's lists from add_row
        self._rows: list[tuple[ArrayLike, ...]] = []
        self._held = 0  # windows in _rows
        self.version = 0  # bumped whenever the estimates are renewed
        self.faults: list[int] = []  # the mice the last block found faulty (_faults)
        self.beyond: list[int] = []  # the mice the evidence puts beyond the bounds (_beyond_bounds)
        # this block's part of ``held`` (``_released``)
        self._held_block = np.zeros((4, self.n))
        # Per mouse and count axis, forgetting: the turn its readings gave at scale 1
        # (unit) and at the scales applied (given), over windows with every mouse in use.
        self.turn_unit = np.zeros((self.n, 2))
        self.turn_given = np.zeros((self.n, 2))
        # and the position walked meanwhile, turned by those turns (to first order: the
        # sum over windows of the turn so far times the step turned by 90 degrees)
        self.walk_unit = np.zeros((self.n, 2, 2))
        self.walk_given = np.zeros((self.n, 2, 2))
        self._rebased = 0  # windows of this block added before the pose was last set
        self.turn_owed = 0.0  # what the heading is owed at the last renewal (take_turn)
        self.walk_owed = np.zeros(2)  # and the position
        # the last block's own turn and walk per unit scale and its steps turned summed,
        # unforgotten (``_gave``), and the block's before it (``_give_back_faults``)
        self._block: BlockGave | None = None
        self._prev_block: BlockGave | None = None
        self._serial = 0  # windows added ever (add, add_row): numbering them
        # The screen's take-backs (Screen.hand_taken): (mouse, first window, end window),
        # numbered as _serial numbers them.  The windows of a take-back no longer hold
        # that mouse's readings in the pose, so a give-back must not give them back again.
        self._taken: list[tuple[int, int, int]] = []
        self._learnt_last = False  # whether the block before this one was learnt

    @property
    def bounds(self) -> tuple[float, float]:
        """The scales that may be applied: those of a true CPI within +-limit of the
        configured one.  A mouse whose true CPI is (1 + e) times its config's reads 1 + e
        times its motion and needs the scale 1 / (1 + e); a bound of 1 +- limit on the
        scale itself left a mouse reading 10 % less (scale 1.111) clipped at 1.1, a
        heading drift of 0.3 degrees a second on a 10 cm triangle."""
        return 1.0 / (1.0 + self.limit), 1.0 / (1.0 - self.limit)

    @property
    def active(self) -> bool:
        """Whether anything can be learnt: three or more mice (two others to predict)."""
        return self.n >= 3

    def matrices(self) -> np.ndarray:
        """(N, 2, 2) counts -> body with the learnt scales applied (column a times g_a)."""
        return self.base * self.scale[:, None, :]

    def until_block_end(self) -> int:
        """Windows still to add before the current block ends (at least 1)."""
        return self.block - self._held

    def add(
        self,
        counts: np.ndarray,
        usable: np.ndarray,
        held_out: np.ndarray | None = None,
        q: np.ndarray | None = None,
        steps: np.ndarray | None = None,
        in_solve: np.ndarray | None = None,
        heading: np.ndarray | None = None,
        taken: Sequence[tuple[int, int, int]] = (),
    ) -> bool:
        """Add windows of the current block, at most ``until_block_end()`` of them; at the
        block's end, learn.  ``counts`` (n, N, 2) raw REL_X/REL_Y; ``usable`` (n, N): the
        mice tracking in consistent windows; ``held_out`` (n, N): the mice the screen
        left out as inconsistent, and ``q`` (n, 3) each window's twist increment from the
        others (a mouse whose CPI is far off is left out, and its scale is found from
        what the others say it moved: ``_learn_held_out``); ``steps`` (n, 2) the pose's
        step in each window, world axes (for ``take_walk``); ``in_solve`` (n,): whether
        the window's pose used every mouse (the turns it made are given back at a
        renewal, consistent or not; default: the windows with every mouse usable);
        ``heading`` (n,): the pose's heading in the middle of each window (radians, world;
        default 0), which turns what a scale moved the body into the world's axes;
        ``taken``: the screen's take-backs up to the last of these windows
        (``Screen.hand_taken``).  Returns whether a block ended (and the estimates were
        renewed)."""
        if not self.active or not len(counts):
            return False
        n = len(counts)
        if held_out is None or q is None:
            held_out, q = np.zeros((n, self.n), dtype=bool), np.zeros((n, 3))
        if steps is None:
            steps = np.zeros((n, 2))
        whole = np.asarray(usable).all(axis=1) if in_solve is None else np.asarray(in_solve)
        theta = np.zeros(n) if heading is None else np.asarray(heading)
        self._rows.append((np.asarray(counts), np.asarray(usable), np.asarray(held_out),
                           np.asarray(q), np.asarray(steps), whole, theta))  # fmt: skip
        self._held += n
        self._count(n, taken)
        return self.end_block()

    def add_row(
        self, counts: list, usable: list, held_out: list, q: list, step: list | None = None,
        in_solve: bool | None = None, heading: float = 0.0,
        taken: Sequence[tuple[int, int, int]] = (),
    ) -> bool:  # fmt: skip
        """``add`` for one window as Python values (the daemon's: no numpy per window),
        without the learning: True when the block is full, and ``end_block`` is due before
        the next window is added (the daemon runs it once the window's POSE is out)."""
        if not self.active:
            return False
        self._rows.append(([counts], [usable], [held_out], [q],
                           [step if step is not None else [0.0, 0.0]],
                           [all(usable) if in_solve is None else in_solve],
                           [heading]))  # fmt: skip
        self._held += 1
        self._count(1, taken)
        return self._held >= self.block

    def _count(self, n: int, taken: Sequence[tuple[int, int, int]]) -> None:
        """``n`` windows added, and the take-backs up to the last of them, counted back
        from it (Screen.hand_taken), numbered as the windows are."""
        self._serial += n
        for i, ago_from, ago_to in taken:  # (none in nearly every window)
            self._taken.append((i, self._serial - ago_from, self._serial - ago_to))

    def end_block(self) -> bool:
        """At a full block, learn from it (True); otherwise nothing (False)."""
        if self._held < self.block:
            return False
        # (each is only read: a lone chunk may be the caller's array)
        counts, usable, held_out, q, steps, in_solve, heading = (
            joined(chunks, dt)
            for chunks, dt in zip(zip(*self._rows, strict=True),
                                  (float, bool, bool, float, float, bool, float), strict=True)
        )  # fmt: skip
        self._rows, self._held = [], 0
        self._learn_held_out(counts, held_out, q)
        self._gave(counts, in_solve, steps, heading)
        self._learn(counts, usable)
        self._report_held_out()
        self._settle_turn()
        return True

    def _gave(
        self, counts: np.ndarray, whole: np.ndarray, steps: np.ndarray, heading: np.ndarray
    ) -> None:
        """Add the block's windows whose pose used every mouse (``whole``) to the turns
        each mouse gave, and to the walk: the one those turns bent, and the one its readings
        moved the body directly (where the mice are off the rig's centre, a CPI error moves
        the position as well as the heading: a 10 cm triangle 0.32 m off the centre, a
        mouse 7 % off, ended 23 mm off where its heading was given back to 0.02 degrees,
        told the true CPI 3 mm).  Inconsistent windows count as
        well: their pose took every mouse's reading at the scales of then (a 4 cm
        triangle with a mouse 7 % off turns 13 degrees a second; its 25 inconsistent
        windows before the scale was learnt kept 3.9 degrees of that, and 0.49 m after
        40 s, where the consistent ones' turn was given back)."""
        # mouse i's count axis a moves it base[i, :, a] * c[i, a] in body axes, and the
        # turn row makes that a turn: the sum over body axes written out (an einsum took
        # twice as long), from einsum's start of 0.0, which makes a turn of -0.0 +0.0
        # (so the sums below are einsum's, bit for bit)
        tb = self._turn_base
        per = 0.0 + tb[:, 0] * counts + tb[:, 1] * counts
        per[~whole] = 0.0
        per[: self._rebased] = 0.0  # before the pose was set from outside: owed nothing
        # what each reading moved the body (k, i, a, o), into world axes (k, i, a, b)
        moved = counts[:, :, :, None] * self._move_base[None]
        moved[~whole] = 0.0
        moved[: self._rebased] = 0.0
        self._rebased = 0
        cos, sin = np.cos(heading)[:, None, None], np.sin(heading)[:, None, None]
        bx, by = moved[..., 0], moved[..., 1]
        straight_each = np.stack([cos * bx - sin * by, sin * bx + cos * by], axis=3)
        straight = straight_each.sum(axis=0)
        # the turn before each window (so far in the horizon) times its step turned +90
        before = self.turn_unit[None] + np.cumsum(per, axis=0) - per
        perp = np.stack([-steps[:, 1], steps[:, 0]], axis=1)
        walk = np.einsum("kia,kb->iab", before, perp) + straight
        given = np.einsum("kia,kb->iab", before * self.scale[None], perp)
        given += straight * self.scale[:, :, None]
        # over the evidence's own horizon: the estimate is the scale of those windows (a
        # horizon of 20 s, tried, left a later refinement's turn ungiven: 35 mm against 26
        # on the wide rig's worst drive); a settled estimate moves by little, so the
        # heading moves by little at a renewal, within what the scale's spread leaves open
        f = self.forget
        self.walk_unit = (self.walk_unit + walk) * f
        self.walk_given = (self.walk_given + given) * f
        unit = per.sum(axis=0)
        self.turn_unit = (self.turn_unit + unit) * f
        self.turn_given = (self.turn_given + self.scale * unit) * f
        # and this block's own part: its turn, its walk with the turn before the block left
        # out, and its steps turned summed, kept from the blocks of the last
        # CHANGE_SEGMENTS segments on, from which the sums are made again as of a horizon
        # that began at a change of scale (``_drop_before_change``).  A block's part maps
        # (turn, walk) before it to after it, affinely: the parts of blocks with the same
        # first segment (kept or dropped together: a stop, a mouse out for long) are
        # composed into one, so that the list holds at most CHANGE_SEGMENTS + 1.
        local = np.einsum("kia,kb->iab", np.cumsum(per, axis=0) - per, perp) + straight
        first = self._serial - len(counts)
        block = BlockGave(per.sum(axis=0), local, perp.sum(axis=0), first, per, perp,
                          straight_each)  # fmt: skip
        self._prev_block, self._block = self._block, block  # (_give_back_faults)
        # take-backs of windows older than the two blocks kept concern no give-back
        oldest = first if self._prev_block is None else self._prev_block.first
        self._taken = [mark for mark in self._taken if mark[2] > oldest]
        since = self._segment_count - CHANGE_SEGMENTS
        kept = [part for part in self._recent_gave if part[0] >= since]
        part = (self._segment_count, f, unit * f, local * f, perp.sum(axis=0) * f)
        if kept and kept[-1][0] == part[0]:
            _, a1, u1, l1, q1 = kept.pop()
            _, a2, u2, l2, q2 = part
            part = (
                part[0],
                a1 * a2,
                a2 * u1 + u2,
                a2 * l1 + l2 + u1[:, :, None] * q2,
                a2 * q1 + a1 * q2,
            )
        kept.append(part)
        self._recent_gave = kept

    def take_turn(self) -> float:
        """The turn the heading is owed now that the scales were renewed, once.

        A scale learnt after seconds of motion leaves the heading those seconds lost for
        good: on a square of mice a CPI 3 % off turns the heading by about a degree a
        second while the evidence builds.  So at every renewal the heading is given the
        difference between the turn the mice's readings would have made at the scales now
        applied and the turn they made at the scales applied then, over the evidence's
        horizon (the windows with every mouse in use, forgetting as the evidence does):
        the heading is that of the current scales throughout.  The readings' heading row
        is linear, so this is exact for the heading (the position walked meanwhile keeps
        the heading it had).  An estimate that was wrong and is corrected later takes its
        turn back then.  The tracker takes it whether or not it applies the scales
        (learn_scale), and adds it only where it does."""
        owed, self.turn_owed = self.turn_owed, 0.0
        return owed

    def rebase(self) -> None:
        """The pose was set from outside (Tracker.reset, fix): nothing is owed for the
        turns and the walk before it (those of this block's windows so far included)."""
        for a in (self.turn_unit, self.turn_given, self.walk_unit, self.walk_given):
            a[...] = 0.0
        self.turn_owed, self.walk_owed = 0.0, np.zeros(2)
        self._recent_gave = []
        self._rebased = self._held

    def take_walk(self) -> np.ndarray:
        """The position the pose is owed with ``take_turn`` (the walk meanwhile turned by
        the turns owed along it), once."""
        owed, self.walk_owed = self.walk_owed, np.zeros(2)
        return owed

    def _settle_turn(self) -> None:
        """After a renewal: what the heading is owed for the scales as now applied."""
        self.turn_owed += float(np.sum(self.scale * self.turn_unit - self.turn_given))
        self.turn_given = self.scale * self.turn_unit
        self.walk_owed = (
            self.walk_owed
            + np.einsum("ia,iab->b", self.scale, self.walk_unit)
            - self.walk_given.sum(axis=(0, 1))
        )
        self.walk_given = self.scale[:, :, None] * self.walk_unit

    def _learn_held_out(self, counts: np.ndarray, held_out: np.ndarray, q: np.ndarray) -> None:
        """Each left-out mouse's readings against what the others say it moved, summed
        over groups of GROUP_S in which it was left out throughout: the scale that fits
        them (least squares; its residual says whether the readings are in proportion at
        all, as a wrong CPI's are and a lift's or a seam's are not)."""
        self._held_block = np.zeros((4, self.n))
        if not held_out.any():
            self.held *= self.forget
            return
        starts = np.arange(0, len(counts), self.group)
        pos = self.positions
        body = np.stack(
            [q[:, None, 0] - q[:, None, 2] * pos[None, :, 1],
             q[:, None, 1] + q[:, None, 2] * pos[None, :, 0]], axis=2,
        )  # fmt: skip
        pred = np.einsum("nij,knj->kni", self._base_inv, body)
        self.held *= self.forget
        for i in range(self.n):
            out = np.minimum.reduceat(held_out[:, i].astype(np.int8), starts) > 0
            if not out.any():
                continue
            x = np.add.reduceat(counts[:, i], starts, axis=0)
            y = np.add.reduceat(pred[:, i], starts, axis=0)
            take = out & (np.abs(y).sum(axis=1) >= _MIN_COUNTS)
            x, y = x[take], y[take]
            self._held_block[:, i] = (np.sum(x * x), np.sum(x * y), np.sum(y * y), len(x))
        self.held += self._held_block

    def _learn(self, counts: np.ndarray, usable: np.ndarray) -> bool:
        released = self._released()
        if released:
            self._start_over(released)
        # Groups of consecutive windows (GROUP_S) in which every mouse tracked: their
        # counts summed (a count read a few ms late moves between neighbouring windows,
        # not out of their sum, so the readings' timing noise mostly cancels).
        starts = np.arange(0, len(counts), self.group)
        whole = np.minimum.reduceat(usable.all(axis=1).astype(np.int8), starts) > 0
        c = np.add.reduceat(counts, starts, axis=0)
        # and in which every mouse moved well beyond its counts' rounding: slow groups
        # would bias the fit towards the mice with less noise
        moved = np.all(np.abs(c).sum(axis=2) >= _MIN_COUNTS, axis=1)
        c = c[whole & moved]
        # J g: every mouse's body displacement as configured (M_i c_i, mouse i's two rows
        # of column i) times its scale g_i.  The part no rigid motion of the rig explains
        # is P J g; its weighted square summed over the groups is g' S g.
        body = np.einsum("nij,gnj->gni", self.base, c)
        pj, block = projected(body, self.project, self.weight)
        found = self._faults(block, len(c), body, pj)
        flagged, block_scale = found.faulty, found.scale
        self.faults = self._blamed(flagged)
        self._give_back_faults(block_scale)
        learnt = not found.beyond and len(c) > 0
        self._learnt_last = learnt
        self.gram *= self.forget
        self.groups *= self.forget
        segments = [segment * self.forget for segment in self._segments]
        groups = [k * self.forget for k in self._segment_groups]
        # A block that puts a mouse beyond is not learnt as a CPI, whether it finds a
        # fault (blamed or not) or cannot tell whose it is (``_carries``)
        if learnt:
            self.gram += block
            self.groups += len(c)
            segments.append(block)
            groups.append(float(len(c)))
            self._segment_count += 1
            if len(segments) > _SEGMENTS:
                segments[:2] = [segments[0] + segments[1]]
                groups[:2] = [groups[0] + groups[1]]
        self._segments, self._segment_groups = segments, groups
        self._learn_axes(c, learnt)
        keep = self._changed()
        if keep:
            self._drop_before_change(keep)
        return self._solve()

    def _released(self) -> list[int]:
        """The mice held out beyond the bounds (``beyond``) whose readings in this block,
        against what the others say they moved (``_learn_held_out``), need a scale within
        the bounds again: back on a floor they read as configured.  (Nothing is learnt
        while a mouse is out, so the evidence that put it beyond would hold it out for
        good.)  One block is enough: a mouse let back too soon is found beyond again from
        the evidence since, and the windows it was used in are given back at its scale."""
        lo, hi = self.bounds
        out = []
        for i in self.beyond:
            xx, xy, _, groups = self._held_block[:, i]
            if groups >= _FAULT_GROUPS and xx > 0 and lo <= xy / xx <= hi:
                out.append(i)
        return out

    def _start_over(self, released: list[int]) -> None:
        """The evidence is dropped, and what the pose is owed for the windows before: a
        mouse ``released`` from beyond the bounds reads otherwise than it says, and the
        others' scales are learnt again with it.  The scales applied stay, but for the
        released mice's (1 until learnt again)."""
        self.gram = np.zeros((self.n, self.n))
        self.axis_gram = np.zeros((2 * self.n, 2 * self.n))
        self.groups = 0.0
        self._segments, self._segment_groups, self.axis_segments = [], [], []
        self._recent_gave = []
        for a in (self.turn_unit, self.turn_given, self.walk_unit, self.walk_given):
            a[...] = 0.0
        self.scale[released] = 1.0
        self.split[released] = False
        self.held[:, released] = 0.0  # (what it read on the other floor: not its scale now)
        self.beyond = []
        self.version += 1

    def _beyond_bounds(self) -> list[int]:
        """The mice whose scale over the evidence is plainly beyond the bounds (by
        FAULT_SIGMAS of its spread and _BEYOND_MIN): no CPI within them fits its
        readings, and one clipped to the bound leaves the rest in every window."""
        lo, hi = self.bounds
        g, spread = self.one, self.one_spread
        beyond = np.maximum(lo - g, g - hi)
        with np.errstate(invalid="ignore"):
            plain = (beyond > _BEYOND_MIN) & (beyond > FAULT_SIGMAS * spread)
        return np.flatnonzero(plain).tolist()

    def _changed(self) -> int:
        """How many of the recent segments are after a change of a mouse's scale within the
        evidence (0: none, else the split ``change_point`` finds): the scales fitted to the
        recent segments and to the older ones differ plainly (beyond CHANGE_SIGMAS of
        their combined spread, each the larger of the residual's and the jackknife's as in
        ``_solve``, and by CHANGE_MIN).  The evidence sums everything since the start
        (forgetting by half in two minutes), so after a change its fit is some mean of the
        two scales, and the turn given back at a renewal (``take_turn``) applies it to the
        whole horizon, windows before the change included: three mice, one reading 8.6 %
        less from 23 s on, ended a 31 s drive 2.0 m and 31 degrees off (0.04 m with no
        learning), all of it in one window.  "Recent" is the last CHANGE_SEGMENTS
        segments and the split ``change_point`` finds: a change a few segments back mixes
        both scales into the last ten, whose jackknife spread it then widens, and the fit
        of the mixed evidence renewed meanwhile (three mice, one reading 14 % less: 60
        degrees given back over the whole horizon, a second before the fixed split saw
        the change).  The scales compared are one per mouse of the evidence with each
        count axis's counts first corrected by its scale over the older segments
        (``_change_evidence``): a mouse off on one axis reads, in one scale, as a mean of
        its two weighted by the directions driven, so its one scale moved wherever the
        drive's mix of directions did, and was taken for a change (a triangle, one mouse
        3 % off on x: 8 of 15 drives, the evidence before cut from 32 s to 7).  The scan
        is made only where the last ten segments' scales alone differ from the older
        ones' by CHANGE_MIN (a healthy rig pays nothing more than before)."""
        if len(self._segments) - CHANGE_SEGMENTS < _CHANGE_OLDER:
            return 0
        segments = self._change_evidence()
        if not scales_differ(segments, CHANGE_SEGMENTS):
            return 0
        best = change_point(segments)
        for recent in dict.fromkeys((best, CHANGE_SEGMENTS)):
            found = self._change_at(segments, recent)
            if found:
                self.changed = found
                return best
        return 0

    def _change_evidence(self) -> np.ndarray:
        """The segments ``_changed`` compares (K, N, N): the per-axis segments with each
        count axis's counts corrected by its scale over the segments older than the last
        CHANGE_SEGMENTS (``axis_scales``), summed per mouse into one column as S's are.
        A CPI off on one axis is a fixed ratio of the mouse's two axes: corrected, the
        one scale of every stretch of the drive is the same whatever its directions, and
        a change of scale (both axes alike: another floor, a dirty lens) shows as it
        did."""
        n, cols = self.n, len(self.cols)
        whole = axis_scales(self.axis_gram, self.groups, n, cols)
        older = np.sum(self.axis_segments[:-CHANGE_SEGMENTS], axis=0)
        groups = sum(self._segment_groups[:-CHANGE_SEGMENTS])
        g = axis_scales(older, groups, n, cols, prior=whole)
        # (2N, N): mouse i's axes into its one column, each times its scale
        m = g[:, None] * np.repeat(np.eye(self.n), 2, axis=0)
        return m.T @ np.stack(self.axis_segments) @ m

    def _change_at(self, segments: np.ndarray, recent: int) -> list[tuple[int, float]]:
        """``_changed``'s test of the last ``recent`` of the ``segments`` against the older
        ones: the mice that changed plainly, each with its scale after over before (none:
        [])."""
        older = len(segments) - recent
        n, cols = self.n, len(self.cols)
        parts = (segments[-recent:], segments[:older])
        counts = (sum(self._segment_groups[-recent:]), sum(self._segment_groups[:older]))
        if min(counts) < MIN_GROUPS:
            return []
        if not scales_differ(segments, recent):
            return []
        sums = [np.sum(part, axis=0) for part in parts]
        new, old = (fit(s, k, n, cols) for s, k in zip(sums, counts, strict=True))
        if new is None or old is None:
            return []
        diff = np.abs(new[0] - old[0])
        # First with the residual's spreads alone, a lower bound of the jackknifed ones:
        # where no change is plain with them, none is (and no jackknife is solved).
        with np.errstate(invalid="ignore"):
            if not plain_change(diff, np.hypot(new[1], old[1])).any():
                return []
            widths = [widened(new[1], sums[0], list(parts[0])),
                      widened(old[1], sums[1], list(parts[1]))]  # fmt: skip
            plain = plain_change(diff, np.hypot(*widths))
        return [(int(i), float(new[0][i] / old[0][i])) for i in np.flatnonzero(plain)]

    def _drop_before_change(self, keep: int) -> None:
        """After a change of scale (``_changed``) in the last ``keep`` segments: the
        evidence is those segments alone, and the turns and walk owed for are those of the
        blocks since (the scales learnt from now on are those of after the change)."""
        self._segments = self._segments[-keep:]
        self._segment_groups = self._segment_groups[-keep:]
        self.axis_segments = self.axis_segments[-keep:]
        self.gram = np.sum(self._segments, axis=0)
        self.groups = float(sum(self._segment_groups))
        self.axis_gram = np.sum(self.axis_segments, axis=0)
        # Their turns and walks summed as _gave sums them, the turn before each walk from
        # the first of those blocks on, and given at the scales applied now (as the
        # renewals' turns given back made them).  The windows before the change are owed
        # nothing more: they keep the scales the pose was given for them.  (Blocks
        # without evidence just before the first kept segment are among those blocks:
        # the robot stood, or a mouse was out; what they turned is theirs either way.)
        since = self._segment_count - keep
        self._recent_gave = [part for part in self._recent_gave if part[0] >= since]
        turn, walk = np.zeros((self.n, 2)), np.zeros((self.n, 2, 2))
        for _, a, unit, local, perp in self._recent_gave:
            walk = a * walk + local + turn[:, :, None] * perp
            turn = a * turn + unit
        self.turn_unit, self.walk_unit = turn, walk
        self.turn_given = self.scale * turn
        self.walk_given = self.scale[:, :, None] * walk
        self.changes += 1

    def _learn_axes(self, c: np.ndarray, learnt: bool) -> None:
        """The block's evidence per count axis (``fit_axes``), where ``_learn`` learnt
        from its groups' counts ``c`` (groups, N, 2): J's column per mouse and count axis,
        mouse i's axis a moving it base[i, :, a] * c[i, a] in body axes."""
        n = self.n
        self.axis_gram *= self.forget
        segments = [segment * self.forget for segment in self.axis_segments]
        if learnt:
            j = np.zeros((len(c), 2 * n, 2 * n))
            for i in range(n):
                for a in range(2):
                    j[:, 2 * i : 2 * i + 2, 2 * i + a] = self.base[i][None, :, a] * c[:, i, a, None]
            pj = np.einsum("rs,gst->grt", self.project, j)
            block = np.einsum("grt,r,grs->ts", pj, self.weight, pj)
            self.axis_gram += block
            segments.append(block)
            if len(segments) > _SEGMENTS:
                segments[:2] = [segments[0] + segments[1]]
        self.axis_segments = segments

    def _solve(self) -> bool:
        """The scales from the accumulated S (module docstring): the ones that leave the
        least unexplained motion, drawn to 1 only where the evidence is silent, the common
        mode pinned by the median mouse."""
        if self.groups < MIN_GROUPS:
            return False
        fitted = fit(self.gram, self.groups, self.n, len(self.cols))
        if fitted is None:
            return False
        g, spread = fitted
        # the spread: the larger of the residual's and the jackknife's over the blocks
        spread = widened(spread, self.gram, self._segments)
        self.one, self.one_spread = g, spread
        self.estimate = np.repeat(g[:, None], 2, axis=1)
        self.spread = np.repeat(spread[:, None], 2, axis=1)
        self._split_axes()
        # applied where plain: a scale within 3 of its standard deviations of 1 is noise,
        # and noise applied to a mouse that reads the turn is heading lost for good
        off = np.abs(self.estimate - 1.0)
        plain = (off > PLAIN * self.spread) & (off > _MIN_APPLIED)
        plain |= (self.scale != 1.0) & (off > _KEEP_PLAIN * self.spread) & (off > _KEEP_APPLIED)
        plain &= self.groups >= MIN_GROUPS
        # A mouse plainly beyond the bounds is held out by the screen (``beyond``); its
        # scale, unclipped, gives back what it moved the pose since its evidence began
        # (a change of scale drops what came before: ``_drop_before_change``).
        self.beyond = self._blamed(self._beyond_bounds())
        lo, hi = np.full(self.n, self.bounds[0]), np.full(self.n, self.bounds[1])
        lo[self.beyond], hi[self.beyond] = -np.inf, np.inf
        self.scale = np.where(plain, np.clip(self.estimate, lo[:, None], hi[:, None]), 1.0)
        self.version += 1
        return True

    def _split_axes(self) -> None:
        """A mouse whose two count axes' scales differ plainly (beyond PLAIN of the
        difference's spread and _MIN_APPLIED; kept while beyond _KEEP_PLAIN and
        _KEEP_APPLIED) is given a scale per axis, the others one each from the same fit
        (``fit_axes`` with ``split``).  One scale per mouse cannot fit a CPI off on one
        axis: it reads as some mean of the two, of either sign, and its misfit bends the
        healthy mice's scales (three mice, one 4 % off on its x axis: one scale gave it
        2.5 % the wrong way, 3.7 m off at the end of a 36 s drive against 1.8 m with no
        scale; per axis 0.18 m).  Where the drive does not tell a mouse's axes apart
        (its difference's spread infinite: mice whose axes all lie along the body's,
        with no sideways motion), the one scale stands."""
        n, cols = self.n, len(self.cols)
        evidence: AxisEvidence = (self.axis_gram, self.axis_segments, self.groups, n, cols)
        before = self.split
        split = self._plain_split(evidence, None, before)
        if split is None:
            self.split = np.zeros(n, dtype=bool)
            return
        if not split.any():
            split = self._one_split(evidence, before)
        self.split = split
        if not split.any():
            return
        with np.errstate(invalid="ignore"):
            mixed = fit_axes(*evidence, split=self.split)
        if mixed is not None:
            self.estimate, self.spread = mixed[0], mixed[1]

    def _plain_split(
        self, evidence: AxisEvidence, split: np.ndarray | None, before: np.ndarray
    ) -> np.ndarray | None:
        """The mice whose axes' scales differ plainly in ``fit_axes`` with ``split`` (None:
        every mouse given a scale per axis); those ``before`` split kept while beyond
        _KEEP_PLAIN.  None where the evidence gives no fit."""
        # First with the residual's spreads alone, a lower bound: where no difference can
        # be plain with them, none is with the jackknife's either, whose solve per
        # segment (a fifth of replay's time on a healthy rig) is then not made.
        for jackknifed in (False, True):
            with np.errstate(invalid="ignore"):  # exact readings: a residual of -0
                fitted = fit_axes(*evidence, split=split, jackknifed=jackknifed)
            if fitted is None:
                return None
            off, sd = np.abs(fitted[2]), fitted[3]
            with np.errstate(invalid="ignore"):  # (NaN: a mouse with one scale)
                kept = before & (off > _KEEP_PLAIN * sd) & (off > _KEEP_APPLIED)
                plain = kept | ((off > PLAIN * sd) & (off > _MIN_APPLIED))
            if not plain.any():
                break
        return plain

    def _one_split(self, evidence: AxisEvidence, before: np.ndarray) -> np.ndarray:
        """Where a scale per axis for every mouse is more than the evidence tells apart
        (a drive that never slides leaves every sideways axis against every forward one
        free), a scale per axis for one mouse alone, the others one each, often is not.
        Three mice of an offset ring, one reading 4.2 % short on its y axis only: with
        every mouse split nothing was plain, and its one scale (1.027, bending a healthy
        one to 0.976) turned the heading 33 degrees in 13 s and ended the drive 0.30 m
        off against 27 mm with no scale; split alone its axes said 1.000 and 1.043 +-
        0.001.  The mouse split is the one whose split explains the most of what one
        scale each leaves unexplained, and only where it explains _ONE_SPLIT_MARGIN times
        as much as any other mouse's would and its axes then differ plainly.  Other
        mice's splits fit the misfit of the one that is off in part, some more plainly in
        standard deviations than the right one (wide rig: a wrong mouse at 6.4 of them,
        the right one's difference not separable), and two mice whose axes read alike (a
        close pair's, mice in a line along x) fit one mouse's error about as well split
        either way (a close pair: the healthy one split ended 595 mm off against 312
        with one scale each): then none is split."""
        n, s = self.n, evidence[0]
        split = np.zeros(n, dtype=bool)
        left = unexplained(s, split)
        explained = np.zeros(n)  # what splitting each mouse alone explains of it
        for i in range(n):
            split[i] = True
            explained[i] = left - unexplained(s, split)
            split[i] = False
        explained = np.where(np.isfinite(explained), explained, 0.0)
        order = np.argsort(explained)[::-1]
        best = int(order[0])
        # (a mouse split at the last renewal stays split while its split explains the
        # most, as ``_plain_split`` keeps a difference while beyond _KEEP_PLAIN: a split
        # coming and going would move the heading at each renewal)
        margin = 1.0 if before[best] else _ONE_SPLIT_MARGIN
        if not explained[best] > 0 or explained[best] < margin * explained[order[1]]:
            return split
        # What one parameter more explains is its difference squared over its variance,
        # so a difference plain beyond PLAIN of its residual's spread explains PLAIN
        # squared times the residual per degree of freedom left: where it explains not
        # half of that, ``_plain_split``'s fits (a tenth of a healthy rig's learning
        # each) cannot find it plain.
        groups, cols = evidence[2], evidence[4]
        dof = max(1.0, groups * (2 * n - cols) - n)
        if explained[best] < 0.5 * PLAIN**2 * (left - explained[best]) / dof:
            return split
        split[best] = True
        plain = self._plain_split(evidence, split, before & split)
        return split if plain is not None and plain[best] else np.zeros(n, dtype=bool)

    def _faults(
        self, block: np.ndarray, groups: int, body: np.ndarray, pj: np.ndarray
    ) -> BlockFaults:
        """The mice whose scale in this block alone (its S, ``groups`` of them) is beyond
        what any CPI within the bounds gives, by FAULT_MARGIN of it and FAULT_SIGMAS of
        the block's spread: a mouse that reads half its motion (a dirty lens, a sensor
        losing the floor) is no wrong CPI.  Each window's test lets such a fault by where
        the tolerances are wide (late stamps, a far mouse, a close pair: a 125 Hz mouse
        of a close pair, reading half in a spin, ended a drive 0.37 m off against 4 mm
        told), and the screen's noise model then learns it as noise; summed over a
        block's groups, the timing noise cancels and it is plain.  ``body``: the block's
        groups' readings (G, N, 2) as configured, for ``_carries``; ``pj``: their part no
        rig motion explains per unit scale (G, 2N, N), for ``_one_group``."""
        none = BlockFaults([], None, False)
        if groups < _FAULT_GROUPS:
            return none
        fitted = fit(block, groups, self.n, len(self.cols))
        if fitted is None:
            return none
        g, spread = fitted
        lo, hi = self.bounds
        beyond = np.maximum(lo * (1.0 - FAULT_MARGIN) - g, g - hi * (1.0 + FAULT_MARGIN))
        flagged = np.flatnonzero((beyond > 0) & (beyond > FAULT_SIGMAS * spread)).tolist()
        if not flagged:
            return none
        known = self._known_per_dof()
        explained = self._in_proportion(block, groups, g, known)
        if not explained and known is not None:
            # A block its own scales do not explain: the scales are bent by what they
            # cannot explain, so they may single out a healthy mouse.  Where leaving one
            # mouse out explains the rest, that mouse carries it, and only it may stay
            # flagged; where leaving out either of two does (a close pair's jump across
            # the pair reads to the pair alone as a turn), the block cannot tell whose it
            # is and blames nobody.  Where none does, the scales' word stands.
            carriers = [i for i in range(self.n) if self._carries(i, body, groups, known)]
            if carriers:
                flagged = [i for i in flagged if carriers == [i]]
        scaled = explained and not self._one_group(block, groups, pj) & set(flagged)
        return BlockFaults(flagged, g if flagged and scaled else None, True)

    def _one_group(self, block: np.ndarray, groups: int, pj: np.ndarray) -> set[int]:
        """The mice whose scale is within the bounds (and FAULT_MARGIN) in the block less
        some one of its groups: what puts them beyond is a moment (a jump), not a scale.
        In a pivot the scales are weakly told apart (the turn and a scale of the far mouse
        trade off), and a far mouse's one sideways jump of 8 mm pulled its block scale to
        0.08 (five groups; the others alone said 1): it was excluded for the rest of the
        drive and the block given back at that scale, 15 degrees of turn in one window
        (349 mm off at the end against 42 with fault handling off).  A mouse reading short
        for the block, or silent and catching up, is beyond without any one group too."""
        lo, hi = self.bounds
        out: set[int] = set()
        n, cols = self.n, len(self.cols)
        for k in range(groups):
            part = np.einsum("rt,r,rs->ts", pj[k], self.weight, pj[k])
            fitted = fit(block - part, groups - 1, n, cols)
            if fitted is None:
                continue
            g = fitted[0]
            within = (g >= lo * (1.0 - FAULT_MARGIN)) & (g <= hi * (1.0 + FAULT_MARGIN))
            out.update(np.flatnonzero(within).tolist())
        return out

    def _known_per_dof(self) -> float | None:
        """The evidence's residual per degree of freedom at its scales (None: too little
        evidence to compare with, fewer than MIN_GROUPS groups)."""
        if self.groups < MIN_GROUPS:
            return None
        return residual_per_dof(self.gram, self.one, self.groups, len(self.cols))

    def _in_proportion(
        self, block: np.ndarray, groups: int, g: np.ndarray, known: float | None
    ) -> bool:
        """Whether the block's own scales explain its readings about as well as the
        evidence's explain the evidence (the residual per degree of freedom at most
        _PROPORTION times): a mouse reading at another scale (a dirty lens, another
        floor) is; one reading nothing, then everything at once (a USB stall's silence and
        catch-up), or at random (a lift) is not, whatever scale fits it best.  ``known``:
        ``_known_per_dof``'s."""
        if known is None:
            return False  # (nothing to compare with)
        return residual_per_dof(block, g, groups, len(self.cols)) <= _PROPORTION * known

    def _carries(self, i: int, body: np.ndarray, groups: int, known: float) -> bool:
        """Whether mouse i carries what a block's scales leave unexplained: the other
        mice's readings alone, at their own best scales, are explained in proportion
        (``_in_proportion``'s bound; False where the others alone check nothing).  A USB
        stall's silence and catch-up is the stalled mouse's own: without it the block is
        plain, and without any other mouse it is not.  Jumps of a close pair's mouse
        across the pair, under USB gaps, are plain without the jumping mouse and
        without the far one alike (the pair alone reads them as turns), and the block's
        bent scales singled out the far one (scale -0.09: 1.43 m off at the end against
        13 mm with fault handling off).  ``known``: ``_known_per_dof``'s."""
        n, cols = self.n - 1, len(self.cols)
        if 2 * n <= cols:
            return False
        others = [k for k in range(self.n) if k != i]
        a = motion_columns(self.positions[others], self.cols)
        weight = self.weight.reshape(self.n, 2)[others].ravel()
        try:
            project = projector(a, weight)
        except np.linalg.LinAlgError:  # the others at one point: no rig motion is fitted
            return False
        block = projected(body[:, others], project, weight)[1]
        fitted = fit(block, groups, n, cols)
        # (others whose readings fix none of their scales, two mice on a line through
        # the centre of a spin, say, explain anything: they tell nothing)
        if fitted is None or not np.isfinite(fitted[1]).any():
            return False
        return residual_per_dof(block, fitted[0], groups, cols) <= _PROPORTION * known

    def _give_back_faults(self, block_scale: np.ndarray | None) -> None:
        """The windows of this block in which a mouse the block found faulty was used
        (with every mouse: ``_gave``'s) are given back at the block's own scale for it,
        once and for good.  Its readings were off since its fault began: the screen's
        test had let them by (late stamps, a far mouse, a spin with a mouse near the
        centre), and a mouse reading 30-45 % less, found a block or two late, had turned
        the heading by up to 25 degrees (drives ended 0.05-0.7 m off against 5 mm without
        it).  The block's scale is the least-squares fit of its readings to what the
        others say they moved, so the block's turn given at it is about the others' turn,
        where the fault began within the block too (each window weighs as its motion).
        Those windows then leave the horizon (turn and walk, unit and given, and the
        recent blocks' parts): a scale learnt later does not give them back again.
        Only where the block's scale explains its readings (``_in_proportion``): a USB
        stall's silence and its catch-up in one block, or a lift's readings, fit some
        scale too, and given back at it a stall's drive ended 0.65 m off against 0.17
        with fault handling off; and where no one group puts the mouse beyond
        (``_one_group``: a jump is no scale).  (The windows the screen excluded the mouse from are
        not among those given back; those it was suspect in, still used, are.)

        The block before is given back as well, at its own scale of the mouse, where it
        was learnt (its own scale still within the fault margin: the fault began in it)
        and that scale is plainly off the one applied (FAULT_SIGMAS of its spread and
        _BEYOND_MIN): on the sweep the fault was found a block after its start in most
        drives, and the block of its start had kept up to 0.36 m.  That scale need not
        explain its block: the fault began inside it, so it read at two scales, and this
        block, which its own scale explains, says a scale is what changed.  (Asked to
        explain it as well, 6 of 80 drives kept up to 0.37 m of it.)"""
        if not self.faults or block_scale is None or not self._recent_gave:
            return  # (none, or the horizon was just started over: ``_start_over``)
        parts = self._recent_gave
        # The block before, where it was learnt (the fault often began there, its own
        # scale of the mouse not yet beyond the fault margin, and was learnt as a CPI):
        # given back too where its own scale is plainly off.
        before = None
        if (self._learnt_last and len(parts) >= 2 and parts[-1][0] == self._segment_count
                and parts[-2][0] == self._segment_count - 1):  # fmt: skip
            before = fit(self._segments[-1], self._segment_groups[-1], self.n, len(self.cols))
        block, prev = self._block, self._prev_block
        if block is None:
            return  # (no block given yet: nothing to give back)
        for i in self.faults:
            self._give_back_block(i, block_scale[i], block, parts[-1], 1, None)
            if before is None or prev is None:
                continue
            g, spread = before[0][i], before[1][i]
            off = abs(g - float(self.scale[i].mean()))
            if off > _BEYOND_MIN and off > FAULT_SIGMAS * spread:
                self._give_back_block(i, g, prev, parts[-2], 2, block.steps)

    def _not_taken(self, i: int, block: BlockGave) -> tuple[np.ndarray, np.ndarray]:
        """Mouse i's turn and walk per unit scale in a block (its ``unit`` and ``local``)
        over the windows the screen did not take back for it (``_take_back``: it solved
        them again without the mouse, from its fault's onset on; given back again here,
        that turn counted twice, and a drive ended 59 mm off against 7)."""
        unit, local = block.unit[i], block.local[i]
        k = len(block.per)
        keep = np.ones(k)
        for mouse, lo, hi in self._taken:
            a, b = max(lo - block.first, 0), min(hi - block.first, k)
            if mouse == i and a < b:
                keep[a:b] = 0.0
        if keep.all():
            return unit, local
        # _gave's sums for this mouse, the windows taken back left out
        per = block.per[:, i] * keep[:, None]
        before = np.cumsum(per, axis=0) - per
        local = before.T @ block.perp + np.einsum("k,kab->ab", keep, block.straight[:, i])
        return per.sum(axis=0), local

    def _give_back_block(
        self, i: int, scale: float, block: BlockGave, part: tuple, age: int,
        steps_after: np.ndarray | None,
    ) -> None:  # fmt: skip
        """Mouse i's windows of one block given back at ``scale`` (but those the screen
        took back, ``_not_taken``), and all of them taken out of the horizon.  ``part``:
        the recent blocks' part it is the last of; ``age``: blocks since it, itself
        included, whose forgetting its sums have had; ``steps_after``: the steps turned
        summed of the block after it (its heading owed turns those too), or None."""
        unit, local = block.unit[i], block.local[i]
        delta = scale - self.scale[i]  # per count axis
        o_unit, o_local = self._not_taken(i, block)
        walk = o_local if steps_after is None else o_local + o_unit[:, None] * steps_after[None]
        self.turn_owed += float(delta @ o_unit)
        self.walk_owed = self.walk_owed + delta @ walk
        f, fa = self.forget, self.forget**age
        # in the horizon, forgotten ``age`` times: its own sums, and its turn times the
        # steps of the block after (the turn before each window there, ``_gave``)
        in_walk = local * fa
        if steps_after is not None:
            in_walk = in_walk + unit[:, None] * steps_after[None] * fa
        self.turn_unit[i] -= unit * fa
        self.turn_given[i] -= self.scale[i] * unit * fa
        self.walk_unit[i] -= in_walk
        self.walk_given[i] -= self.scale[i][:, None] * in_walk
        part[2][i] -= unit * f  # (a part holds its own last block forgotten once)
        part[3][i] -= local * f

    def _blamed(self, flagged: list[int]) -> list[int]:
        """Of a block's ``flagged`` mice, those to exclude: all of them where they are
        fewer than half the rig, else none.  The scales are relative to the median mouse:
        with half the mice or more out of proportion the median is one of them, and the
        healthy ones read as the faulty (four mice, two reading half: all four flagged)."""
        return flagged if 2 * len(flagged) < self.n else []

    def _report_held_out(self) -> None:
        """The estimates reported for mice the screen keeps out as far off (a CPI typo):
        from the windows they were left out of.  Not applied: they stay out."""
        for i in range(self.n):
            held = self.held_out_scale(i)
            if held is not None:
                self.estimate[i], self.spread[i] = held
                self.version += 1

    def held_out_scale(self, i: int) -> tuple[float, float] | None:
        """Mouse i's scale from the windows the screen left it out of, with its spread,
        where those readings are in proportion to what the others say (a wrong CPI, not a
        lift or a seam: at most a tenth of them unexplained) and there are more of them
        than of the windows it was used in; else None."""
        xx, xy, yy, groups = self.held[:, i]
        if groups < MIN_GROUPS or xx <= 0 or yy <= 0:
            return None
        g = xy / xx
        unexplained = max(yy - g * xy, 0.0)
        if unexplained > 0.1 * yy or g <= 0:
            return None
        if groups < self.groups_used(i):
            return None
        return float(g), float(np.sqrt(unexplained / max(groups - 1.0, 1.0) / xx))

    def groups_used(self, i: int) -> float:
        """How much joint evidence mouse i has (its diagonal of S against the mean)."""
        d = np.diag(self.gram)
        return float(self.groups * d[i] / d.mean()) if d.mean() > 0 else 0.0

    def reported_axis(self, i: int) -> int:
        """The count axis (0: x, 1: y) whose scale stands for mouse i where one number is
        reported (its warning, SOURCE): x, as both are one, but for a mouse given a scale
        per axis (``split``) the one whose counts need the larger change."""
        if not self.split[i]:
            return 0
        gx, gy = (float(v) for v in self.estimate[i])
        return int(abs(1.0 / gy - 1.0) > abs(1.0 / gx - 1.0))

    def change_lines(self, names: Sequence[str]) -> list[str]:
        """A line per mouse of the last change of scale (``changed``): "mouse right reads
        7.4 % less than it did" (the daemon's log and `calibrate scales` say it)."""
        return [f"mouse {names[i]} reads {reads(r, 1)} than it did" for i, r in self.changed]

    def warnings(self, names: tuple[str, ...] | list[str]) -> list[str]:
        """A line per mouse whose scale is WARN or more from 1, beyond three of its
        standard deviations: a CPI typo, or the wrong mouse's CPI (and where beyond the
        bounds, that the screen holds it out: ``beyond``)."""
        out = []
        for i, name in enumerate(names):
            held = self.held_out_scale(i)
            a = self.reported_axis(i)
            g, s = float(self.estimate[i, a]), float(self.spread[i, a])
            if held is not None:
                g, s = held
            if abs(1.0 / g - 1.0) >= WARN and abs(g - 1.0) > 3.0 * s:
                where = f" on its {'xy'[a]} axis" if held is None and self.split[i] else ""
                held_out = "; beyond scale_limit: held out" if i in self.beyond else ""
                out.append(
                    f"mouse {name} reads {reads(g)} than the others{where}: check its cpi "
                    f"(learnt scale {g:.3f} +- {s:.3f}){held_out}"
                )
        return out
