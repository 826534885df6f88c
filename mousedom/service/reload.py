"""SIGHUP: reread the config and its calibration, keep the pose, keep what did not change.

Whatever the new config holds, the running one stays unless the new one loads completely
(its YAML work is bounded by safeyaml); the pose carries over, sensors whose device is
unchanged stay open, and the new window grid starts after the last published POSE so that
its time never steps back.  A sensor the reload closes leaves the running windows, and one
it opens joins the new ones, as a sensor that vanishes or comes back does (``Sensors.leave``
and ``replace``).  ``Reloader`` is given the parts it changes; it swaps the
running config and tracker (running.py) for all of them at once.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from mousedom.config import Config, load_config
from mousedom.errors import UserError
from mousedom.service.live_record import Recording
from mousedom.service.publish import Publisher
from mousedom.service.running import Running
from mousedom.service.sdnotify import Notifier
from mousedom.service.server import Server
from mousedom.service.slots import Sensors, sensors_of

if TYPE_CHECKING:
    from mousedom.fusion.tracker import Tracker

log = logging.getLogger(__name__)


class Reloader:
    """``reload()`` (see the module docstring)."""

    def __init__(
        self,
        running: Running,
        clock: Callable[[], float],
        notifier: Notifier,
        sensors: Sensors,
        publisher: Publisher,
        server: Server,
        tracker_class: type[Tracker],
        restart_only: Callable[[Config], list[str]],
    ) -> None:
        self.running = running
        self.clock = clock
        self.notifier = notifier
        self.sensors = sensors
        self.publisher = publisher
        self.server = server
        self.tracker_class = tracker_class
        # What of a new config takes effect only at a restart (the daemon knows)
        self.restart_only = restart_only

    def reload(self) -> None:
        path = self.running.config.path
        self.notifier.reloading()
        new = self._load(path)
        if new is None:
            return
        for w in new.warnings:  # values that look like the wrong unit
            log.warning("%s", w)
        now = self.clock()
        self.sensors.leave(sensors_of(new), now)
        self.finish_windows()
        # finish() may have closed a window ending after now (the one holding the last
        # report): the new grid starts after it, or POSE t would step back once.
        tracker = self.tracker_class(new, t0=max(now, self.publisher.last_pose_t))
        tracker.reset(**self.publisher.pose_now())
        tracker.complete_until(now)  # what came before now went to the old tracker
        self._stop_recording_if_mice_changed(new)
        self.publisher.fold_window_health()  # the old slots' last windows, before they move
        self.running.replace(new, tracker)
        self.sensors.replace(sensors_of(new), now)
        for what in self.restart_only(new):
            log.warning("%s changed: takes effect at the next restart", what)
        self.server.apply_settings(new.server)
        log.info("reloaded %s: %d mice, model %s", path, len(new.mice), new.model)
        status = self.sensors.status_line(len(self.server.clients))
        self.notifier.notify(READY=1, STATUS=status)

    def _load(self, path: str | None) -> Config | None:
        """The new config, or None (logged, told to systemd) if it does not load whole."""
        try:
            if not path:
                raise UserError("the running config was not read from a file")
            return load_config(path)
        except Exception as e:  # noqa: BLE001 - whatever a reload meets, the old config runs on
            if not isinstance(e, UserError):
                log.exception("reload of %s failed unexpectedly", path)
            log.error("reload failed, keeping the running config: %s", e)
            self.notifier.notify(READY=1, STATUS=f"reload failed: {e}")
            return None

    def finish_windows(self) -> None:
        """What is already readable belongs to the running windows: read it, close and
        publish them all (before a reload, and at the stop)."""
        self.sensors.read_live()
        self.publisher.publish(self.running.tracker.finish())
        self.publisher.log_scales()

    def _stop_recording_if_mice_changed(self, new: Config) -> None:
        outputs = self.publisher.outputs
        for out in list(outputs.items):
            if isinstance(out, Recording) and new.names != out.names:
                log.warning("the mice changed: recording %s stops here", out.path)
                outputs.remove(out)
