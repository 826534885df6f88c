"""What the daemon sends: POSE lines for every closed window, SOURCE health messages.

``Publisher`` owns the POSE counters, the windows' residuals and health until a SOURCE
message folds them into the slots, and the learnt scales' log; it hands each window to the
socket's clients (``SocketOutput``, never dropped) and to the optional outputs
(``Outputs``: one that fails is logged and dropped).  It reads the sensors through
``SensorView`` and the running config and tracker through ``Running``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from mousedom.fusion import robust
from mousedom.fusion.posebatch import PoseBatch, PoseRow
from mousedom.fusion.robust import Health, Reason
from mousedom.service.output import Output, Pose2
from mousedom.service.protocol import encode, encode_pose, source_message
from mousedom.service.running import Running
from mousedom.service.scales import ScaleLog, scale_fields
from mousedom.service.server import Server
from mousedom.service.slots import Slot, WindowNames

log = logging.getLogger(__name__)

Clock = Callable[[], float]


class SensorView(Protocol):
    """What the publisher reads of the sensors (slots.Sensors)."""

    slots: list[Slot]
    # (missing, excluded, suspect) names per pattern of states met so far: names_for
    # fills it
    names_by_state: dict[tuple[int, ...], WindowNames]

    def names_for(self, state: Sequence[int]) -> WindowNames: ...


class Outputs:
    """The optional outputs (DDS, MCAP, Foxglove, the live recording, metrics), called in
    order; one that raises is logged, closed and dropped, and the rest go on."""

    def __init__(self, outputs: Sequence[Output] = ()) -> None:
        self.items: list[Output] = list(outputs)
        self._reporters: list[Output] = []
        self.wants_reports = False
        self._changed()

    def __bool__(self) -> bool:
        return bool(self.items)

    def add(self, out: Output) -> None:
        self.items.append(out)
        self._changed()

    def _changed(self) -> None:
        self._reporters = [o for o in self.items if o.wants_reports]
        self.wants_reports = bool(self._reporters)

    def stop(self, out: Output, why: str) -> None:
        log.error("%s failed (%s); it is stopped, the daemon goes on without it", out, why)
        try:
            self.remove(out)
        except Exception:  # noqa: BLE001 - it failed already: nothing more to say
            pass

    def remove(self, out: Output) -> None:
        """Take ``out`` off the list and close it."""
        self.items.remove(out)
        self._changed()
        out.close()

    def _call(self, out: Output, method: Callable[..., Any], *args: Any) -> Any:
        try:
            return method(*args)
        except Exception as e:  # noqa: BLE001 - any failure of an optional output
            self.stop(out, str(getattr(e, "strerror", None) or e))
            return None

    def publish(self, row: PoseRow) -> None:
        for out in list(self.items):
            self._call(out, out.publish, row)

    def reports(self, index: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        for out in list(self._reporters):
            self._call(out, out.reports, index, t, dx, dy)

    def gyro(self, t: np.ndarray, rate: np.ndarray, saturated: np.ndarray | None = None) -> None:
        for out in list(self._reporters):
            self._call(out, out.gyro, t, rate, saturated)

    def checkpoint(self, complete: float) -> None:
        for out in list(self.items):
            self._call(out, out.checkpoint, complete)

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:
        for out in list(self.items):
            self._call(out, out.sources, messages, t)

    def moved(self, before: Pose2, after: Pose2) -> None:
        for out in list(self.items):
            self._call(out, out.moved, before, after)

    def fixes(self) -> list[tuple[Output, Pose2]]:
        asked: list[tuple[Output, Pose2]] = []
        for out in list(self.items):
            got = self._call(out, out.fixes)
            asked.extend((out, pose) for pose in got or ())
        return asked


class SocketOutput(Output):
    """The Unix socket's clients: a POSE line per window (each client at its own rate),
    the sensors' SOURCE states."""

    def __init__(self, server: Server, sensors: SensorView, running: Running) -> None:
        self.server = server
        self.sensors = sensors
        self.running = running

    def publish(self, row: PoseRow) -> None:
        sensors = self.sensors
        state = row.state
        # (a list from rows made of arrays is not a key: names_for makes it one)
        names = sensors.names_by_state.get(state) if isinstance(state, tuple) else None
        if names is None:  # a new pattern
            names = sensors.names_for(state)
        line = encode_pose(
            row.t,
            (row.x, row.y, row.theta),
            (row.vx, row.vy, row.omega),
            row.cov,
            row.used,
            row.ok,
            names[0],
            names[1],
            names[2],
            row.consistent,
            row.gyro,
        )
        # A client at a lower rate takes the POSE nearest its own grid (server.py).
        self.server.broadcast_pose(row.t, line, 0.5 / self.running.config.rate_hz)

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:
        for msg in messages:
            # A sensor's state: a newer SOURCE replaces one still waiting for a client.
            self.server.broadcast_state(f"SOURCE {msg['name']}", encode(msg))


