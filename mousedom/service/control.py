"""What clients may ask of the daemon: the VERSION banner, reset, fix, rate, status.

``ClientCommands`` answers ``Server``'s callbacks.  Who may move the pose is decided by the
server (SO_PEERCRED) before a command gets here.  It needs the running config and tracker,
the publisher's SOURCE messages and counters (``PublisherView``) and the loop's figures
(``LoopFigures``), given at construction.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from mousedom.service.output import Pose2
from mousedom.service.protocol import error_message, ok_message, version_message
from mousedom.service.running import Running
from mousedom.service.server import Client, Command

log = logging.getLogger(__name__)


class PublisherView(Protocol):
    """What a command reads of the publisher (publish.Publisher)."""

    @property
    def poses(self) -> int: ...

    @property
    def not_updated(self) -> int: ...

    def source_messages(self, now: float) -> list[dict[str, Any]]: ...

    def moved(self, before: Pose2) -> None: ...

    def pose_now(self) -> dict[str, float]: ...


class LoopFigures(Protocol):
    """The loop's own figures a STATUS reports (daemon.Daemon)."""

    @property
    def started(self) -> float: ...  # clock time at construction

    @property
    def wakes(self) -> int: ...  # loop iterations

    @property
    def source_reads(self) -> int: ...  # sensor reads

    @property
    def clients(self) -> int: ...  # clients connected

    @property
    def dropped_clients(self) -> int: ...  # clients dropped for not reading


class ClientCommands:
    """Server callbacks: on_connect and on_command (see the module docstring)."""

    def __init__(
        self,
        running: Running,
        clock: Callable[[], float],
        publisher: PublisherView,
        loop: LoopFigures,
    ) -> None:
        self.running = running
        self.clock = clock
        self.publisher = publisher
        self.loop = loop

    def on_connect(self, client: Client) -> list[dict[str, Any]]:
        banner = client.version = self.version(client)
        return [banner, *self.publisher.source_messages(self.clock())]

    def version(self, client: Client) -> dict[str, Any]:
        """The VERSION ``client`` is told, as the running config says it now (sent on
        connect, and again after a reload that changes it: reload.py)."""
        config = self.running.config
        return version_message(config.rate_hz, config.names, client.control, config.model)

    def on_command(self, client: Client, cmd: Command) -> list[dict[str, Any]]:
        a = cmd.args
        tracker, publisher = self.running.tracker, self.publisher
        if cmd.name == "reset":
            before = tracker.pose
            tracker.reset(x=a.get("x", 0.0), y=a.get("y", 0.0), theta=a.get("theta", 0.0))
            log.info("pose reset to %s by %r", publisher.pose_now(), client)
            publisher.moved(before)
            return [ok_message("reset", cmd.id, pose=publisher.pose_now())]
        if cmd.name == "fix":
            before = tracker.pose
            tracker.fix(x=a.get("x"), y=a.get("y"), theta=a.get("theta"))
            log.info("pose fixed (%s) by %r", a, client)
            publisher.moved(before)
            return [ok_message("fix", cmd.id, pose=publisher.pose_now())]
        if cmd.name == "rate":
            client.set_rate(a["hz"])
            return [ok_message("rate", cmd.id, hz=a["hz"])]
        if cmd.name == "status":
            now = self.clock()
            return [self._status(now, cmd.id), *publisher.source_messages(now)]
        return [error_message(f"unhandled command {cmd.name!r}", cmd.id)]  # pragma: no cover

    def _status(self, now: float, cmd_id: Any) -> dict[str, Any]:
        config, tracker, loop = self.running.config, self.running.tracker, self.loop
        status = {
            "class": "STATUS",
            "uptime": round(now - loop.started, 3),
            # absolute: doctor and a user read it from another working directory (the
            # daemon never changes its own, so this is the file it loaded and reloads)
            "config": os.path.abspath(config.path) if config.path else config.path,
            "model": config.model,
            "integrator": config.integrator,
            "rate_hz": config.rate_hz,
            "clients": loop.clients,
            "poses": self.publisher.poses,
            "not_updated": self.publisher.not_updated,
            "dropped_clients": loop.dropped_clients,
            "wakes": loop.wakes,
            "source_reads": loop.source_reads,
            "pose": self.publisher.pose_now(),
            "counts_in": np.asarray(tracker.counts_in).tolist(),
            "counts_out": np.asarray(tracker.counts_out).tolist(),
        }
        if cmd_id is not None:
            status["id"] = cmd_id
        return status
