"""What the mice held out of the solve owe the pose (issue 31: every count counted once, and a
fault counted from its start only).

A mouse held out of a window is not forgotten: its reading less what the others said it
moved (its residual under them, r) is written to its account, window by window, until it is
used again.  At re-admission the account is settled with the pose by a correction to the
window's twist: adding a mouse to a least squares adds B_i r_i to its solution (B_i the
mouse's columns of the estimator with it in use), so summed over the exclusion the pose
gets B_i times the sum (``settle``, by solving the sum as if it were a reading).

- **Whole**: a late mouse's sum is its lateness at the end less that at the start, no
  larger than one window's error: chi-square with 2 degrees of freedom at the false-alarm
  rate, against twice the expected error of a window in the exclusion (the mean over
  them): the mouse's own, or that of the others' prediction of it where larger, from
  which every residual is taken (``paid``; far across the line through two close mice,
  many times its own).  A lifted,
  under-reading or jumping mouse owes the motion it missed or invented: far beyond.
- **Runs**: then only the runs of windows it agreed in while it waited are given back
  (after a lift, between and after a seam's jumps), where their sum is within its expected
  error.  A run starts at a window that moved the mouse enough to show a fault (a lifted
  mouse's silence passes where changes of motion widen every tolerance) and counts where
  it held a fifth of the re-admission's windows of such (``end_run``).
- **Taken back**: the windows just before a mouse was held out, in which its fault began
  within the test, are taken from the pose when it is held out (``Screen._take_back``);
  their residuals join the account (``take``), so a late mouse that pays back gets them
  again.

Exact for the heading; for the position up to the turn within the exclusion.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Solve = Callable[[np.ndarray, np.ndarray], "np.ndarray | None"]  # (d (N, 2), used) -> q


class Ledger:
    """The accounts of a rig's N mice (see the module); ``thr2`` the 2-degree-of-freedom
    test's threshold, ``evidence`` the windows a run needs to count."""

    def __init__(self, n: int, thr2: float, evidence: int) -> None:
        self.n = n
        self.thr2 = thr2
        self.evidence = evidence
        self.owed = np.zeros((n, 2))  # the sum of residuals over the exclusion
        self.owed_s2 = np.zeros(n)  # the largest expected error of a window in it
        # the expected error of the windows held out and the covariance (2, 2) of the
        # others' prediction of it in each (RigidTest.prediction_cov; a solve without rank
        # adds nothing), summed, and the windows summed: ``paid`` holds the debt to their
        # means
        self.sum_s2 = np.zeros(n)
        self.sum_pc = np.zeros((n, 2, 2))
        self.windows = np.zeros(n, dtype=int)
        self.windows_pc = np.zeros(n, dtype=int)
        # the residuals under the others of the silence it was used through just before
        # it was held out (``before``), and their expected error summed: counted in the
        # pose already, they do not join what is given back, but its catch-up pays them
        self.pre = np.zeros((n, 2))
        self.pre_s2 = np.zeros(n)
        self._run = np.zeros((n, 2))  # the run of agreeing windows going on
        self._run_s2 = np.zeros(n)
        self._banked = np.zeros((n, 2))  # the runs that counted
        self._banked_s2 = np.zeros(n)
        self.readmitted: list[int] = []  # mice back in use in this window

    def hold(self, i: int, r: np.ndarray, s2: float, pc: np.ndarray | None = None) -> None:
        """Mouse i held out afresh with residual r (expected error s2; pc: the covariance
        of the prediction r is taken from): a new account."""
        self.owed[i] = r
        self.owed_s2[i] = s2
        self.sum_s2[i], self.windows[i] = s2, 1
        self.sum_pc[i], self.windows_pc[i] = 0.0, 0
        self.pre[i] = 0.0
        self.pre_s2[i] = 0.0
        self._predicted(i, pc)
        self._run[i] = self._banked[i] = 0.0
        self._run_s2[i] = self._banked_s2[i] = 0.0

    def carry(self, i: int, r: np.ndarray, s2: float, pc: np.ndarray | None = None) -> None:
        """One more window held out."""
        self.owed[i] += r
        self.owed_s2[i] = max(self.owed_s2[i], s2)
        self.sum_s2[i] += s2
        self.windows[i] += 1
        self._predicted(i, pc)

    def before(self, i: int, r: np.ndarray, s2: float) -> None:
        """Mouse i, held out in this window, had been used through a silence just before
        (``Screen._runs``): r its residuals under the others summed over it, s2 their
        expected error.  A USB host that stopped polling it delivers the silence's counts
        in one catch-up report, which may arrive while it is out: its debt, the motion of
        the windows held out, is then overpaid by the motion of the silence's windows in
        use, and the whole of its counts, dropped, left the pose where the zeros put it
        (two mice: 0.77 m off at the end, fault handling off 0.11 m).  Whether it paid is
        judged on both; what is given back is the debt's alone (the windows in use are in
        the pose already).  The windows taken back from the pose (``take``) move from
        this part to the debt."""
        self.pre[i] = r
        self.pre_s2[i] = s2

    def _predicted(self, i: int, pc: np.ndarray | None) -> None:
        if pc is not None and np.all(np.isfinite(pc)):
            self.sum_pc[i] += pc
            self.windows_pc[i] += 1

    def paid(self, i: int) -> bool:
        """Whether mouse i's debt is nothing to within the test (``thr2``): a late mouse's
        sum is its lateness at the end less that at the start, so it is held to twice the
        error of a window held out: the mouse's own, or its prediction's where that is
        larger (direction by direction), each the mean over the windows held out.  What
        the others predict of a mouse they fix poorly (far across the line through two
        close ones) is off by many times its own error, and every residual it owes is
        taken from such a prediction: a debt paid back is nothing to within that (a
        healthy mouse late once far behind a close pair was excluded on the others'
        error, its heading left to the pair, 13 m off at the end of a drive).  The mean,
        not the largest error of any window held out: one window in which the others
        barely fixed the mouse (41 mm across against 1.6 mm typical), or in which it read
        a lift's noise (148 mm), passed a lift's whole shortfall (68 mm; 0.6 m) as paid
        back, the heading turned 13 and 25 degrees at its return.  (Its first and latest
        windows' errors alone, where the lateness lies, were tried: they left drives whose
        catch-up came mid-account up to 24 mm worse.)"""
        r = self.owed[i] + self.pre[i]
        if self.owed_s2[i] <= 0.0:
            return not r.any()
        # its own error, or the prediction's where larger (the part of it beyond the
        # mouse's own, direction by direction): where the others predict it as well as it
        # reads, a single window's residual was already within twice its own error, and
        # adding the prediction's let a jump on a square pass as paid back
        s2 = self.sum_s2[i] / self.windows[i]
        w, v = np.linalg.eigh(self.sum_pc[i] / max(1, self.windows_pc[i]))
        cov = 2.0 * (s2 * np.eye(2) + (v * np.maximum(w - s2, 0.0)) @ v.T)
        cov += self.pre_s2[i] * np.eye(2)
        return float(r @ np.linalg.solve(cov, r)) <= self.thr2

    def take(self, i: int, r: np.ndarray) -> None:
        """Residuals of windows taken back from the pose join the account (out of the
        silence before it, where they were in it: ``before``)."""
        self.owed[i] += r
        if self.pre_s2[i] > 0.0:
            self.pre[i] -= r

    def agree(self, i: int, r: np.ndarray, s2: float) -> None:
        """A window of the exclusion in which mouse i agreed, in a run."""
        self._run[i] += r
        self._run_s2[i] += s2

    def end_run(self, i: int, good: int) -> None:
        """The run ends (a window it disagreed in, or its re-admission) having held ``good``
        windows that would have shown a fault: kept where that is enough."""
        if good >= self.evidence:
            self._banked[i] += self._run[i]
            self._banked_s2[i] += self._run_s2[i]
        self._run[i] = 0.0
        self._run_s2[i] = 0.0

    def readmit(self, i: int, good: int = 0) -> None:
        """Mouse i back in use: its run ends (``end_run``), its account is settled in
        this window (``settle``)."""
        self.end_run(i, good)
        self.readmitted.append(i)

    def settle(self, used: np.ndarray, solve: Solve) -> np.ndarray | None:
        """The twist the mice re-admitted in this window are owed (see the module), or None;
        their accounts are closed."""
        back, self.readmitted = self.readmitted, []
        owed = np.zeros((self.n, 2))
        with_them = used.copy()
        for i in back:
            r, a = self.owed[i], self._banked[i]
            if self.paid(i):
                owed[i] = r
                with_them[i] = True
            elif self._banked_s2[i] > 0 and float(a @ a) <= self.thr2 * self._banked_s2[i]:
                owed[i] = a
                with_them[i] = True
            self.hold(i, np.zeros(2), 0.0)
        if not owed.any():
            return None
        return solve(owed, with_them)
