"""The gyro's bias, learnt from spans of windows where mice and gyro agree.

Per window the mice's turn is far noisier than over a span: a report stamped a little late
moves counts from one window to the next, so each window's turn is off by as much as the
next one's is off the other way.  Over a span of windows only the counts moved across the
span's two edges remain.  So the bias is not learnt window by window (as if those errors
were independent, which would learn it slowly and over-confidently), but once a span
(``SPAN_S``) from the span's summed innovation

    E = sum_k (g_k - a_k - b_hat T) = -n T db + sum_k (n_gyro,k - n_mice,k)

with variance S = sum_k C_aa,k (the mice's white errors) + 2 t (the timing errors of the
span's two edges, t the span's mean per-window timing variance) + n N^2 T + (n T)^2 P.
E^2 / S is chi-square (1 dof) when both tell the truth: a span that fails it teaches
nothing, unless the mice it holds are trusted (three or more that agree, or a standstill):
then the gyro's bias moved, and it is learnt again (its variance reset).

Between renewals the bias's error is constant, and a heading made with it drifts by T db
per window: ``cross``, the covariance of the heading's error with the bias's, carries
that (GyroFusion.window adds -2 kappa T cross to each window's heading variance).
"""

from __future__ import annotations

import math

from mousedom.fusion import chi2

SPAN_S = 0.25  # seconds of windows per renewal of the bias


class BiasLearner:
    """The bias (b_hat, its variance P, ``cross``) and the span being summed."""

    def __init__(
        self,
        sigma: float,
        walk: float,
        density: float,
        period: float,
        false_alarm: float = 1e-4,
    ) -> None:
        self.bias = 0.0  # rad/s
        self.var = sigma * sigma  # P
        self.cross = 0.0  # cov(heading error, bias error)
        self._sigma2 = sigma * sigma  # P when the bias is learnt again
        self._walk = walk * walk * period  # P's growth per window
        self._white = density * density * period  # one window's white turn noise
        self._period = period
        self._span = max(1, round(SPAN_S / period))
        self._threshold = chi2.quantile(1.0 - false_alarm, 1)
        self._reset_span()

    def _reset_span(self) -> None:
        self._n = 0
        self._e = 0.0
        self._white_sum = 0.0  # the mice's white variance, summed
        self._timing = 0.0  # their timing variance, summed (its mean counts twice)
        self._ncov = 0.0  # sum of kappa N^2 T - (1 - kappa) C_aa (see the module)
        self._trusted = True  # every window's mice trusted (three that agree, or still)

    @property
    def walk(self) -> float:
        """P's growth per window."""
        return self._walk

    def predict(self) -> None:
        """A window passes: the bias may have wandered."""
        self.var += self._walk

    def relearn(self) -> None:
        """The bias moved far: its variance reset, the span being summed dropped."""
        self.var = max(self.var, self._sigma2)
        self._reset_span()

    def carry(self, kappa: float) -> None:
        """The window's heading took ``kappa`` of the gyro's turn, with the bias's error."""
        self.cross -= kappa * self._period * self.var

    def observe(self, e: float, white: float, timing: float, kappa: float, trusted: bool) -> None:
        """One window of the span: its innovation ``e`` (g - a - b_hat T), the mice's white
        and timing variances of their turn, the gyro's share ``kappa`` in the heading,
        whether its mice are trusted."""
        self._n += 1
        self._e += e
        self._white_sum += white
        self._timing += timing
        self._ncov += kappa * self._white - (1.0 - kappa) * (white + timing)
        self._trusted = self._trusted and trusted
        # tested every window (a bias that jumped is seen within a few), learnt from once a
        # span
        if self._n >= self._span or not self._agrees():
            self.renew()

    def _agrees(self) -> bool:
        """Whether the span so far passes the test (see the module docstring)."""
        n = self._n
        nt = n * self._period
        s = self._white_sum + 2.0 * self._timing / n + n * self._white + nt * nt * self.var
        return self._e * self._e <= self._threshold * s

    def renew(self) -> bool | None:
        """End the span: learn from it if it agrees (or its mice are trusted); whether it
        agreed (None: no window in it)."""
        n = self._n
        if not n:
            return None
        nt = n * self._period
        rest = self._white_sum + 2.0 * self._timing / n + n * self._white
        agreed = self._agrees()
        if not agreed:
            if not self._trusted:
                self._reset_span()
                return False
            self.var = max(self.var, self._sigma2)  # the bias moved: learnt again
        s = rest + nt * nt * self.var
        k = nt * self.var / s
        self.bias += k * self._e
        self.cross = (1.0 - k * nt) * self.cross + k * self._ncov
        self.var -= k * nt * self.var
        self._reset_span()
        return agreed

    @property
    def sigma(self) -> float:
        return math.sqrt(self.var)
