"""``guidance replay``: recorded inputs through the same pipeline (issue 6, docs/app.md).

Two kinds of input:

* an MCAP recording made by ``guidance run`` or ``guidance sim`` (``guidance.recording``):
  its ``/session`` record rebuilds the ``PipelineConfig``, and its input topics
  (``/odometry``, ``/compass``, ``/heading``, ``/landmark_fix``, ``/scene``, ``/goal``) are
  fed to a fresh ``Pipeline`` in the order the app processed them. Because the pipeline is
  pure and the recorded floats round-trip exactly through JSON, the replay reproduces the
  recorded estimates and decisions bit for bit; ``compare_with_recording`` checks that;
* raw logs from elsewhere: a CAN log (candump ``.log``, ``.asc``, ``.blf``... through
  python-can's readers and the car's decoders, ``replay_can``: the wheel speeds and, on a car
  whose ``[vehicle] yaw_source`` is "gyro" or "both", the yaw rate) and optionally an NMEA text file
  (each line optionally prefixed by its time in seconds; otherwise spread at ``--nmea-rate``
  from the start of the CAN log), merged by time. Start, goal and method come from
  ``--config`` (the car's TOML) or sensible defaults. With no ``[goal]`` (and with no
  ``--config``) the pipeline has no goal: it publishes the estimate, its health and the
  warnings, and makes no decision, no chance and no arrival.

``--speed X`` paces the replay at X times the recorded rate; by default it runs flat out.
"""

from __future__ import annotations

import argparse
import datetime as dt
import heapq
import json
import math
import re
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from guidance import files
from guidance.core.messages import CompassHeading, WheelOdometry
from guidance.errors import UserError
from guidance.tools.odometry_csv import first_time, is_odometry_csv, odometry_inputs
from guidance.tools.replay_can import can_log_inputs
from guidance.tools.replay_mcap import (
    PROCESSED_TOPICS,
    RAW_TOPICS,
    mcap_inputs,
    message_from_record,
    recorded_outputs,
)
from guidance.tools.replay_session import pipeline_config_from_session, recording_sessions
from guidance.tools.track import TrackWriter

if TYPE_CHECKING:  # the estimator stack (filterpy, scipy, numba) loads on first use only
    from guidance.core.pipeline import Input, Outputs, Pipeline, PipelineConfig

__all__ = [
    "PROCESSED_TOPICS",
    "RAW_TOPICS",
    "mcap_inputs",
    "message_from_record",
    "pipeline_config_from_session",
    "recorded_outputs",
    "recording_sessions",
]

DEFAULT_PROFILE = "gm_global_a"

# ----------------------------------------------------------------------------- raw logs


_STAMPED = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?)[\s,;]+(.*)$")
"""A time stamp before an NMEA line: ASCII digits only (``float()`` takes ``1_0_0``)."""


def nmea_inputs(path: Path, start_s: float, rate_hz: float) -> Iterator[CompassHeading]:
    """Headings of an NMEA text file; a leading number on a line is its time (s)."""
    from drivers.compass import NmeaCompassParser

    parser = NmeaCompassParser()
    t = start_s
    with files.opened(path, "nmea_log") as f:
        for raw in files.text_lines(f, files.MAX_NMEA_LINE_BYTES):
            text = raw.rstrip(b"\r\n").decode("ascii", errors="replace")
            m = _STAMPED.match(text)
            if m:
                t_line, body = float(m.group(1)), m.group(2)
            else:
                t_line, body = t, text
                t += 1.0 / rate_hz
            out = parser.feed_line(body.encode("ascii", errors="replace"), t_line)
            if out is not None:
                yield out


def can_inputs(path: Path, profile: str) -> Iterator[WheelOdometry]:
    """Wheel odometry of a CAN log through the car's decoder (python-can readers)."""
    for out in can_log_inputs(path, profile, yaw_rate=False):
        assert isinstance(out, WheelOdometry)  # no yaw-rate decoder: increments only
        yield out


