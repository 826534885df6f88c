"""SIGHUP: reread the config and its calibration, keep the pose, keep what did not change.

Whatever the new config holds, the running one stays unless the new one loads completely
(its YAML work is bounded by safeyaml); the pose carries over, and sensors whose device is
unchanged stay open.  The running tracker closes the windows that are final; the new one
goes on from there (its grid starts at the last published POSE, whose time so never steps
back) with what the sensors kept have reported, so that a window still waiting for a slower
mouse's report closes when it comes, as without a reload (``Tracker.carry``).  A sensor the
reload closes is in no window after that; one it opens joins them once open, as a sensor
that comes back does (``Sensors.replace``).  ``Reloader`` is given the parts it changes; it
swaps the running config and tracker (running.py) for all of them at once.

The pose carries over with its covariance (``Tracker.carry``): a reload changes how the
rig is read from now on, not what is known of where it is.  A reload whose config builds
the same tracker (the fusion's terms unchanged, every sensor kept) goes on with the running
one and what it learnt: its scales, noise and health (``Tracker.go_on``).  A connected client whose
VERSION no longer says what the daemon does (the sensors, the rate, the model, whether it
may control) gets a fresh VERSION, and then each sensor's SOURCE, after the POSE lines of
the old config's windows and before any of the new one's (docs/protocol.md): the POSE
lines' ``used``, ``missing`` and ``excluded`` count from the sensors it names.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mousedom.config import Config, load_config
from mousedom.errors import UserError
from mousedom.service.live_record import Recording
from mousedom.service.protocol import encode
from mousedom.service.publish import Publisher
from mousedom.service.running import Running
from mousedom.service.sdnotify import Notifier
from mousedom.service.server import Client, Server
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
        restart_only: Callable[[Config, Config], list[str]],
        version: Callable[[Client], dict[str, Any]],
    ) -> None:
        self.running = running
        self.clock = clock
        self.notifier = notifier
        self.sensors = sensors
        self.publisher = publisher
        self.server = server
        self.tracker_class = tracker_class
        # What of a new config takes effect only at a restart (the daemon knows), given
        # the config it replaces and the new one
        self.restart_only = restart_only
        # The VERSION a client is sent on connect, as the running config says it now
        # (control.ClientCommands.version)
        self.version = version

    def reload(self) -> None:
        path = self.running.config.path
        self.notifier.reloading()
        new = self._load(path)
        if new is None:
            return
        for w in new.warnings:  # values that look like the wrong unit
            log.warning("%s", w)
        now = self.clock()
        # What is final now closes as the next window would close it, with the old config
        # (the sensors the reload closes in it); the rest waits for reports still to come.
        self.sensors.read_due(now)
        old = self.running.tracker
        self.publisher.publish(old.poll())
        self.publisher.log_scales()
        kept = self.sensors.kept(sensors_of(new))
        tracker = old
        try:  # nothing has changed yet: a fusion the new config cannot make keeps the old
            if not old.go_on(new, kept):  # (the fusion's terms changed: learnt afresh)
                tracker = self.tracker_class(new, t0=old.frontier_time)
                tracker.carry(old, kept)  # the pose, its covariance
        except Exception as e:  # noqa: BLE001 - whatever a reload meets, the old config runs on
            self._failed(path, e)
            return
        self._stop_recording_if_mice_changed(new)
        self.publisher.fold_window_health()  # the old slots' last windows, before they move
        previous = self.running.config
        self.running.replace(new, tracker)
        self.server.apply_settings(new.server)  # (a client's control, for its VERSION)
        # Before the slots change: a sensor the reload opens sends its SOURCE at once.
        told = self._announce_version()
        self.sensors.replace(sensors_of(new), now)
        if told:  # as on connect: the VERSION, then each sensor's SOURCE
            self.publisher.send_sources(now)
        for what in self.restart_only(previous, new):
            log.warning("%s changed: takes effect at the next restart", what)
        log.info("reloaded %s: %d mice, model %s", path, len(new.mice), new.model)
        status = self.sensors.status_line(len(self.server.clients))
        self.notifier.notify(READY=1, STATUS=status)

    def _announce_version(self) -> bool:
        """A fresh VERSION to each client whose last one no longer says what the daemon
        does (its sensors, rate, model, or the client's control changed), queued after
        the POSE lines already made for it; whether any client was told."""
        told = False
        for client in list(self.server.clients.values()):
            banner = self.version(client)
            if banner != client.version:
                client.version = banner
                self.server.send(client, encode(banner))
                told = True
        return told

    def _load(self, path: str | None) -> Config | None:
        """The new config, or None (logged, told to systemd) if it does not load whole."""
        try:
            if not path:
                raise UserError("the running config was not read from a file")
            return load_config(path)
        except Exception as e:  # noqa: BLE001 - whatever a reload meets, the old config runs on
            self._failed(path, e)
            return None

    def _failed(self, path: str | None, e: Exception) -> None:
        """Said once: in the log (with the traceback where no UserError explains it) and
        to systemd, which is told the daemon is ready again with the old config."""
        if not isinstance(e, UserError):
            log.exception("reload of %s failed unexpectedly", path)
        log.error("reload failed, keeping the running config: %s", e)
        self.notifier.notify(READY=1, STATUS=f"reload failed: {e}")

    def finish_windows(self) -> None:
        """What is already readable belongs to the running windows: read it, close and
        publish them all (at the stop)."""
        self.sensors.read_live()
        self.publisher.publish(self.running.tracker.finish())
        self.publisher.log_scales()

    def _stop_recording_if_mice_changed(self, new: Config) -> None:
        outputs = self.publisher.outputs
        for out in list(outputs.items):
            if isinstance(out, Recording) and new.names != out.names:
                log.warning("the mice changed: recording %s stops here", out.path)
                outputs.remove(out)
            elif new.names != self.running.config.names:
                out.mice_changed(tuple(new.names))  # (the per-mouse channels: PerMouse)
