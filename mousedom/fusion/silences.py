"""Each used mouse's silence and its catch-up: the state ``robust.Screen`` keeps to tell a
stalled USB mouse's catch-up report from a jump (``Screen._runs``, ``_catching_up``).

A USB host that does not poll a mouse for longer than ``late_report_s`` delivers its counts
summed in one report, which covers one report period (``countfunction``): the silence was
used as a mouse reading nothing (nothing tells it from a mouse at rest), and the catch-up
reads as a jump, the others short of it.  So a mouse silent while the others moved it
opens an account here: its residual under the others summed over the silent windows and
the windows since it read again (up to CATCH_UP_WINDOWS, the catch-up report's), with the
sum's expected error.  The screen, which solves, feeds it; this class only keeps the sums.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

# A report after a silence longer than late_report_s covers one report period, so its
# counts land in the window of its stamp and, where that period straddles an edge, the
# next; the silence's account stays open for this many windows after the mouse reads again.
CATCH_UP_WINDOWS = 2


# A mouse reads nothing in a window where its squared reading is at most this share of
# its sigma^2 (the split of reports across windows leaves rounding dust where there were
# none): Screen._silent, the common case's and replay's rules, and these rows.
SILENT_SHARE = 1e-6


class Silences:
    """The open silences of a rig of ``n`` mice (module docstring)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.sum = np.zeros((n, 2))  # residual under the others, summed
        self.s2 = np.zeros(n)  # its expected error, summed
        self.silent = [0] * n  # windows silent (0: no silence open)
        self.after = [0] * n  # windows since it read again
        self.owed = [False] * n  # the silence owed beyond its error
        self.any = False  # any open

    def close(self, i: int) -> None:
        """Mouse i's silence is over, or no longer its own to settle."""
        self.sum[i] = 0.0
        self.s2[i] = 0.0
        self.silent[i] = self.after[i] = 0
        self.owed[i] = False

    def step(self, i: int, r: np.ndarray, silent: bool, s2: float, thr2: float) -> None:
        """One more window of mouse i's silence (opening one where ``silent``): residual r
        under the others (or in use, where the window needed no decision), expected error
        s2; ``thr2``: the test's threshold (two degrees of freedom)."""
        if silent and self.after[i]:
            self.close(i)  # silent again after it read: its catch-up is over
            return
        self.sum[i] += r
        self.s2[i] += s2
        if silent:
            self.silent[i] += 1
            owed = self.sum[i]
            self.owed[i] = float(owed @ owed) > thr2 * self.s2[i]
            return
        self.after[i] += 1
        if self.after[i] > CATCH_UP_WINDOWS:
            self.close(i)

    def catching(self, i: int) -> bool:
        """Whether mouse i's reading in this window may be its silence's catch-up: the
        silence owed beyond its error, and its catch-up's windows are not over."""
        return self.owed[i] and self.after[i] < CATCH_UP_WINDOWS

    def settle(self) -> None:
        """After a window's steps: whether any silence is open."""
        self.any = any(self.silent)

    def rows(
        self,
        p: Sequence[Any] | np.ndarray,
        d: Sequence[Any] | np.ndarray,
        used: Sequence[bool],
        sig2: Sequence[float],
        thr2: float,
    ) -> None:
        """Windows accepted without a decision (predictions p and readings d, rows of
        (N, 2) or of N * 2 floats, solved with the mice ``used``; ``sig2`` each mouse's
        floor): none of them held a mouse short of what the others moved it beyond its
        sigma (those are decided), so their residual in use is a standstill's noise or the
        rest of a catch-up already judged; what they add is that, at the floor's error."""
        p_rows = np.asarray(p, dtype=float).reshape(len(p), self.n, 2)
        d_rows = np.asarray(d, dtype=float).reshape(len(d), self.n, 2)
        for i in range(self.n):
            if not self.silent[i]:
                continue
            if not used[i]:
                self.close(i)
                continue
            r = d_rows[:, i] - p_rows[:, i]
            silent = np.einsum("ij,ij->i", d_rows[:, i], d_rows[:, i]) <= SILENT_SHARE * sig2[i]
            # a standstill's silent rows at once (a parked rig: thousands), then row by row
            # from the first it reads in, until its catch-up's windows are over
            k = len(r) if self.after[i] == 0 and silent.all() else 0
            if self.after[i] == 0 and not silent.all():
                k = int(np.argmin(silent))
            if k:
                self.step(i, r[:k].sum(axis=0), True, k * sig2[i], thr2)
                self.silent[i] += k - 1
            for j in range(k, len(r)):
                if not self.silent[i]:
                    break
                self.step(i, r[j], bool(silent[j]), sig2[i], thr2)
        self.settle()