def _first_can_time(path: Path) -> float:
    """The first time of a CAN log, or of a speed and yaw-rate CSV (``odometry_csv``)."""
    from drivers.can_odometry import LogReadResult, read_can_log

    if is_odometry_csv(path):
        return first_time(path)

    for msg in read_can_log(path, LogReadResult()):
        return float(msg.timestamp)
    return 0.0


# ----------------------------------------------------------------------------- running


@dataclass
class ReplayResult:
    inputs: int = 0
    decisions: list[dict[str, Any]] = field(default_factory=list)
    prompts: list[tuple[float, str]] = field(default_factory=list)
    states: list[dict[str, Any]] = field(default_factory=list)
    first_t_s: float | None = None
    last_t_s: float | None = None
    odometer_m: float = 0.0
    final: dict[str, Any] = field(default_factory=dict)
    landmark_updates: int = 0

    def expected(self) -> dict[str, Any]:
        """The outputs a regression test compares (decisions, prompts, sampled states)."""
        return {
            "inputs": self.inputs,
            "decisions": self.decisions,
            "prompts": [list(p) for p in self.prompts],
            "states": self.states[::10],
            "final": self.final,
        }


def replay(
    pipeline: Pipeline,
    inputs: Iterable[Input],
    *,
    speed: float | None = None,
    on_output: Callable[[Input, Outputs], None] | None = None,
) -> ReplayResult:
    """Feed ``inputs`` to ``pipeline``; collect decisions, prompts and published states."""
    res = ReplayResult()
    wall0 = time.monotonic()
    for msg in inputs:
        if res.first_t_s is None:
            res.first_t_s = msg.t_s
        if speed is not None:
            ahead = (msg.t_s - res.first_t_s) / speed - (time.monotonic() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        out = pipeline.feed(msg)
        res.inputs += 1
        res.last_t_s = msg.t_s
        for d in out.decisions:
            res.decisions.append(
                {
                    "t_s": d.t_s,
                    "exit_index": d.exit_index,
                    "intersection_id": d.intersection_id,
                    "exit_heading_rad": d.exit_heading_rad,
                    "turn_rad": d.turn_rad,
                    "target_kind": d.target_kind,
                    "revisit": d.revisit,
                }
            )
        for p in out.prompts:
            res.prompts.append((p.t_s, p.text))
        if out.state is not None:
            s = out.state
            res.states.append(
                {
                    "t_s": s.t_s,
                    "x_m": s.x_m,
                    "y_m": s.y_m,
                    "heading_rad": s.heading_rad,
                    "major_axis_m": s.ellipse.major_axis_m,
                }
            )
        if on_output is not None:
            on_output(msg, out)
    st = pipeline.state()
    res.odometer_m = pipeline.estimate.odometer_m
    res.landmark_updates = pipeline.landmark_updates
    res.final = {
        "t_s": st.t_s,
        "x_m": st.x_m,
        "y_m": st.y_m,
        "heading_rad": st.heading_rad,
        "major_axis_m": st.ellipse.major_axis_m,
        "odometer_m": pipeline.estimate.odometer_m,
        "arrived": pipeline.arrived,
        "lost": st.lost,
    }
    return res


def compare_with_recording(
    res: ReplayResult, recorded: Mapping[str, list[dict[str, Any]]]
) -> list[str]:
    """Differences between the replay and what the live run recorded (empty: identical)."""
    problems = []
    rec_d = recorded.get("/decision", [])
    if len(rec_d) != len(res.decisions):
        problems.append(f"{len(res.decisions)} decisions replayed, {len(rec_d)} recorded")
    for i, (a, b) in enumerate(zip(res.decisions, rec_d, strict=False)):
        if (a["t_s"], a["exit_index"], a["intersection_id"], a["exit_heading_rad"]) != (
            b["t_s"],
            b["exit_index"],
            b["intersection_id"],
            b["exit_heading_rad"],
        ):
            problems.append(f"decision {i} differs: replay {a} recorded {b}")
    rec_s = recorded.get("/state", [])
    if len(rec_s) != len(res.states):
        problems.append(f"{len(res.states)} states replayed, {len(rec_s)} recorded")
    for i, (a, b) in enumerate(zip(res.states, rec_s, strict=False)):
        if (a["t_s"], a["x_m"], a["y_m"], a["heading_rad"]) != (
            b["t_s"],
            b["x_m"],
            b["y_m"],
            b["heading_rad"],
        ):
            problems.append(f"state {i} at t={a['t_s']} differs")
            break
    return problems


@dataclass(frozen=True)
class RawSetup:
    """What a car TOML gives a raw-log replay: the pipeline and the CAN profile."""

    pipeline: PipelineConfig
    profile: str
    notes: tuple[str, ...] = ()


def _log_date(path: Path) -> dt.date | None:
    """The date of a log whose times are Unix seconds (for the declination), else None."""
    t = _first_can_time(path)
    if t > 1e9:  # after 2001-09-09: a Unix time, not a monotonic clock
        return dt.datetime.fromtimestamp(t, dt.UTC).date()
    return None


def raw_setup(
    config: str | None, profile: str | None, start_heading_deg: float | None, log: Path
) -> RawSetup:
    """Pipeline and profile for raw logs: everything in the config, the CLI flags on top."""
    if config:
        from guidance.app.config import load_config

        date = _log_date(log)
        cfg = load_config(config, require_goal=False, default_date=date)
        pcfg = cfg.pipeline
        cfg_profile = getattr(cfg.odometry.config, "profile", None) if cfg.odometry else None
        if start_heading_deg is not None:
            pcfg = replace(pcfg, start_heading_rad=math.radians(90.0 - start_heading_deg))
        notes = (f"declination {pcfg.declination_deg:+.2f} deg for {date}",) if date else ()
        if pcfg.goal_xy_m is None:  # no [goal]: the estimate, its health and warnings only
            pcfg = replace(pcfg, stop_at_arrival=False)  # being lost does not end the replay
        return RawSetup(pcfg, profile or cfg_profile or DEFAULT_PROFILE, notes)
    note = "no --config: no declination, no calibration, the paper's noise model"
    return RawSetup(_default_pipeline(start_heading_deg), profile or DEFAULT_PROFILE, (note,))


def _default_pipeline(start_heading_deg: float | None) -> PipelineConfig:
    from guidance.core.localize.estimator import EstimatorConfig
    from guidance.core.pipeline import PipelineConfig
    from guidance.core.plan.navigator import NavigatorConfig

    return PipelineConfig(
        estimator=EstimatorConfig(),
        navigator=NavigatorConfig(),
        start_xy_m=(0.0, 0.0),
        start_heading_rad=(
            None if start_heading_deg is None else math.radians(90.0 - start_heading_deg)
        ),
    )


# ----------------------------------------------------------------------------- CLI


def register(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="run a recording (MCAP) or raw CAN/NMEA logs through the pipeline",
        description=(
            "Replay an MCAP recording of guidance run/sim through the same pipeline (the "
            "estimates and decisions are reproduced exactly and compared with the recorded "
            "ones), or raw logs: a CAN log (candump .log, .asc, .blf via python-can) and/or "
            "an NMEA text file."
        ),
    )
    p.add_argument(
        "file",
        type=Path,
        help="an .mcap recording (or folder), a CAN log, or a speed and yaw-rate CSV "
        "(t,speed_mps,yaw_rate_rad_s)",
    )
    p.add_argument("--nmea", type=Path, default=None, help="an NMEA compass capture to merge")
    p.add_argument(
        "--profile",
        default=None,
        help=f"vehicle profile for a CAN log (default: the config's, else {DEFAULT_PROFILE})",
    )
    p.add_argument(
        "--config",
        default=None,
        help="car TOML for raw logs: profile, start, declination, compass calibration, model",
    )
    p.add_argument(
        "--track",
        type=Path,
        default=None,
        metavar="FILE.csv",
        help="write the estimate at every odometry step (for guidance evaluate)",
    )
    p.add_argument(
        "--start-heading-deg",
        type=float,
        default=None,
        help="raw logs without a compass: true heading at the start, clockwise from north",
    )
    p.add_argument("--nmea-rate", type=float, default=5.0, help="Hz, for unstamped NMEA lines")
    p.add_argument("--speed", type=float, default=None, metavar="X", help="X times recorded rate")
    p.add_argument(
        "--raw",
        action="store_true",
        help="MCAP: decode the raw /can frames and /nmea lines again (with --profile; "
        "default: the profile the recording was made with)",
    )
    p.add_argument(
        "--learned",
        type=Path,
        default=None,
        metavar="FILE.json",
        help="raw logs, car model: start from this car's learned parameters (if the file "
        "exists) and save what the drive learned into it",
    )
    p.add_argument("--json", action="store_true", help="last stdout line: the result as JSON")
    p.add_argument("--write-expected", type=Path, default=None, help="write outputs as JSON")
    p.set_defaults(func=_cli_replay)


def _cli_replay(args: argparse.Namespace) -> int:
    if args.speed is not None and not (math.isfinite(args.speed) and args.speed > 0):
        raise UserError("--speed must be a finite number > 0")
    path: Path = args.file
    is_mcap = path.is_dir() or path.suffix.lower() == ".mcap"
    current: list[Pipeline] = []
    track = TrackWriter(args.track) if args.track is not None else None

    def on_output(msg: Input, out: Outputs) -> None:
        if not args.json:
            for pr in out.prompts:
                sys.stdout.write(f"[{pr.t_s:9.2f} s] {pr.text}\n")
        if track is not None and isinstance(msg, WheelOdometry) and out.accepted:
            track.write(current[-1].state())

    summaries: list[dict[str, Any]] = []
    failed = 0
    res: ReplayResult | None = None
    try:
        if is_mcap:
            groups = recording_sessions(path)
            for files in groups:
                if len(groups) > 1 and not args.json:
                    sys.stdout.write(f"session {files[0].name} ({len(files)} file(s))\n")
                try:
                    res, summary = _replay_mcap(files, args, current, on_output)
                except UserError as exc:
                    if len(groups) == 1:
                        raise
                    failed += 1
                    sys.stderr.write(f"guidance replay: {files[0].name}: error: {exc}\n")
                    summaries.append({"files": [f.name for f in files], "error": str(exc)})
                    continue
                summaries.append(summary)
        else:
            res = _replay_raw(path, args, current, on_output)
            summaries.append(_print_result(res, None, args))
    finally:
        if track is not None:
            track.close()
    if args.write_expected is not None and res is not None:
        args.write_expected.write_text(json.dumps(res.expected(), indent=1) + "\n")
    if args.json:
        doc = summaries[0] if len(summaries) == 1 else {"sessions": summaries}
        sys.stdout.write(json.dumps(doc) + "\n")
    if failed:
        return 2
    return 1 if any(s.get("differences") for s in summaries) else 0


def _replay_mcap(
    files: list[Path],
    args: argparse.Namespace,
    current: list[Pipeline],
    on_output: Callable[[Input, Outputs], None],
) -> tuple[ReplayResult, dict[str, Any]]:
    """One recorded session: its inputs through a fresh pipeline, compared with its outputs;
    damaged records and chunks are counted and reported, the rest replayed."""
    from guidance.core.pipeline import Pipeline
    from guidance.recording.scan import Damage

    skipped: list[str] = []
    damage = Damage()
    session, inputs = mcap_inputs(
        files,
        raw=args.raw,
        profile=args.profile,
        skipped=skipped,
        damage=damage,
    )
    current.append(Pipeline(pipeline_config_from_session(session)))
    res = replay(current[-1], inputs, speed=args.speed, on_output=on_output)
    problems = compare_with_recording(res, recorded_outputs(files, skipped))
    where = files[0].name if len(files) == 1 else f"{files[0].name} (+{len(files) - 1})"
    if skipped:
        sys.stderr.write(
            f"guidance replay: {where}: {len(skipped)} damaged records left out "
            f"(first: {skipped[0]})\n"
        )
    if damage.any or damage.truncated_files:
        from guidance.recording.repair import damage_text, repair_hint

        sys.stderr.write(
            f"guidance replay: {where}: damaged recording: {damage_text(damage)}; the rest was"
            " replayed"
            + (f" (first: {damage.notes[0]})" if damage.notes else "")
            + f"; {repair_hint(files[0])}\n"
        )
    summary = _print_result(res, problems, args)
    summary["files"] = [f.name for f in files]
    summary["damaged_records"] = len(skipped)
    summary["damage"] = {
        "bad_chunks": damage.bad_chunks,
        "bad_records": damage.bad_records,
        "skipped_bytes": damage.skipped_bytes,
        "truncated_files": damage.truncated_files,
    }
    return res, summary


def _replay_raw(
    path: Path,
    args: argparse.Namespace,
    current: list[Pipeline],
    on_output: Callable[[Input, Outputs], None],
) -> ReplayResult:
    from guidance.core.pipeline import Pipeline

    setup = raw_setup(args.config, args.profile, args.start_heading_deg, path)
    pcfg = setup.pipeline
    if args.nmea is None and pcfg.start_heading_rad is None:
        raise UserError("no compass log: give --start-heading-deg or a --config with one")
    if not args.json:
        for note in setup.notes:
            sys.stdout.write(f"note: {note}\n")
    if args.nmea is None and "compass" in pcfg.expected_rates_hz:  # not replayed: not silent
        rates = {k: v for k, v in pcfg.expected_rates_hz.items() if k != "compass"}
        pcfg = replace(pcfg, expected_rates_hz=rates)
    # a gyro car's yaw-rate frames decoded as guidance run decodes them, in the log's order
    gyro = pcfg.estimator.gyro is not None
    streams: list[Iterator[Any]] = [can_log_inputs(path, setup.profile, yaw_rate=gyro)]
    if is_odometry_csv(path):  # a car's own speed and yaw rate (issue 38)
        ecfg = pcfg.estimator
        if ecfg.gyro is not None and ecfg.gyro.with_wheels:
            raise UserError(f'{path}: a speed and yaw-rate file has no wheel difference of its '
                            'own: yaw_source = "both" needs the wheels (a CAN log)')  # fmt: skip
        streams = [odometry_inputs(path, gyro=ecfg.gyro is not None, track_m=ecfg.track_m)]
    if args.nmea is not None:
        streams.append(nmea_inputs(args.nmea, _first_can_time(path), args.nmea_rate))
    merged = heapq.merge(*streams, key=lambda m: m.t_s)
    current.append(Pipeline(pcfg))
    if args.learned is None:
        return replay(current[-1], merged, speed=args.speed, on_output=on_output)
    from guidance.app.config import load_config
    from guidance.app.learned_file import save_after, start_from_learned

    vid = load_config(args.config, require_goal=False).vehicle_id if args.config else "replay"
    loc = current[-1].localizer  # the learned parameters are the first stage's
    before, note = start_from_learned(
        loc, args.learned, vid, _first_can_time(path), wall_clock=False
    )
    sys.stderr.write(f"guidance replay: {note}\n")
    res = replay(current[-1], merged, speed=args.speed, on_output=on_output)
    save_after(loc, args.learned, vid, res.last_t_s or 0.0, res.odometer_m, before)
    return res


def _print_result(
    res: ReplayResult, problems: list[str] | None, args: argparse.Namespace
) -> dict[str, Any]:
    """The summary lines (stdout) and the result as JSON-able data."""
    f = res.final
    dur = (res.last_t_s or 0.0) - (res.first_t_s or 0.0)
    w = sys.stdout.write
    w(
        f"{res.inputs} inputs over {dur:.1f} s: {res.odometer_m:.1f} m driven, "
        f"{len(res.decisions)} decisions, {len(res.prompts)} prompts\n"
        f"final estimate x {f['x_m']:.1f} m, y {f['y_m']:.1f} m, heading "
        f"{math.degrees(f['heading_rad']):.1f} deg, major axis {f['major_axis_m']:.1f} m\n"
    )
    if problems is not None:
        w(
            "matches the recording exactly\n"
            if not problems
            else f"DIFFERS from the recording: {problems[0]} ({len(problems)} differences)\n"
        )
    return {
        "inputs": res.inputs,
        "duration_s": dur,
        "distance_m": res.odometer_m,
        "decisions": len(res.decisions),
        "prompts": len(res.prompts),
        "final": f,
        "matches_recording": None if problems is None else not problems,
        "differences": problems or [],
    }