class Publisher:
    """POSE and SOURCE out to the clients and the outputs (see the module docstring)."""

    # Windows whose residuals wait to be folded into the slots: a bound for a loop that
    # publishes without ever making a SOURCE message (they come once a second).
    _RESIDUALS_HELD = 256

    def __init__(
        self,
        running: Running,
        sensors: SensorView,
        socket: SocketOutput,
        outputs: Outputs,
        clock: Clock,
    ) -> None:
        self.running = running
        self.sensors = sensors
        self.socket = socket
        self.outputs = outputs
        self.clock = clock
        self.poses = 0  # POSE lines made
        self.last_pose_t = -float("inf")  # POSE times never step back, across reloads too
        self.not_updated = 0  # of which held: no rank, no motion invented
        # Each window's residuals and the last window's health, folded into the slots
        # when a SOURCE message is made (see fold_window_health).
        self.window_residuals: list[Any] = []
        self._last_health: tuple[Any, Any] | None = None
        self._last_gyro: Any = ()  # the last window's gyro (PoseRow.gyro) for its SOURCE
        # The learnt scales' warnings, logged when they appear, persist or end (scales.py)
        self.scale_log = ScaleLog()

    def publish(self, batch: PoseBatch) -> None:
        # Rows of Python values (the one-window path makes them without numpy): what only
        # the SOURCE messages need (residuals, health) is folded in when they are made.
        rows = batch.rows()
        if not rows:
            return
        residuals = self.window_residuals
        socket, outputs = self.socket, self.outputs
        for pose in rows:
            if pose.ok:
                residuals.append(pose.residual)
            # Counted before it is sent: a client that has a POSE finds it in the counters.
            self.poses += 1
            self.last_pose_t = pose.t
            self.not_updated += not pose.ok
            socket.publish(pose)
            if outputs:
                outputs.publish(pose)
        last = rows[-1]
        self._last_health = (last.state, last.reason)
        self._last_gyro = last.gyro
        if outputs:
            self._absolute_fixes()
        if len(residuals) > self._RESIDUALS_HELD:
            self.fold_window_health()

    def log_scales(self) -> None:
        """The learnt scales' warnings, if they were renewed (twice a second of windows)
        since they were last read.  The daemon asks once a window's learning is done (after
        Tracker.settle, and after the last windows at a reload or a stop)."""
        learner = self.running.tracker.scales
        if self.scale_log.due(learner):
            self.scale_log.renewed(learner, self.running.config.names, self.clock())

    def fold_window_health(self) -> None:
        """The held windows' residuals into each slot's sums, and the last window's health
        into the slots' states (per mouse index: called before the slots change)."""
        slots = self.sensors.slots
        for residual in self.window_residuals:
            for slot, (rx, ry) in zip(slots, residual, strict=False):
                slot.add_residual(rx, ry)
        self.window_residuals.clear()
        if self._last_health is not None:
            state, reason = self._last_health
            for slot, st, why in zip(slots, state, reason, strict=False):
                slot.health_state, slot.health_reason = Health(st), Reason(why)
            self._last_health = None

    def send_sources(self, now: float) -> None:
        """Every sensor's SOURCE to the clients now (a sensor came or went, a reload)."""
        self.socket.sources(self.source_messages(now), now)

    def source_messages(self, now: float) -> list[dict[str, Any]]:
        self.fold_window_health()
        config = self.running.config
        scales = scale_fields(self.running.tracker.scales, config.names, config.robust.learn_scale)
        out = []
        for slot in self.sensors.slots:
            h = slot.source.health
            h.reports_per_s = slot.source.rate(now)
            # a mouse's learnt scale, or the gyro's bias (its slot comes after the mice)
            extra = scales[slot.index] if slot.index < len(scales) else self._gyro_fields()
            out.append(
                source_message(
                    h.as_dict(),
                    live=slot.fused,
                    age=None if h.last_t is None else round(now - h.last_t, 6),
                    residual=slot.take_rms(),
                    excluded=not slot.fused or slot.health_state == Health.EXCLUDED,
                    state="gone" if not slot.fused else robust.STATES[slot.health_state],
                    reason=robust.REASONS[slot.health_reason] or None,
                    **extra,
                )
            )
        return out

    def _gyro_fields(self) -> dict[str, float | None]:
        """The gyro's SOURCE fields: its bias and the bias's sigma after the last window."""
        gyro = self._last_gyro
        if not len(gyro):
            return {"bias": None, "bias_sigma": None}
        return {"bias": float(gyro[1]), "bias_sigma": float(gyro[2])}

    def every_second(self, now: float) -> None:
        """The SOURCE messages to the clients and the outputs, and the outputs' checkpoint
        (every report stamped before the tracker's frontier has been handed over)."""
        if self.socket.server.clients:
            self.socket.sources(self.source_messages(now), now)
        if self.outputs:
            self.outputs.sources(self.source_messages(now), now)
            self.outputs.checkpoint(self.running.tracker.frontier_time)

    def moved(self, before: Pose2) -> None:
        """The pose was moved: outputs that keep a continuous odom frame (REP-105) move
        their map -> odom correction instead."""
        if self.outputs:
            self.outputs.moved(before, self.running.tracker.pose)

    def _absolute_fixes(self) -> None:
        """Poses an output was told from outside (ROS 2's /initialpose), applied as the
        socket's fix of all three coordinates is: map -> odom takes the jump (REP-105)."""
        for out, (x, y, theta) in self.outputs.fixes():
            tracker = self.running.tracker
            tracker.settle()  # (the pose before the fix with what its window's learning gave)
            before = tracker.pose
            tracker.fix(x=x, y=y, theta=theta)
            log.info("pose set to (%.3f, %.3f, %.3f) by %s", x, y, theta, type(out).__name__)
            self.moved(before)

    def pose_now(self) -> dict[str, float]:
        x, y, theta = (float(v) for v in self.running.tracker.pose)
        return {"x": x, "y": y, "theta": theta}
