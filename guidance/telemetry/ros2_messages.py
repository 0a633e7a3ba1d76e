"""The car's messages as ROS 2 messages (CDR, by ``rosbags``), for the ROS 2 sink and the
rosbag2 export (one definition of the conversion).

Frames (REP-103, REP-105): the estimate is in ``map`` (x east, y north, z up; the car's local
frame, its origin the start), the car is ``base_link``; yaw is counter-clockwise from east,
as the state's ``heading_rad``. Covariances are row-major 6x6 over (x, y, z, roll, pitch,
yaw): the filter's 3x3 (x, y, heading) goes to (x, y, yaw); z, roll and pitch are not
estimated, so they carry ``UNKNOWN_VARIANCE`` (a planar car: a robot_localization user sets
``two_d_mode``). Twist is in ``base_link``: forward speed from the wheel speeds; the state
carries no yaw rate, so angular z is 0 with ``UNKNOWN_VARIANCE``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

UNKNOWN_VARIANCE = 1.0e6
"""Variance of what the car does not estimate (m^2, rad^2)."""
SPEED_VARIANCE = 0.1**2
"""Forward speed variance (m/s)^2: the wheel-speed quantisation and tyre scale at city speed."""
FRAME_MAP = "map"
FRAME_CAR = "base_link"
TYPES = {
    "odometry": "nav_msgs/msg/Odometry",
    "pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "fix": "sensor_msgs/msg/NavSatFix",
    "landmark_fix": "geometry_msgs/msg/PoseWithCovarianceStamped",
}
"""Topic (under the sink's namespace) -> ROS 2 message type."""


@functools.cache
def typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def dds_type_name(msgtype: str) -> str:
    """``nav_msgs/msg/Odometry`` -> ``nav_msgs::msg::dds_::Odometry_`` (the rmw_zenoh key)."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def type_hash(msgtype: str) -> str:
    """The type's RIHS01 hash (REP-2016), as rosidl makes it (``rosbags``)."""
    return str(typestore().hash_rihs01(msgtype))


def _stamp(t_unix_s: float) -> Any:
    time_cls = typestore().types["builtin_interfaces/msg/Time"]
    sec = math.floor(t_unix_s)
    return time_cls(sec=int(sec), nanosec=round((t_unix_s - sec) * 1e9) % 1_000_000_000)


def _header(t_unix_s: float, frame: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=_stamp(t_unix_s), frame_id=frame)


def _pose_cov(cov3: Sequence[Sequence[float]]) -> Any:
    import numpy as np

    out = np.zeros(36)
    for i in (2, 3, 4):
        out[i * 6 + i] = UNKNOWN_VARIANCE
    index = (0, 1, 5)  # x, y, yaw
    for r in range(3):
        for c in range(3):
            out[index[r] * 6 + index[c]] = float(cov3[r][c])
    return out


def _pose(x: float, y: float, yaw: float, cov3: Sequence[Sequence[float]]) -> Any:
    t = typestore().types
    q = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=q
    )
    return t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=_pose_cov(cov3))


def state_to_ros(state: Mapping[str, Any]) -> dict[str, Any]:
    """A ``guidance.state`` message as {topic: ROS 2 message} (odometry, pose, fix); a state
    without a finite position gives none."""
    import numpy as np

    t = typestore().types
    x, y, yaw = state.get("x_m"), state.get("y_m"), state.get("heading_rad")
    cov = state.get("covariance")
    if not all(isinstance(v, int | float) and math.isfinite(v) for v in (x, y, yaw)) or not cov:
        return {}
    when = float(state.get("wall_time_unix_s") or 0.0)
    pose = _pose(float(x), float(y), float(yaw), cov)  # type: ignore[arg-type]
    speed = state.get("speed_mps")
    twist_cov = np.zeros(36)
    for i in range(6):
        twist_cov[i * 6 + i] = UNKNOWN_VARIANCE
    twist_cov[0] = SPEED_VARIANCE
    linear = t["geometry_msgs/msg/Vector3"](
        x=float(speed) if isinstance(speed, int | float) else 0.0, y=0.0, z=0.0
    )
    twist = t["geometry_msgs/msg/Twist"](linear=linear, angular=t["geometry_msgs/msg/Vector3"](
        x=0.0, y=0.0, z=0.0))  # fmt: skip
    out: dict[str, Any] = {
        "odometry": t["nav_msgs/msg/Odometry"](
            header=_header(when, FRAME_MAP),
            child_frame_id=FRAME_CAR,
            pose=pose,
            twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=twist_cov),
        ),
        "pose": t["geometry_msgs/msg/PoseWithCovarianceStamped"](
            header=_header(when, FRAME_MAP), pose=pose
        ),
    }
    lat, lon = state.get("lat_deg"), state.get("lon_deg")
    if isinstance(lat, int | float) and isinstance(lon, int | float):
        enu = np.zeros(9)  # east, north, up (REP-145), m^2
        enu[0], enu[1], enu[3], enu[4] = cov[0][0], cov[0][1], cov[1][0], cov[1][1]
        enu[8] = UNKNOWN_VARIANCE
        status = t["sensor_msgs/msg/NavSatStatus"](status=0, service=0)
        out["fix"] = t["sensor_msgs/msg/NavSatFix"](
            header=_header(when, FRAME_CAR), status=status, latitude=float(lat),
            longitude=float(lon), altitude=float("nan"), position_covariance=enu,
            position_covariance_type=3,  # COVARIANCE_TYPE_KNOWN
        )  # fmt: skip
    return out


def landmark_to_ros(message: Mapping[str, Any]) -> list[Any]:
    """The verified matches of a ``guidance.landmark`` message as PoseWithCovarianceStamped
    (the landmark's surveyed position, its sigma as an isotropic variance; the orientation
    is unknown). The verification evidence stays in the JSON message beside it."""
    t = typestore().types
    when = float(message.get("wall_time_unix_s") or 0.0)
    out = []
    for m in message.get("matches") or []:
        x, y, sigma = m.get("x_m"), m.get("y_m"), m.get("sigma_m")
        if not all(isinstance(v, int | float) and math.isfinite(v) for v in (x, y, sigma)):
            continue
        var = float(sigma) ** 2
        cov = [[var, 0.0, 0.0], [0.0, var, 0.0], [0.0, 0.0, UNKNOWN_VARIANCE]]
        out.append(
            t["geometry_msgs/msg/PoseWithCovarianceStamped"](
                header=_header(when, FRAME_MAP), pose=_pose(float(x), float(y), 0.0, cov)
            )
        )
    return out


def serialize(message: Any) -> bytes:
    """CDR with its 4-byte encapsulation header (what rmw_zenoh puts on the wire)."""
    return bytes(typestore().serialize_cdr(message, message.__msgtype__))
