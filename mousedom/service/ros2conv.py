"""The daemon's windows as ROS 2 messages, as plain data: shared by the DDS output
(``ros2out``) and the MCAP writer (``mcapout``).  Pure: no DDS, no files, no clock.

Conventions (REP-103, REP-105, docs/ros2.md):
- ``nav_msgs/msg/Odometry``: the pose of ``base_frame`` in ``odom_frame`` and the twist in
  ``base_frame`` (the body frame: x forward, y left).  The 3x3 covariances over (x, y, theta)
  go into the row-major 6x6 over (x, y, z, rot x, rot y, rot z) at rows and columns 0, 1
  and 5; what planar odometry does not observe (z, roll, pitch and their rates) gets
  ``UNOBSERVED`` on the diagonal, as robot_localization and Nav2 expect of a 2-D sensor.
- REP-105 continuity: the odom pose never jumps.  The socket's ``reset`` and ``fix`` move
  the daemon's pose; here they move the ``map -> odom`` correction instead (``Rep105``),
  so that map -> odom -> base_link is the fixed pose and odom -> base_link stays smooth.
"""

from __future__ import annotations

import math
from typing import Any

from mousedom.config import Ros2Config
from mousedom.config.names import ros_token
from mousedom.fusion.posebatch import PoseRow

UNOBSERVED = 1e6  # variance of what a planar sensor cannot see (m^2, rad^2 and per s^2)
PLANAR = (0, 1, 5)  # x, y, yaw in ROS's 6x6 (x, y, z, rot x, rot y, rot z)

Pose2 = tuple[float, float, float]
Matrix3 = list[list[float]]


def compose(a: Pose2, b: Pose2) -> Pose2:
    """SE(2) a * b: b expressed in a's frame, made absolute."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def inverse(a: Pose2) -> Pose2:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-(c * a[0] + s * a[1]), s * a[0] - c * a[1], -a[2])


class Rep105:
    """The map -> odom correction M with P = M * O: P is the daemon's pose (which ``reset``
    and ``fix`` move), O the odometry frame's pose of the robot (which never jumps).  Both
    take the same body-frame steps, so M changes only when the daemon's pose is moved.

    O's covariance never collapses either: a reset or fix takes the daemon's uncertainty
    away (its coordinates are given), but O is the same estimate as before, and a filter
    fusing /odom would trust it without limit just after.  What O's covariance was at the
    move is carried along O's path since (J C J^T: J the Jacobian of a pose composed with
    the steps since, ``odom_cov``) and added to the daemon's grown since, turned into the
    odom frame.  After a fix of some coordinates only, what the daemon kept of the others
    counts twice: on the safe side."""

    def __init__(self) -> None:
        self.map_odom: Pose2 = (0.0, 0.0, 0.0)
        self.carried: Matrix3 | None = None  # O's covariance at the last move (odom frame)
        self.carried_at = (0.0, 0.0)  # and O's position then
        self._last: Matrix3 | None = None  # O's covariance as last given (odom_cov)

    def odom_pose(self, pose: Pose2) -> Pose2:
        return compose(inverse(self.map_odom), pose)

    def odom_cov(self, cov3: Any, odom: Pose2) -> Matrix3:
        """O's covariance (odom frame) at ``odom``, the daemon's being ``cov3``."""
        c = turned([[float(v) for v in row] for row in cov3], -self.map_odom[2])
        if self.carried is not None:
            dx, dy = odom[0] - self.carried_at[0], odom[1] - self.carried_at[1]
            j = [[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]]
            k = self.carried
            jk = [[sum(j[a][m] * k[m][b] for m in range(3)) for b in range(3)] for a in range(3)]
            c = [[c[a][b] + sum(jk[a][m] * j[b][m] for m in range(3)) for b in range(3)]
                 for a in range(3)]  # fmt: skip
        self._last = c
        return c

    def moved(self, before: Pose2, after: Pose2) -> None:
        """The daemon's pose was set from ``before`` to ``after`` (reset or fix)."""
        if self._last is not None:
            odom = self.odom_pose(before)
            self.carried, self.carried_at = self._last, (odom[0], odom[1])
        self.map_odom = compose(compose(after, inverse(before)), self.map_odom)


def quaternion(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(0.5 * yaw), "w": math.cos(0.5 * yaw)}


