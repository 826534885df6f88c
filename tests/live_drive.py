"""A simulated drive closed the daemon's way, for tests that compare it with replay."""

from __future__ import annotations

from mousedom.fusion.tracker import PoseBatch, Tracker


def live_windows(cfg, result, step: float = 0.01) -> tuple[PoseBatch, Tracker]:
    """Reports pushed as they arrive, windows closed one by one as time passes
    (``poll(one_by_one=True)``): the poses and the tracker."""
    tracker = Tracker(cfg, t0=float(result.motion.starts[0]))
    reps = result.reports
    end = max(float(r.t[-1]) for r in reps.values())
    out = []
    for k in range(int(end / step) + 1):
        lo, hi = k * step, (k + 1) * step
        for name, r in reps.items():
            sel = (r.t > lo) & (r.t <= hi)
            if sel.any():
                tracker.push(name, r.t[sel], r.dx[sel], r.dy[sel])
        tracker.complete_until(hi)
        out.append(tracker.poll(one_by_one=True))
    out.append(tracker.finish())
    return PoseBatch.concat(out, len(reps)), tracker
