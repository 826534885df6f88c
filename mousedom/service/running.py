"""The running config and its tracker: what a reload replaces, together.

Every part of the daemon that reads the config or moves the tracker holds this one object
and reads ``running.config`` and ``running.tracker`` when it acts, so that a reload
(reload.py) swaps both for all of them at once, between two windows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from mousedom.config import Config

if TYPE_CHECKING:  # the numeric core is imported when the daemon runs, not when it loads
    from mousedom.fusion.tracker import Tracker


@dataclass
class Running:
    config: Config
    tracker: Tracker

    def replace(self, config: Config, tracker: Tracker) -> None:
        self.config, self.tracker = config, tracker
