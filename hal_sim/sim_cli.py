"""The ``guidance sim`` command: its flags (over a sim TOML's ``[sim]``, read by
``hal_sim.drive_options``), the summary printed from a drive's result, and ``guidance run``'s
runner for a car TOML with ``[sim] devices = true`` (``run_on_simulated_devices``).

The drive itself is ``hal_sim.drive`` (``SimDrive``), imported when a command runs, so
registering the commands costs nothing. Nothing in ``hal_sim`` imports this module back: the
simulator's modules form no import cycle (``tests/test_layers.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from typing import Any

from guidance.core.plan.chance import shown
from hal_sim.drive_options import (
    METHODS,
    DriveOptions,
    DriveResult,
    options_from_config,
)


def _compass_arg(text: str) -> float | None:
    if text.lower() in ("none", "off", "no"):
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected degrees or 'none', not {text!r}") from None


def _window(text: str) -> tuple[float, float]:
    try:
        a, b = text.split(":")
        return float(a), float(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:DURATION seconds, not {text!r}") from None


def register(sub: Any) -> None:
    p = sub.add_parser(
        "sim",
        help="a simulated drive through the full in-car stack (make demo)",
        description=(
            "Drive a simulated car from a random start to a goal 1.2-2.5 km away in a random "
            "city, through the real CAN odometry driver (virtual bus), the real NMEA compass "
            "driver (pseudo-terminal), the estimator, the navigator and the voice. Prints the "
            "prompts, a summary, and writes a PNG of the drive."
        ),
    )
    p.add_argument("--seed", type=int, default=None, help="world seed (default 7)")
    p.add_argument(
        "--method",
        default=None,
        choices=METHODS,
        help="navigation method (default hybrid)",
    )
    p.add_argument(
        "--compass-deg",
        type=_compass_arg,
        default=argparse.SUPPRESS,
        metavar="D|none",
        help="compass 2-sigma error in degrees, or none (default 20)",
    )
    p.add_argument("--density", type=float, default=None, help="landmarks per km² (default 1)")
    p.add_argument(
        "--detection-rate", type=float, default=None, help="landmark detection rate 0-1 (0.6)"
    )
    pace = p.add_mutually_exclusive_group()
    pace.add_argument(
        "--speed", type=float, default=None, metavar="X", help="run X times real time"
    )
    pace.add_argument("--realtime", action="store_true", help="run in real time (--speed 1)")
    p.add_argument("--no-voice", action="store_true", help="do not speak the prompts")
    p.add_argument("--voice-to", metavar="WAV", default=None, help="record the prompts to a WAV")
    p.add_argument("--json", action="store_true", help="last stdout line: the summary as JSON")
    p.add_argument("--out", default=None, help="output folder (default out/sim)")
    p.add_argument("--config", default=None, help="a sim TOML config (e.g. config/sim.toml)")
    p.add_argument(
        "--checkpoint",
        default=None,
        metavar="PATH",
        help="checkpoint file: resume from it if present, write it every 5 simulated seconds",
    )
    p.add_argument(
        "--camera",
        type=float,
        default=None,
        metavar="HZ",
        nargs="?",
        const=2.0,
        help="simulated camera frames at HZ (default 2) through the real landmark recogniser",
    )
    p.add_argument(
        "--decision-distance",
        type=float,
        default=None,
        metavar="M",
        help=(
            "the simulated co-driver reports each intersection when it is M metres ahead "
            "(default 250: as soon as it comes into view; the studies use 30)"
        ),
    )
    p.add_argument("--no-telemetry", action="store_true", help="no Zenoh telemetry")
    p.add_argument("--no-record", action="store_true", help="no MCAP recording")
    p.add_argument("--no-png", action="store_true", help="no PNG")
    p.add_argument(
        "--no-relocalise",
        action="store_true",
        help="a lost car stops there (the paper's definition); by default a car with landmarks "
        "looks for itself again and drives on",
    )
    p.add_argument(
        "--start-unknown",
        action="store_true",
        help="start anywhere: the car is not told where it starts and finds itself at its "
        "first landmark ([start] with no position in a car's config)",
    )
    p.add_argument(
        "--can-silent",
        type=_window,
        default=None,
        metavar="T:D",
        help="fault: no CAN frames for D simulated seconds from T",
    )
    p.add_argument(
        "--compass-garbage",
        type=_window,
        default=None,
        metavar="T:D",
        help="fault: garbage instead of NMEA for D simulated seconds from T",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="field protocol: a new random goal on each arrival until S simulated seconds",
    )
    p.set_defaults(func=_cli_sim)


def _cli_sim(args: argparse.Namespace) -> int:

    opts = DriveOptions()
    app_config = None
    if args.config:
        opts, app_config = options_from_config(args.config, opts)
    changes: dict[str, Any] = {}
    for flag, key in (
        ("seed", "seed"),
        ("method", "method"),
        ("density", "density_per_km2"),
        ("detection_rate", "detection_rate"),
        ("out", "out"),
        ("checkpoint", "checkpoint"),
        ("voice_to", "voice_to"),
        ("can_silent", "can_silent"),
        ("compass_garbage", "compass_garbage"),
        ("camera", "camera_hz"),
        ("decision_distance", "decision_distance_m"),
        ("duration", "duration_s"),
    ):
        value = getattr(args, flag)
        if value is not None:
            changes[key] = value
    if "compass_deg" in vars(args):  # given on the command line: it wins over the config
        changes["compass_deg"] = args.compass_deg
    if args.realtime:
        changes["speed"] = 1.0
    elif args.speed is not None:
        changes["speed"] = args.speed
    if args.no_voice:
        changes["voice"] = "none"
    if args.no_telemetry:
        changes["telemetry"] = False
    if args.no_record:
        changes["record"] = False
    if args.no_png:
        changes["png"] = False
    if args.no_relocalise:
        changes["relocalise"] = False
    if args.start_unknown:
        changes["start_unknown"] = True
    opts = replace(opts, **changes)

    drive_and_report(opts, app_config, as_json=args.json)
    return 0


def run_on_simulated_devices(
    config_path: str, *, as_json: bool = False, screen: str = "off"
) -> int:
    """``guidance run --config`` with ``[sim] devices = true``: one simulated drive through the
    car's wiring. With ``screen`` (not "off"): the car's operator screen (live on a terminal,
    plain lines otherwise) while the drive goes in real time (``[sim] speed`` changes that),
    then the summary; else the prompts, the summary and, with ``as_json``, the result as the
    last line (``outcome``, ``landmark_updates``, ``prompts``...), as fast as it goes."""
    from hal_sim.drive import run_drive

    opts, cfg = options_from_config(config_path, DriveOptions())
    if cfg.landmark_db is not None:
        opts = replace(opts, landmark_db=cfg.landmark_db.database)
    if cfg.voice.backend == "none":
        opts = replace(opts, voice="none")
    elif cfg.voice.backend == "wav" and cfg.voice.wav_path:
        opts = replace(opts, voice_to=cfg.voice.wav_path)

    if as_json or screen == "off":
        result = drive_and_report(opts, cfg, as_json=as_json)
    else:
        if opts.speed is None:  # the operator sees the drive as the car lives it
            opts = replace(opts, speed=1.0)
        result = run_drive(opts, None, cfg, screen=screen)
        print_summary(result, opts)
    return 0 if result.outcome in ("arrived", "time_limit", "stopped") else 1  # Ctrl-C: clean


def drive_and_report(opts: DriveOptions, app_config: Any, *, as_json: bool) -> DriveResult:
    """One simulated drive with its prompts printed as they come, then the summary and, with
    ``as_json``, the result as the last stdout line (``guidance sim``, and ``guidance run`` on
    the simulated devices)."""
    from hal_sim.drive import run_drive

    def printer(line: str) -> None:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()

    result = run_drive(opts, printer, app_config)
    print_summary(result, opts)
    if as_json:
        sys.stdout.write(json.dumps(result.to_json()) + "\n")
    sys.stdout.flush()
    return result


def print_summary(result: DriveResult, opts: DriveOptions) -> None:
    """The end-of-drive summary lines (``guidance sim``, ``guidance run`` on simulated devices)."""
    w = sys.stdout.write
    w(
        f"\n{result.outcome.upper()}: drove {result.driven_km:.2f} km in {result.sim_s:.0f} s "
        f"simulated ({result.wall_s:.1f} s wall)\n"
        f"  final position error {result.final_error_m:.1f} m; {result.decisions} decisions, "
        f"{result.prompts} prompts, {result.landmark_updates} landmark updates"
        + (f", {result.goals_reached} goals reached" if opts.duration_s is not None else "")
        + "\n"
    )
    if result.chance_at_start is not None and result.lowest_chance is not None:
        w(
            f"  chance of reaching the goal: {shown(result.chance_at_start)} at the start, "
            f"{shown(result.lowest_chance)} at its lowest\n"
        )
    if result.lost_episodes:
        w(
            f"  lost {result.lost_episodes} time(s); found again {result.relocalisations} time(s)"
            + ("" if opts.relocalise else " (--no-relocalise: the trip ended at lost)")
            + "\n"
        )
    if result.resumed_at_s is not None:
        w(f"  resumed from the checkpoint at {result.resumed_at_s:.1f} s\n")
    for warning in result.health_warnings:
        w(f"  health: {warning}\n")
    if result.png:
        w(f"  PNG: {result.png}\n")
    if result.wav:
        w(f"  prompts recorded to {result.wav}\n")
    elif opts.voice_to:
        w(f"  no speech in {opts.voice_to}: no speech engine (see docs/voice.md)\n")
    if result.recording:
        w(f"  recording: {', '.join(result.recording)}\n")
    sys.stdout.flush()
