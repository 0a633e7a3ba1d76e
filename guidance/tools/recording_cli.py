"""``guidance recording repair IN OUT``: a damaged or cut-short recording made readable by any
MCAP tool (``guidance.recording.repair``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from guidance.recording.repair import damage_text, repair


def register(sub: Any) -> None:
    p = sub.add_parser(
        "recording", help="recording files: repair one cut short by a crash, export to ROS 2"
    )
    verbs = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    r = verbs.add_parser(
        "repair",
        help="write a complete MCAP file from a damaged or cut-short one",
        description=(
            "Read IN as `guidance replay` does (chunk CRCs checked, damage skipped) and write "
            "every complete message, channel, schema and metadata into OUT, a finished MCAP "
            "file the standard mcap reader, Foxglove and other tools open. IN is not changed."
        ),
    )
    r.add_argument("input", type=Path, metavar="IN", help="the damaged recording (.mcap)")
    r.add_argument("output", type=Path, metavar="OUT", help="the repaired copy (a new file)")
    r.set_defaults(func=_cli_repair)
    e = verbs.add_parser(
        "ros2",
        help="export a recording as a rosbag2 (MCAP) of ROS 2 messages",
        description=(
            "Write OUT_DIR, a rosbag2 folder (MCAP storage) that ROS 2 tools and rosbags read: "
            "the recorded states as nav_msgs/Odometry, PoseWithCovarianceStamped and "
            "NavSatFix under /guidance, landmark matches as PoseWithCovarianceStamped "
            "(docs/telemetry.md, For ROS 2 users)."
        ),
    )
    e.add_argument("input", type=Path, metavar="IN", help="the recording (.mcap or its folder)")
    e.add_argument("output", type=Path, metavar="OUT_DIR", help="the rosbag2 folder (new)")
    e.set_defaults(func=_cli_ros2)


def _cli_ros2(args: argparse.Namespace) -> int:
    from guidance.telemetry.ros2_export import export_rosbag2

    res = export_rosbag2(args.input, args.output)
    counts = ", ".join(f"{n} on {t}" for t, n in sorted(res.messages.items())) or "no messages"
    sys.stdout.write(f"wrote {args.output}: {counts}\n")
    return 0


def _cli_repair(args: argparse.Namespace) -> int:
    res = repair(args.input, args.output)
    lost = damage_text(res.damage)
    if res.orphans:
        lost = ", ".join(filter(None, [lost, f"{res.orphans} messages of lost channels"]))
    sys.stdout.write(
        f"wrote {args.output}: {res.messages} messages on {res.channels} channels"
        f" (left behind: {lost or 'nothing'})\n"
    )
    return 0
