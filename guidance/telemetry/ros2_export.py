"""``guidance recording ros2 IN.mcap OUT_DIR``: a drive recording as a rosbag2 (MCAP storage)
that ROS 2 tools and ``rosbags`` read: the recorded states as ``nav_msgs/Odometry``,
``PoseWithCovarianceStamped`` and ``NavSatFix``, landmark matches as
``PoseWithCovarianceStamped``, the same conversion the live sink uses (``ros2_messages``),
stamped with the recording's log times."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from guidance.errors import UserError
from guidance.telemetry.ros2_messages import TYPES, landmark_to_ros, state_to_ros, typestore

NAMESPACE = "/guidance"


@dataclass
class ExportResult:
    messages: dict[str, int] = field(default_factory=dict)
    """Per ROS 2 topic, the messages written."""
    skipped: int = 0
    """Recorded states without a position (nothing to say in ROS 2)."""


def export_rosbag2(source: Path, out_dir: Path) -> ExportResult:
    """Write ``out_dir`` (a new rosbag2 folder) from the recording ``source``."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from guidance.recording.reader import Reader

    if out_dir.exists():
        raise UserError(f"{out_dir} exists: rosbag2 writes a new folder")
    reader = Reader(source, topics=("/state", "/landmark"))
    ts = typestore()
    result = ExportResult()
    with Writer(out_dir, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        conns: dict[str, Any] = {}

        def write(topic: str, ros: Any, t_ns: int) -> None:
            name = f"{NAMESPACE}/{topic}"
            if name not in conns:
                conns[name] = writer.add_connection(name, TYPES[topic], typestore=ts)
            writer.write(conns[name], t_ns, ts.serialize_cdr(ros, ros.__msgtype__))
            result.messages[name] = result.messages.get(name, 0) + 1

        for rec in reader:
            t_ns = round(rec.t_s * 1e9)
            if rec.topic == "/state":
                items = list(state_to_ros(rec.data).items())
                if not items:
                    result.skipped += 1
            else:
                items = [("landmark_fix", m) for m in landmark_to_ros(rec.data)]
            for topic, ros in items:
                write(topic, ros, t_ns)
    return result
