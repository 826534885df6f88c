"""SIGHUP: reread the config and its calibration, keep the pose, keep what did not change.

A mixin of ``Daemon``.  Whatever the new config holds, the running one stays unless the
new one loads completely (its YAML work is bounded by safeyaml); the pose carries over,
sensors whose device is unchanged stay open, and the new window grid starts after the last
published POSE so that its time never steps back.
"""

from __future__ import annotations

import logging

from mousedom.config import load_config
from mousedom.errors import UserError
from mousedom.service.factory import source_key

log = logging.getLogger(__name__)


class Reloader:
    """``_do_reload`` (see the module docstring)."""

    def _do_reload(self) -> None:
        path = self.config.path
        self.notifier.reloading()
        try:
            if not path:
                raise UserError("the running config was not read from a file")
            new = load_config(path)
        except Exception as e:  # noqa: BLE001 - whatever a reload meets, the old config runs on
            if not isinstance(e, UserError):
                log.exception("reload of %s failed unexpectedly", path)
            log.error("reload failed, keeping the running config: %s", e)
            self.notifier.notify(READY=1, STATUS=f"reload failed: {e}")
            return
        for w in new.warnings:  # values that look like the wrong unit
            log.warning("%s", w)
        now = self.clock()
        for slot in self.slots:  # what is already readable belongs to the old windows
            if slot.live:
                self._read_slot(slot)
        self._publish(self.tracker.finish())
        pose = self._pose_now()
        # finish() may have closed a window ending after now (the one holding the last
        # report): the new grid starts after it, or POSE t would step back once.
        tracker = self._tracker_class(new, t0=max(now, self.last_pose_t))
        tracker.reset(**pose)
        tracker.complete_until(now)  # what came before now went to the old tracker
        old = {s.name: s for s in self.slots}
        slots = []
        for i, mouse in enumerate(new.mice):
            prev = old.pop(mouse.name, None)
            if prev is not None and source_key(prev.mouse) == source_key(mouse):
                prev.index, prev.mouse = i, mouse
                slots.append(prev)
            else:
                if prev is not None:
                    self._close_slot(prev)
                slots.append(self._new_slot(i, mouse))
        for gone in old.values():
            self._close_slot(gone)
        if self.recording is not None and new.names != self.recording.names:
            log.warning("the mice changed: recording %s stops here", self.recording.path)
            self._record(self.recording.close)
            self.recording = None
        self._fold_window_health()  # the old slots' last windows, before they move
        self.config, self.tracker, self.slots = new, tracker, slots
        self._live_changed()
        for slot in slots:
            if slot.live:
                tracker.set_live(slot.index, True, now)
            else:
                self._try_open(slot, now)
        if new.server.socket and new.server.socket != self.server.path:
            log.warning("server.socket changed: takes effect at the next restart")
        # (not warned when the file has none: `run --metrics` may have turned it on)
        running = self.metrics.cfg if self.metrics is not None else None
        if new.metrics is not None and new.metrics != running:
            log.warning("outputs.metrics changed: takes effect at the next restart")
        self.server.apply_settings(new.server)
        log.info("reloaded %s: %d mice, model %s", path, len(new.mice), new.model)
        self.notifier.notify(READY=1, STATUS=self._status_line())
