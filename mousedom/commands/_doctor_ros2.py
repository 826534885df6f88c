"""``mousedom doctor``, the ROS 2 output: can a DDS participant start as the daemon's
does, and, with a daemon running, does its odometry arrive."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from mousedom.commands._doctor_base import PACKAGE, Check, Lines
from mousedom.commands._doctor_daemon import Live
from mousedom.config import Config
from mousedom.errors import UserError

PARTICIPANT_TIMEOUT_S = 5.0  # a DDS participant starts in ~0.2 s; more means it is stuck

# Run in a child process, so that a DDS stack that hangs cannot hang doctor: start a
# participant as the daemon does (its domain, its DDS configuration, Cyclone's own words
# when it fails), then, if asked, count the odometry messages that arrive for a while.
_PARTICIPANT = r"""
import json, sys, time
args = json.loads(sys.argv[1])
def done(**kw):
    print(json.dumps(kw), flush=True)
    sys.exit(0)
try:
    from cyclonedds.core import DDSException
    from cyclonedds.domain import Domain, DomainParticipant
except ImportError as e:
    done(ok=False, missing=True, error=str(e))
from mousedom.service import ros2msgs, ros2out
domain = args["domain"]
error = None
with ros2out._dds_stderr() as said:
    try:
        dds_domain = Domain(domain, ros2out.dds_config())
    except DDSException:
        if "config:" in said():
            error = ros2out._why_no_participant(domain, said())
    if error is None:
        try:
            dp = DomainParticipant(domain)
        except DDSException:
            error = ros2out._why_no_participant(domain, said())
if error is not None:
    done(ok=False, error=error)
received = None
if args["listen"] > 0:
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    topic = Topic(dp, args["topic"], ros2msgs.idl_types()[ros2msgs.ODOMETRY])
    reader = DataReader(dp, topic)
    received = 0
    end = time.monotonic() + args["listen"]
    while time.monotonic() < end:
        received += len(reader.take(N=256))
        time.sleep(0.05)
done(ok=True, received=received)
"""


class Ros2Probe:
    """The ROS 2 check: started before the daemon is read, so that its listening for the
    odometry and the read of the socket take the same second; ``finish`` gives its lines."""

    def __init__(self, cfg: Config | None, listen: float) -> None:
        self.lines = Lines("ros2")
        self.proc: subprocess.Popen[str] | None = None
        if cfg is None:
            return
        if cfg.ros2 is None:
            self.lines.ok("ROS 2 output not configured (outputs.ros2 in the config, or "
                          "`run --ros2`)")  # fmt: skip
            return
        from mousedom.service import ros2conv, ros2out

        o = cfg.ros2
        # optional: the daemon runs on without it, so a problem is a warning
        self.bad = self.lines.warn if o.optional else self.lines.fail
        self.see = f"see {ros2out.DOCS}"
        self.install_hint = ros2out.INSTALL_HINT.split(": ", 1)[-1]
        try:
            self.domain = ros2out.domain_id(o)
        except UserError as e:
            self.bad(str(e), "set ROS_DOMAIN_ID to a number from 0 to 232, or "
                     "outputs.ros2.domain_id")  # fmt: skip
            return
        self.odom, self.listen = ros2conv.topic(o, o.odom_topic), listen
        args = {"domain": self.domain, "topic": "rt" + self.odom, "listen": listen}
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PACKAGE.parent),
                                                          env.get("PYTHONPATH")]))  # fmt: skip
        self.deadline = time.monotonic() + PARTICIPANT_TIMEOUT_S + listen
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _PARTICIPANT, json.dumps(args)],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, env=env,
        )  # fmt: skip

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()

    def finish(self, live: Live | None) -> list[Check]:
        if self.proc is None:
            return self.lines
        try:
            out, err = self.proc.communicate(timeout=max(0.0, self.deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            self.close()
            self.bad(f"no DDS participant on domain {self.domain} within "
                     f"{PARTICIPANT_TIMEOUT_S + self.listen:g} s",
                     f"DDS is stuck (network interfaces? CYCLONEDDS_URI?): {self.see}")  # fmt: skip
            return self.lines
        try:
            result = json.loads(out.strip().splitlines()[-1])
        except (IndexError, ValueError):
            tail = (err.strip().splitlines() or ["no output"])[-1]
            self.bad(f"the DDS check failed: {tail}", self.see)
            return self.lines
        if result.get("missing"):
            self.bad("the ROS 2 output is configured, but cyclonedds is not installed",
                     self.install_hint)  # fmt: skip
            return self.lines
        if not result.get("ok"):
            self.bad(str(result.get("error") or "no DDS participant"), "fix what Cyclone DDS "
                     "names; or let the daemon run without ROS 2: outputs.ros2.optional: "
                     "true")  # fmt: skip
            return self.lines
        self.lines.ok(f"a DDS participant starts on domain {self.domain}", domain=self.domain)
        received, odom = result.get("received"), self.odom
        if received is None or live is None or not live.connected:
            return self.lines  # no daemon to listen to
        if received:
            self.lines.ok(f"{odom}: {received} messages in {self.listen:.1f} s", topic=odom,
                          received=received)  # fmt: skip
        else:
            self.lines.warn(f"{odom}: no message in {self.listen:.1f} s", "does the daemon run "
                            "the ROS 2 output (its log says so at start)? the same "
                            "ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE as this shell?",
                            topic=odom, received=0)  # fmt: skip
        return self.lines
