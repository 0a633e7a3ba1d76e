"""``guidance odometry`` and ``guidance compass``: replay recorded device data through the drivers.

Both run the same decoder / parser the car uses, so a log that decodes here decodes live. Heavy
imports (python-can, cantools, pynmea2) happen inside the commands, not at ``guidance`` start.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    odo = sub.add_parser(
        "odometry",
        help="replay a recorded CAN log through the wheel-odometry decoder",
        description=(
            "Decode the wheel speeds of a recorded CAN log (candump -L .log, .asc, .blf, .trc, "
            ".csv, .db, .mf4; optionally .gz) with a vehicle profile and integrate the distance."
        ),
    )
    odo.add_argument("logfile", type=Path, help="the CAN log")
    odo.add_argument(
        "--profile",
        required=True,
        help="vehicle profile (guidance profiles lists them), or auto: the car from the CAN "
        "ids in the log, or no answer (exit 2) when it is unknown or ambiguous",
    )
    odo.add_argument(
        "--max-gap",
        type=float,
        default=None,
        metavar="S",
        help="longest silence (s) still integrated across (default 1.0)",
    )
    odo.add_argument("--json", action="store_true", help="print one JSON object")
    odo.set_defaults(func=_odometry)

    prof = sub.add_parser(
        "profiles",
        help="list the vehicle profiles (cars whose wheel speeds the CAN driver reads)",
        description=(
            "The vehicle profiles: one per opendbc DBC an opendbc car platform uses for its "
            "powertrain bus, with the make, the wheel-speed and yaw-rate messages and the "
            "platforms. docs/drivers.md: Adding your car."
        ),
    )
    prof.add_argument("--json", action="store_true", help="one JSON array, one object per profile")
    prof.set_defaults(func=_profiles)

    comp = sub.add_parser(
        "compass",
        help="parse a recorded NMEA capture through the compass parser",
        description=(
            "Parse an NMEA 0183 capture (HDG/HDM/HDT headings; everything else is counted and "
            "skipped) and print heading statistics. Lines starting with '#' are comments."
        ),
    )
    comp.add_argument("logfile", type=Path, help="the NMEA capture")
    comp.add_argument(
        "--allow-missing-checksum",
        action="store_true",
        help="accept sentences that carry no *hh checksum",
    )
    comp.add_argument("--json", action="store_true", help="print one JSON object")
    comp.set_defaults(func=_compass)


def _json_safe(value: Any) -> Any:
    """JSON without NaN/Infinity (not valid JSON): non-finite floats become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def _reasons(by_reason: dict[str, int]) -> str:
    parts = [f"{k} {v}" for k, v in by_reason.items() if v]
    return f" ({', '.join(parts)})" if parts else ""


def _odometry(args: argparse.Namespace) -> int:
    from drivers.can_odometry import MAX_GAP_S, replay_log
    from guidance.errors import UserError

    max_gap = MAX_GAP_S if args.max_gap is None else args.max_gap
    if not (math.isfinite(max_gap) and max_gap > 0):
        raise UserError("--max-gap must be a positive number of seconds")
    summary = replay_log(args.logfile, args.profile, max_gap_s=max_gap)
    if args.json:
        print(json.dumps(_json_safe(summary.to_json())))
        return 0
    s = summary
    print(f"log:         {s.log}")
    print(f"profile:     {s.profile}")
    if s.profile_reason:
        print(f"chosen:      {s.profile_reason}")
    print(f"frames:      {s.frames} read, {s.ignored} not wheel speeds")
    if s.unreadable:
        print(f"unreadable:  {s.unreadable} records{'; ' + s.read_error if s.read_error else ''}")
    print(f"decoded:     {s.decoded} wheel-speed frames -> {s.increments} increments")
    print(f"rejected:    {s.rejected}{_reasons(s.rejected_by_reason)}")
    if s.front_fallback:
        print(f"fallback:    {s.front_fallback} increments from the front wheels (rears read 0)")
    print(
        f"duration:    {s.duration_s:.2f} s ({s.integrated_s:.2f} s integrated, "
        f"{s.gap_s:.2f} s in gaps > {max_gap:g} s)"
    )
    print(
        f"distance:    {s.distance_m:.2f} m (left {s.left_m:.2f} m, right {s.right_m:.2f} m; "
        f"top speed {s.max_speed_mps * 3.6:.1f} km/h)"
    )
    return 0


def profile_entries() -> list[dict[str, Any]]:
    """``guidance profiles --json``: one object per profile."""
    from drivers.opendbc_dbc import opendbc_platforms
    from drivers.profiles import PROFILES

    platforms = opendbc_platforms()
    out = []
    for name, p in sorted(PROFILES.items()):
        yaw = p.yaw_rate
        out.append({
            "name": name,
            "brand": p.brand,
            "vehicle": p.vehicle,
            "dbc": p.dbc_file,
            "rear": {"frame_id": p.rear.frame_id, "left": p.rear.left, "right": p.rear.right},
            "front": {"frame_id": p.front.frame_id, "left": p.front.left, "right": p.front.right},
            "speed_resolution_kph": p.speed_resolution_kph,
            "track_width_m": p.track_width_m,
            "yaw_rate": None if yaw is None else {
                "frame_id": yaw.frame_id, "message": yaw.message, "signal": yaw.signal,
                "unit": yaw.unit,
            },
            "platforms": [name for _brand, name in platforms.get(p.dbc_file, ())],
        })  # fmt: skip
    return out


def _profiles(args: argparse.Namespace) -> int:
    entries = profile_entries()
    if args.json:
        print(json.dumps(entries))
        return 0
    for e in entries:
        yaw = e["yaw_rate"]
        yaw_text = f"; yaw rate {yaw['message']}.{yaw['signal']}" if yaw else ""
        print(
            f"{e['name']:<34} {e['brand']:<11} wheels 0x{e['rear']['frame_id']:X}"
            f"{yaw_text}; {len(e['platforms'])} opendbc platforms ({e['vehicle']})"
        )
    brands = sorted({e["brand"] for e in entries})
    print(f"{len(entries)} profiles, {len(brands)} makes: {', '.join(brands)}")
    return 0


def _compass(args: argparse.Namespace) -> int:
    from drivers.compass import parse_capture

    summary = parse_capture(args.logfile, allow_missing_checksum=args.allow_missing_checksum)
    if args.json:
        print(json.dumps(_json_safe(summary.to_json())))
        return 0
    s = summary
    print(f"file:        {s.file}")
    print(f"lines:       {s.lines} ({s.comments} comment lines not counted)")
    kinds = ", ".join(f"{k} {v}" for k, v in sorted(s.by_type.items()))
    print(
        f"headings:    {s.headings} accepted ({s.magnetic_headings} magnetic, "
        f"{s.true_headings} true){'; sentences seen: ' + kinds if kinds else ''}"
    )
    print(f"rejected:    {s.rejected}{_reasons(s.rejected_by_reason)}")
    if s.stats is None:
        print("statistics:  no headings")
    else:
        st = s.stats
        std = "n/a" if not math.isfinite(st["std_deg"]) else f"{st['std_deg']:.2f}"
        print(
            f"statistics:  circular mean {st['mean_deg']:.2f} deg, circular std {std} deg, "
            f"min {st['min_deg']:.2f}, max {st['max_deg']:.2f}"
        )
    return 0