def turned(c: Matrix3, rotate: float) -> Matrix3:
    """A 3x3 covariance over (x, y, yaw) with its x, y block turned by ``rotate``."""
    if not rotate:
        return c
    cr, sr = math.cos(rotate), math.sin(rotate)
    r = [[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]]
    rc = [[sum(r[i][k] * c[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    return [[sum(rc[i][k] * r[j][k] for k in range(3)) for j in range(3)] for i in range(3)]


def covariance6(cov3: Any, rotate: float = 0.0) -> list[float]:
    """A 3x3 covariance over (x, y, yaw) as ROS's row-major 6x6; ``rotate`` turns its
    x, y block by that angle (the odom frame is the daemon's turned by map -> odom)."""
    c = turned([[float(v) for v in row] for row in cov3], rotate)
    out = [0.0] * 36
    for k in (2, 3, 4):
        out[7 * k] = UNOBSERVED
    for a, i in enumerate(PLANAR):
        for b, j in enumerate(PLANAR):
            # A covariance is symmetric: the mean of the two cells, where the maths left
            # them a rounding apart (the estimator's inverse, the turn above), so that a
            # consumer that checks (or factors one triangle) gets one matrix.  NaN is
            # unknown: a variance unobserved, a correlation none (UNOBSERVED off the
            # diagonal would make the matrix indefinite).
            v, w = c[a][b], c[b][a]
            if v != w:
                v = 0.5 * v + 0.5 * w
            out[6 * i + j] = v if v == v else (UNOBSERVED if a == b else 0.0)
    return out


def stamp(t: float, offset: float) -> dict[str, int]:
    """builtin_interfaces/Time of monotonic time t plus ``offset`` (the system clock's lead
    over the monotonic one, or 0), rounded to the nanosecond."""
    ns = max(0, round((t + offset) * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def stamp_ns(t: float, offset: float) -> int:
    return max(0, round((t + offset) * 1e9))


def header(frame: str, st: dict[str, int]) -> dict[str, Any]:
    return {"stamp": st, "frame_id": frame}


def topic(cfg: Ros2Config, name: str) -> str:
    """A topic under the namespace: /odom -> /robot1/odom."""
    name = name if name.startswith("/") else "/" + name
    return (cfg.namespace or "") + name


def odometry(
    cfg: Ros2Config, st: dict[str, int], odom: Pose2, pose_cov: Any, row: PoseRow, rate: float
) -> dict[str, Any]:
    """nav_msgs/msg/Odometry of one window: ``odom`` its pose in the odom frame,
    ``pose_cov`` that pose's 3x3 covariance (odom frame: Rep105.odom_cov), or an angle:
    the row's own turned by it (the odom frame's turn from the daemon's, as before the
    odom covariance was carried), ``row`` the window (a PoseRow), ``rate`` windows per
    second (the twist covariance is q's times rate^2)."""
    if isinstance(pose_cov, (int, float)):
        pose_cov = turned([[float(v) for v in r] for r in row.cov], float(pose_cov))
    r2 = rate * rate
    qcov = [[float(v) * r2 for v in line] for line in row.qcov]
    if not row.ok:
        # the live mice could not tell the motion: the twist (given as 0) is unknown
        qcov = [[UNOBSERVED if i == j else 0.0 for j in range(3)] for i in range(3)]
    elif qcov[1][1] == 0.0 and qcov[0][0] > 0.0:
        # diff-drive: no sideways slip is the model's assumption, not a measurement; an
        # EKF given a variance of 0 would trust it without limit (and may go singular)
        qcov[1][1] = qcov[0][0]
    return {
        "header": header(cfg.odom_frame, st),
        "child_frame_id": cfg.base_frame,
        "pose": {
            "pose": {
                "position": {"x": odom[0], "y": odom[1], "z": 0.0},
                "orientation": quaternion(odom[2]),
            },
            "covariance": covariance6(pose_cov),
        },
        "twist": {
            "twist": {
                "linear": {"x": float(row.vx), "y": float(row.vy), "z": 0.0},
                "angular": {"x": 0.0, "y": 0.0, "z": float(row.omega)},
            },
            "covariance": covariance6(qcov),
        },
    }


def transform(parent: str, child: str, st: dict[str, int], pose: Pose2) -> dict[str, Any]:
    """geometry_msgs/msg/TransformStamped: ``child``'s pose in ``parent``."""
    return {
        "header": header(parent, st),
        "child_frame_id": child,
        "transform": {
            "translation": {"x": pose[0], "y": pose[1], "z": 0.0},
            "rotation": quaternion(pose[2]),
        },
    }


def counts_topic(name: str) -> str:
    """A mouse's counts topic, named by its ROS 2 token (config.names.ros_token)."""
    return f"/mousedom/{ros_token(name)}/counts"


def mouse_frame(name: str, base_frame: str = "") -> str:
    """The TF frame of a mouse's sensor (on /tf_static under the base frame), named as
    its counts topic is (config.names.ros_token), after the base frame's prefix: with
    ``robot1/base_link`` it is ``robot1/front_mouse``, so that robots sharing /tf (docs/
    ros2.md, "Several robots") keep their mice apart as they keep their bases."""
    prefix = base_frame.rpartition("/")[0]
    return f"{prefix}/{ros_token(name)}_mouse" if prefix else f"{ros_token(name)}_mouse"


def mount_transform(
    base: str, name: str, x: float, y: float, yaw: float, flip: bool, st: dict[str, int]
) -> dict[str, Any]:
    """A mouse's mount as a static transform base -> its frame: x forward toward the
    mouse's buttons, y to its left, z up; a mirrored sensor (``flip``) is the same mouse
    turned upside down, a half turn about its x axis (its y and z reversed)."""
    return {
        "header": header(base, st),
        "child_frame_id": mouse_frame(name, base),
        "transform": {
            "translation": {"x": x, "y": y, "z": 0.0},
            "rotation": mount_rotation(yaw, flip),
        },
    }


def mount_rotation(yaw: float, flip: bool) -> dict[str, float]:
    """A mouse's orientation on the body: its yaw, and for a mirrored sensor (``flip``)
    then a half turn about its x axis, (w, x, y, z) = (0, cos(yaw/2), sin(yaw/2), 0)."""
    if flip:
        return {"x": math.cos(0.5 * yaw), "y": math.sin(0.5 * yaw), "z": 0.0, "w": 0.0}
    return quaternion(yaw)


# diagnostic_msgs/msg/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3
# late: healthy, its counts held up (a USB host's stall); they are added back on arrival
_LEVEL = {"tracking": OK, "late": OK, "suspect": WARN, "excluded": ERROR, "missing": ERROR,
          "gone": ERROR}  # fmt: skip


def diagnostics(st: dict[str, int], sources: list[dict[str, Any]]) -> dict[str, Any]:
    """diagnostic_msgs/msg/DiagnosticArray: one status per sensor from its SOURCE message
    (the fault-tolerant fusion's state and reason, whether it is connected, its rate, its
    learnt scale).  A scale warning (10 % or more off the others: a wrong CPI) makes a
    tracking sensor's level WARN, its text the message."""
    statuses = []
    for s in sources:
        state = s.get("state") or ("tracking" if s.get("live") else "gone")
        if not s.get("connected"):
            state = "gone"
        why = s.get("reason") or s.get("error") or ""
        values = {
            "state": state,
            "reason": why,
            "reports per second": f"{s.get('rate_hz') or 0.0:.1f}",
            "residual (m per window)": "" if s.get("residual") is None else f"{s['residual']:.3g}",
            "kind": str(s.get("kind", "")),
            # the learnt scale ("": none learnt): the factor the sensor's counts need
            "scale": _number(s.get("scale"), ".6f"),
            "scale_spread": _number(s.get("scale_spread"), ".6f"),
            "scale_applied": "true" if s.get("scale_applied") else "false",
        }
        if "squal" in s:
            values["SQUAL"] = str(s["squal"])
        level = _LEVEL.get(state, WARN)
        message = state + (f" ({why})" if why else "")
        warning = s.get("scale_warning")
        if warning:
            level = max(level, WARN)
            message = warning if level == WARN and not why else f"{message}; {warning}"
        statuses.append({
            "level": level,
            "name": f"mousedom: {s.get('name', '?')}",
            "message": message,
            "hardware_id": str(s.get("node") or s.get("port") or s.get("name", "")),
            "values": [{"key": k, "value": v} for k, v in values.items()],
        })  # fmt: skip
    return {"header": header("", st), "status": statuses}


def _number(v: Any, fmt: str) -> str:
    return "" if v is None else format(float(v), fmt)


def counts(
    st: dict[str, int], mouse: str, cx: float, cy: float, base_frame: str = ""
) -> dict[str, Any]:
    """geometry_msgs/msg/Vector3Stamped: one mouse's counts (REL_X, REL_Y) in a window,
    ``frame_id`` its frame (``mouse_frame``, which /tf_static places on the robot)."""
    return {"header": header(mouse_frame(mouse, base_frame), st),
            "vector": {"x": float(cx), "y": float(cy), "z": 0.0}}  # fmt: skip
