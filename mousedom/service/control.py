"""What clients may ask of the daemon: the VERSION banner, reset, fix, rate, status.

A mixin of ``Daemon``: it answers ``Server``'s callbacks with the daemon's state.  Who may
move the pose is decided by the server (SO_PEERCRED) before a command gets here.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from mousedom.service.protocol import error_message, ok_message, version_message
from mousedom.service.server import Client, Command

log = logging.getLogger(__name__)


class ClientCommands:
    """Server callbacks: on_connect and on_command (see the module docstring)."""

    def _on_connect(self, client: Client) -> list[dict[str, Any]]:
        banner = version_message(
            self.config.rate_hz, self.config.names, client.control, self.config.model
        )
        return [banner, *self._source_messages(self.clock())]

    def _moved(self, before: tuple[float, float, float]) -> None:
        """The pose was moved: outputs that keep a continuous odom frame (REP-105) move
        their map -> odom correction instead."""
        if self.outputs:
            self._to_outputs("moved", before, self.tracker.pose)

    def _on_command(self, client: Client, cmd: Command) -> list[dict[str, Any]]:
        a = cmd.args
        if cmd.name == "reset":
            before = self.tracker.pose
            self.tracker.reset(x=a.get("x", 0.0), y=a.get("y", 0.0), theta=a.get("theta", 0.0))
            log.info("pose reset to %s by %r", self._pose_now(), client)
            self._moved(before)
            return [ok_message("reset", cmd.id, pose=self._pose_now())]
        if cmd.name == "fix":
            before = self.tracker.pose
            self.tracker.fix(x=a.get("x"), y=a.get("y"), theta=a.get("theta"))
            log.info("pose fixed (%s) by %r", a, client)
            self._moved(before)
            return [ok_message("fix", cmd.id, pose=self._pose_now())]
        if cmd.name == "rate":
            client.set_rate(a["hz"])
            return [ok_message("rate", cmd.id, hz=a["hz"])]
        if cmd.name == "status":
            now = self.clock()
            status = {
                "class": "STATUS",
                "uptime": round(now - self.started, 3),
                "config": self.config.path,
                "model": self.config.model,
                "integrator": self.config.integrator,
                "rate_hz": self.config.rate_hz,
                "clients": len(self.server.clients),
                "poses": self.poses,
                "not_updated": self.not_updated,
                "dropped_clients": self.server.dropped,
                "wakes": self.wakes,
                "source_reads": self.source_reads,
                "pose": self._pose_now(),
                "counts_in": np.asarray(self.tracker.counts_in).tolist(),
                "counts_out": np.asarray(self.tracker.counts_out).tolist(),
            }
            if cmd.id is not None:
                status["id"] = cmd.id
            return [status, *self._source_messages(now)]
        return [error_message(f"unhandled command {cmd.name!r}", cmd.id)]  # pragma: no cover
