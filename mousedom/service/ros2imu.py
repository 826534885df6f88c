"""A gyro from a ROS 2 topic: the yaw rate of a ``sensor_msgs/Imu`` that a driver publishes.

Robots whose IMU already has a ROS 2 driver (``gyro: {ros2: /imu/data}``, docs/gyro.md)
give its angular velocity to the fusion as an IIO gyro's samples are given
(``GyroSamples``): the config's ``axis`` of the message's ``angular_velocity`` (in the
IMU's frame, ``header.frame_id``) times ``sign`` is the turn rate about body z.

On the wire as ROS 2 puts it (ros2out.py: the topic ``/imu/data`` is the DDS topic
``rt/imu/data``, the type ``sensor_msgs::msg::dds_::Imu_``), read best effort (matching the
sensor-data QoS drivers publish with, and reliable writers too), keeping the last
``HISTORY`` messages between two reads.

Stamps: each message's ``header.stamp``, on the clock ``stamps`` names: ``system`` (ROS
time, what drivers stamp with) is moved onto CLOCK_MONOTONIC by the system clock's lead
read at each take; ``monotonic`` is taken as it is.  Stamps far from the read's time (sim
time, a driver that stamps zero) are re-stamped to it and counted (``stamps_restamped``),
as every source's are (the samples of one read then share a stamp, and all but the first
turn nothing: a driver on another clock is not one to fuse).  A message whose
``angular_velocity_covariance[0]`` is -1 has no
angular velocity (REP-145) and one whose rate is not finite, or no gyro's (``MAX_RATE``),
is dropped and counted: neither is a turn.  Saturation is not marked: the message has no
word for it (the fusion's judgement of the gyro against three or more mice still stands).

In the ROS 2 graph the reader is node ``mousedom_gyro``'s (``GYRO_NODE``), in the ROS 2
output's namespace (config.load gives it, with the output's domain): ``ros2 node list``
shows it, ``ros2 topic info /imu/data`` counts it among the subscribers.

No descriptor to wait on (cyclonedds' Python API has none): the source is ``paced``, read
on each turn of the daemon's loop.  A driver that stops publishing sends nothing to say so
(an IIO device's unplug wakes its reader): after ``SILENT_S`` without a message the topic
counts as gone (``SourceGone``), and so after ``FIRST_S`` with none since it was joined,
so that the windows after it take the mice's heading rather than a gyro that turned
nothing; the daemon joins it again a second later, and it is back with its next message.
Samples that are not data (the writer's disposal or unregistration, which Cyclone hands
over as "invalid samples") are skipped.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from mousedom.config import GyroConfig
from mousedom.service.rostime import system_lead
from mousedom.sources.base import (
    MAX_RATE,
    Reports,
    Source,
    SourceGone,
    SourceUnavailable,
)
from mousedom.sources.iio import GyroSamples

log = logging.getLogger(__name__)

HISTORY = 1024  # messages kept between two reads: seconds of a 200 Hz IMU
TAKE = 256  # per take (a read takes until none is left, at most HISTORY)
# No message for this long (after one came) is a driver gone: IMUs publish at 50-1000 Hz
SILENT_S = 0.5
# No message at all for this long after the topic was joined: no driver publishes it (or
# on another domain).  Longer than SILENT_S: DDS discovery takes a second or so.  Until
# the first message the gyro is read but not fused, and SOURCE says it is not connected
# (it said connected for ever, and the windows took a gyro that was never heard).
FIRST_S = 3.0
GYRO_NODE = "mousedom_gyro"  # the reader's node in the ROS 2 graph (the output's: mousedom)


class Ros2ImuSource(Source):
    """The configured ``gyro.ros2`` topic's angular velocity (see the module)."""

    kind = "ros2"
    paced = True
    bounds_own_stamps = True

    def __init__(
        self,
        config: GyroConfig,
        name: str = "gyro",
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(name)
        if config.ros2 is None:
            raise ValueError("a ROS 2 gyro needs gyro.ros2")
        self.config, self.ros2 = config, config.ros2
        self.clock, self.wall = clock, wall
        self.domain: int | None = None
        self.reader: Any = None
        self._participant: Any = None
        self._graph: Any = None
        self._heard: float | None = None  # when the last message was taken
        self._joined: float | None = None  # the first read since the topic was joined
        self.no_rate = 0  # messages without an angular velocity (covariance[0] = -1)
        self.frame_id: str | None = None

    def _open(self) -> None:
        from mousedom.config import Ros2Config
        from mousedom.errors import UserError
        from mousedom.service import ros2msgs as msgs
        from mousedom.service.ros2out import domain_id, participant, require

        try:
            require()  # the ros2 extra: said how to install it, as the output says
            from cyclonedds.qos import Policy, Qos
            from cyclonedds.sub import DataReader
            from cyclonedds.topic import Topic

            # its own domain, else as the output's rule says ($ROS_DOMAIN_ID, else 0)
            self.domain = domain_id(Ros2Config(domain_id=self.ros2.domain()))
            part = participant(self.domain, "the gyro's ROS 2 topic")
            qos = Qos(
                Policy.Reliability.BestEffort,
                Policy.Durability.Volatile,
                Policy.History.KeepLast(HISTORY),
            )
            topic = Topic(part, "rt" + self.ros2.topic, msgs.idl_types()[msgs.IMU], qos=qos)
            self.reader = DataReader(part, topic, qos)
            self._participant = part
            from mousedom.service.ros2graph import NodeAnnouncer

            self._graph = NodeAnnouncer(part, GYRO_NODE, self.ros2.namespace or "/")
            self._graph.announce([self.reader], [])
        except UserError as e:  # no cyclonedds, no participant: said as the source's error
            raise SourceUnavailable(f"{self.name}: {self.ros2.topic} ({e})") from None
        self._heard = self._joined = None
        self.answered = False  # (until its first message: Source.answered)
        self._update_health()
        log.info("%s: reading %s (sensor_msgs/Imu) on ROS 2 domain %d", self.name,
                 self.ros2.topic, self.domain)  # fmt: skip

    def fileno(self) -> int:
        return -1

    def identity(self) -> str | None:
        return f"ros2:{self.domain}:{self.ros2.topic}" if self.reader is not None else None

    def close(self) -> None:
        if self._graph is not None:
            from mousedom.service.ros2out import withdraw

            withdraw(self._graph)
        self.reader = None
        self._graph = None
        self._participant = None

    def read(self, now: float) -> list[GyroSamples]:  # type: ignore[override]
        """The messages that came since the last read, as samples (see the module)."""
        if self.reader is None:
            self.health.connected = False
            raise SourceGone(f"{self.name}: {self.ros2.topic}: not open")
        from cyclonedds.internal import InvalidSample

        taken: list[Any] = []
        for _ in range(HISTORY // TAKE):
            got = self.reader.take(N=TAKE)
            taken += [m for m in got if not isinstance(m, InvalidSample)]
            if len(got) < TAKE:
                break
        if not taken:
            if self._heard is None:
                self._joined = now if self._joined is None else self._joined
                if now - self._joined > FIRST_S:
                    self.health.connected = False
                    self.health.error = (
                        f"{self.name}: {self.ros2.topic}: no message in {FIRST_S:g} s since "
                        f"it was joined (is an IMU driver publishing it on domain "
                        f"{self.domain}?)")  # fmt: skip
                    self.close()
                    raise SourceGone(self.health.error)
                return []
            if now - self._heard > SILENT_S:
                self.health.connected = False
                self.health.error = (f"{self.name}: {self.ros2.topic}: no message for "
                                     f"{SILENT_S:g} s (the driver stopped?)")  # fmt: skip
                self.close()
                raise SourceGone(self.health.error)
            return []
        self._heard = now
        self.answered = True
        batch = self._samples(taken, now)
        if batch is None:
            return []
        self._count(len(batch), float(batch.t[-1]), now)
        return [batch]

    def _read(self, now: float) -> list[Reports]:
        raise TypeError(f"{self.name}: a gyro gives GyroSamples: call read()")

    def _samples(self, msgs: list[Any], now: float) -> GyroSamples | None:
        axis, sign = self.config.axis, self.config.sign
        lead = system_lead(self.wall, self.clock) if self.ros2.stamps == "system" else 0.0
        t, rate = [], []
        for m in msgs:
            cov = m.angular_velocity_covariance
            if len(cov) and cov[0] == -1.0:
                self.no_rate += 1
                continue
            r = sign * float(getattr(m.angular_velocity, axis))
            if not abs(r) < MAX_RATE:  # NaN fails this too
                self.health.dropped += 1
                self.health.error = (f"{self.name}: {self.ros2.topic}: an angular velocity "
                                     f"of {r!r} rad/s is no gyro's: dropped")  # fmt: skip
                continue
            st = m.header.stamp
            t.append(int(st.sec) + int(st.nanosec) * 1e-9 - lead)
            rate.append(r)
            self.frame_id = m.header.frame_id
        self._update_health()
        if not t:
            return None
        stamps = self._forward(np.asarray(t, dtype=np.float64), now)
        self.health.extra["time_backwards"] = self.time_backwards
        return GyroSamples(self.name, stamps, np.asarray(rate, dtype=np.float64))

    def _update_health(self) -> None:
        self.health.extra.update(
            topic=self.ros2.topic,
            domain_id=self.domain,
            stamps=self.ros2.stamps,
            frame_id=self.frame_id,
            axis=self.config.axis,
            sign=self.config.sign,
            no_rate=self.no_rate,
            time_backwards=self.time_backwards,
        )
