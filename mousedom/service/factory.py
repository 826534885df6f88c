"""Which source class reads a configured mouse (evdev, serial ADNS-3080 or replay) or the
gyro (IIO, a ROS 2 Imu topic, or replay)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from mousedom.config import GyroConfig, MouseConfig
from mousedom.errors import UserError
from mousedom.sources.base import Source

Clock = Callable[[], float]


def make_source(
    mouse: MouseConfig | GyroConfig, clock: Clock = time.monotonic, loop: bool = False
) -> Source:
    """The backend a mouse's config asks for: evdev, serial ADNS-3080 or replay; for the
    rig's gyro, its IIO device or its capture.

    A replay is paced on ``clock`` (real time) and starts again at its end with ``loop``.
    """
    if isinstance(mouse, GyroConfig):
        if mouse.replay is not None:
            from mousedom.capture.source import GyroReplaySource

            return GyroReplaySource(mouse, loop=loop, clock=clock)
        if mouse.ros2 is not None:
            from mousedom.service.ros2imu import Ros2ImuSource

            return Ros2ImuSource(mouse, clock=clock)
        from mousedom.sources.iio import GyroSource

        return GyroSource(mouse, clock=clock)
    try:
        if mouse.evdev is not None:
            from mousedom.sources.evdev import EvdevSource

            return EvdevSource(mouse)
        if mouse.serial is not None:
            from mousedom.sources.adns import AdnsSource

            return AdnsSource(mouse)
        if mouse.replay is not None:
            from mousedom.capture.source import ReplaySource

            return ReplaySource(
                mouse.name, mouse.replay, device=mouse.replay_device, loop=loop, clock=clock
            )
    except ImportError as e:
        raise UserError(f"mice.{mouse.name}: this build has no such source ({e})") from None
    raise UserError(f"mice.{mouse.name}: says nowhere where the mouse comes from")


def source_key(mouse: MouseConfig | GyroConfig) -> tuple[Any, ...]:
    """What identifies a sensor's device: when it changes on reload, the source is reopened
    (a gyro's whole section: its axis, sign and rate are set when it opens)."""
    if isinstance(mouse, GyroConfig):
        return ("gyro", mouse.own())
    return (mouse.evdev, mouse.serial, mouse.replay, mouse.replay_device)
