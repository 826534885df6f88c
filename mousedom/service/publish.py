"""What the daemon sends: POSE lines for every closed window, SOURCE health messages.

A mixin of ``Daemon``: it uses ``self.slots``, ``self.server``, ``self.tracker``,
``self.config``, ``self.missing_names`` and ``self.scale_log`` (the learnt scales' warnings,
logged when the learner renews them: service/scales.py), and keeps the POSE counters ``self.poses``,
``self.last_pose_t`` and ``self.not_updated``, and the windows' residuals and health until
a SOURCE message folds them into the slots.
"""

from __future__ import annotations

import logging
from typing import Any

from mousedom.fusion import robust
from mousedom.fusion.posebatch import PoseBatch
from mousedom.service.protocol import encode, encode_pose, source_message
from mousedom.service.scales import scale_fields

log = logging.getLogger(__name__)


class Publisher:
    """POSE and SOURCE out to the socket's clients (see the module docstring)."""

    # Windows whose residuals wait to be folded into the slots: a bound for a loop that
    # publishes without ever making a SOURCE message (they come once a second).
    _RESIDUALS_HELD = 256

    def _publish(self, batch: PoseBatch) -> None:
        # Rows of Python values (the one-window path makes them without numpy) and a POSE
        # line without a dict and json.dumps: the daemon publishes every window, so what
        # only the SOURCE messages need (residuals, health) is folded in when they are made.
        rows = batch.rows()
        if not rows:
            return
        missing = self.missing_names
        tolerance = 0.5 / self.config.rate_hz
        residuals = self._window_residuals
        names_by_state = self._names_by_state
        for pose in rows:
            if pose.ok:
                residuals.append(pose.residual)
            try:
                names = names_by_state[pose.state]
            except (KeyError, TypeError):  # a new pattern, or a list (rows from arrays)
                names = self._health_names(pose.state)
            line = encode_pose(
                pose.t,
                (pose.x, pose.y, pose.theta),
                (pose.vx, pose.vy, pose.omega),
                pose.cov,
                pose.used,
                pose.ok,
                missing,
                names[0],
                names[1],
                pose.consistent,
            )
            self.poses += 1
            self.last_pose_t = pose.t
            self.not_updated += not pose.ok
            self.server.broadcast_pose(pose.t, line, tolerance)
            if self.outputs:
                self._to_outputs("publish", pose)
        last = rows[-1]
        self._last_health = (last.state, last.reason)
        learner = self.tracker.scales
        if self.scale_log.due(learner):  # renewed (twice a second of windows): its warnings
            self.scale_log.renewed(learner, self.config.names, self.clock())
        if self.outputs:
            self._absolute_fixes()
        if len(residuals) > self._RESIDUALS_HELD:
            self._fold_window_health()

    def _health_names(self, state) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(excluded, suspect) sensor names for a window's per-mouse states (cached per
        pattern: a rig has few, and this runs for every window)."""
        key = tuple(state)  # rows from arrays hold lists
        names = self._names_by_state.get(key)
        if names is None:
            ex = tuple(s.name for s, v in zip(self.slots, key, strict=False)
                       if v == robust.EXCLUDED)  # fmt: skip
            su = tuple(s.name for s, v in zip(self.slots, key, strict=False)
                       if v == robust.SUSPECT)  # fmt: skip
            names = self._names_by_state[key] = (ex, su)
        return names

    def _fold_window_health(self) -> None:
        """The held windows' residuals into each slot's sums, and the last window's health
        into the slots' states (per mouse index: called before the slots change)."""
        for residual in self._window_residuals:
            for slot, (rx, ry) in zip(self.slots, residual, strict=False):
                if rx - rx == 0.0 and ry - ry == 0.0:  # both finite
                    slot.residual_sq += rx * rx + ry * ry
                    slot.residual_n += 1
        self._window_residuals.clear()
        if self._last_health is not None:
            state, reason = self._last_health
            for slot, st, why in zip(self.slots, state, reason, strict=False):
                slot.health_state, slot.health_reason = int(st), int(why)
            self._last_health = None

    def _source_messages(self, now: float) -> list[dict[str, Any]]:
        self._fold_window_health()
        out = []
        scales = scale_fields(
            self.tracker.scales, self.config.names, self.config.robust.learn_scale
        )
        for slot in self.slots:
            h = slot.source.health
            if slot.residual_n:
                slot.residual_rms = (slot.residual_sq / slot.residual_n) ** 0.5
                slot.residual_sq, slot.residual_n = 0.0, 0
            out.append(
                source_message(
                    h.as_dict(),
                    live=slot.live,
                    age=None if h.last_t is None else round(now - h.last_t, 6),
                    residual=slot.residual_rms,
                    excluded=not slot.live or slot.health_state == robust.EXCLUDED,
                    state="gone" if not slot.live else robust.STATES[slot.health_state],
                    reason=robust.REASONS[slot.health_reason] or None,
                    **scales[slot.index],
                )
            )
        return out

    def _to_outputs(self, method: str, *args: Any) -> None:
        """Hand on to each output (DDS, MCAP); one that fails is logged and dropped: the
        socket, which robots rely on, goes on."""
        for out in list(self.outputs):
            try:
                getattr(out, method)(*args)
            except Exception as e:  # noqa: BLE001 - any failure of an optional output
                self._stop_output(out, e)

    def _stop_output(self, out: Any, error: Exception) -> None:
        log.error("output %s failed (%s); it is stopped", type(out).__name__, error)
        self.outputs.remove(out)
        try:
            out.close()
        except Exception:  # noqa: BLE001
            pass

    def _absolute_fixes(self) -> None:
        """Poses an output was told from outside (ROS 2's /initialpose), applied as the
        socket's fix of all three coordinates is: map -> odom takes the jump (REP-105)."""
        for out in list(self.outputs):
            fixes = getattr(out, "fixes", None)
            if fixes is None:
                continue
            try:
                asked = fixes()
            except Exception as e:  # noqa: BLE001 - as _to_outputs: that output stops
                self._stop_output(out, e)
                continue
            for x, y, theta in asked:
                before = self.tracker.pose
                self.tracker.fix(x=x, y=y, theta=theta)
                log.info("pose set to (%.3f, %.3f, %.3f) by %s", x, y, theta,
                         type(out).__name__)  # fmt: skip
                self._moved(before)

    def _output_sources(self, now: float) -> None:
        if self.outputs or self.metrics is not None:
            messages = self._source_messages(now)
            if self.outputs:
                self._to_outputs("sources", messages, now)
            if self.metrics is not None:  # each mouse's figures, for the next scrape
                self.metrics.sources(messages, now)

    def _broadcast_sources(self, now: float) -> None:
        if not self.server.clients:
            return
        for msg in self._source_messages(now):
            # A sensor's state: a newer SOURCE replaces one still waiting for a client.
            self.server.broadcast_state(f"SOURCE {msg['name']}", encode(msg))

    def _pose_now(self) -> dict[str, float]:
        x, y, theta = (float(v) for v in self.tracker.pose)
        return {"x": x, "y": y, "theta": theta}
