"""The ``guidance sim`` command: a drive's options (its flags, and a sim TOML's ``[sim]``
defaults) and the outputs they ask for, its result and the summary printed from it.

The drive itself is ``hal_sim.drive`` (``SimDrive``), imported when the command runs, so
registering the command costs nothing.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from guidance.config_tables import rule
from guidance.errors import UserError

METHODS = ("straight_to_goal", "landmark_to_landmark", "hybrid")

if TYPE_CHECKING:
    from guidance.app.build import OutputSettings
    from guidance.app.ports import Speaker


@dataclass(frozen=True, slots=True)
class DriveOptions:
    """Everything a simulated drive depends on (the CLI flags)."""

    seed: int = 7
    method: str = field(default="hybrid", metadata=rule(choices=METHODS))
    compass_deg: float | None = 20.0
    density_per_km2: float = 1.0
    detection_rate: float = 0.6
    area_km2: float = 9.0
    goal_min_m: float = 1200.0
    goal_max_m: float = 2500.0
    speed: float | None = None
    """Simulated seconds per wall second; None: as fast as possible."""
    voice: str = field(default="auto", metadata=rule(choices=("auto", "none", "wav")))
    """auto (speak if possible), none, or wav (``voice_to``)."""
    voice_to: str | None = field(default=None, metadata=rule(path=True))
    out: str = field(default="out/sim", metadata=rule(path=True))
    png: bool = True
    record: bool = True
    telemetry: bool = True
    checkpoint: str | None = field(default=None, metadata=rule(path=True))
    checkpoint_interval_s: float = 5.0
    can_silent: tuple[float, float] | None = None
    """Fault: no CAN frames from t to t + duration (simulated seconds)."""
    compass_garbage: tuple[float, float] | None = None
    """Fault: garbage instead of NMEA sentences from t to t + duration."""
    camera_hz: float | None = None
    """Simulated camera (``hal_sim.sim_camera``) + the real landmark recogniser at this frame
    rate (simulated time), instead of the world's sighting events."""
    landmark_db: str | None = field(default=None, metadata=rule(path=True))
    """With ``camera_hz``: the landmark database, built with ``landmark-db import`` from the
    city's photos on first use (hal_sim/sim_run.py); None: a throwaway one under ``out``."""
    devices: bool = False
    """``[sim] devices = true``: ``guidance run`` drives these simulated devices."""
    decision_distance_m: float = 250.0
    """The simulated co-driver announces the next intersection this far ahead: as soon as it
    comes into view, so the voice's own timing (guidance.core.announce: about 8 s ahead, at
    least 35 m) decides when the driver hears it, as in the car. The studies use 30 m."""
    cap_factor: float = 3.0
    cap_extra_m: float = 2000.0
    config: str | None = field(default=None, metadata=rule(read=False))
    vehicle_id: str = field(default="sim1", metadata=rule(read=False))
    """From ``[vehicle] id``."""
    profile: str = field(default="gm_global_a", metadata=rule(read=False))
    """From ``[odometry] profile``."""
    print_prompts: bool = True
    duration_s: float | None = None
    """Field protocol (SPEC 5): on arrival a new random goal is set and driving goes on until
    this much simulated time has passed; being lost does not stop it (soak runs)."""


@dataclass
class DriveResult:
    outcome: str
    driven_km: float
    final_error_m: float
    prompts: int
    landmark_updates: int
    decisions: int
    png: str | None
    sim_s: float
    wall_s: float
    seed: int
    method: str
    wav: str | None = None
    recording: list[str] = field(default_factory=list)
    resumed_at_s: float | None = None
    health_warnings: list[str] = field(default_factory=list)
    prompt_log: list[tuple[float, str]] = field(default_factory=list)
    loop_lag_p99_ms: float | None = None
    loop_lag_ms: dict[str, float | None] = field(default_factory=dict)
    goals_reached: int = 0
    frames_sent: int = 0
    compass_lines: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "outcome": self.outcome,
            "driven_km": round(self.driven_km, 4),
            "final_error_m": round(self.final_error_m, 3),
            "prompts": self.prompts,
            "landmark_updates": self.landmark_updates,
            "decisions": self.decisions,
            "png": self.png,
            "wav": self.wav,
            "sim_s": round(self.sim_s, 2),
            "wall_s": round(self.wall_s, 3),
            "seed": self.seed,
            "method": self.method,
            "recording": self.recording,
            "resumed_at_s": self.resumed_at_s,
            "health_warnings": self.health_warnings,
            "loop_lag_p99_ms": self.loop_lag_p99_ms,
            "goals_reached": self.goals_reached,
        }


def options_from_config(path: str, opts: DriveOptions) -> tuple[DriveOptions, Any]:
    """Read a sim TOML config (config/sim.toml): its ``[sim]`` table, read by the one table
    loader (``guidance.config_tables``), gives the drive's defaults; ``[navigation] method``
    and ``[estimator] compass_two_sigma_deg`` fill what ``[sim]`` leaves out; the vehicle id and
    the CAN profile come from ``[vehicle]`` and ``[odometry]``. Paths are taken from the config
    file's folder, like every path in a config."""
    from guidance.app.config import load_config
    from guidance.config_tables import from_table

    cfg = load_config(path, require_goal=False)
    base = replace(
        opts,
        method=cfg.pipeline.navigator.method.value,
        compass_deg=cfg.pipeline.estimator.compass_two_sigma_deg,
    )
    try:
        opts = from_table(DriveOptions, cfg.sim, "sim", Path(path).resolve().parent, base=base)
    except UserError as e:
        raise UserError(f"{path}: {e}") from None
    opts = replace(opts, vehicle_id=cfg.vehicle_id)
    if cfg.odometry is not None:
        opts = replace(opts, profile=cfg.odometry.config.profile)
    return opts, cfg


def output_settings(
    opts: DriveOptions, app_config: Any, origin: tuple[float, float], session: dict[str, Any]
) -> OutputSettings:
    """The car's outputs (``guidance.app.build``) as a drive's options ask for them; the
    telemetry and recording place the city at ``origin``, the recording starts with
    ``session``."""
    from guidance.app.build import OutputSettings

    cfg = app_config
    tcfg = rcfg = None
    if opts.telemetry:
        from guidance.telemetry.config import TelemetryConfig

        tcfg = cfg.telemetry if cfg is not None else TelemetryConfig(vehicle_id=opts.vehicle_id)
        tcfg = replace(tcfg, origin_lat_lon_deg=origin)  # the city's place: lat/lon
    if opts.record:
        from guidance.recording.config import RecordingConfig

        rcfg = RecordingConfig(directory=str(Path(opts.out) / "recordings"),
                               prefix=f"sim-seed{opts.seed}", vehicle_id=opts.vehicle_id,
                               queue_size=1 << 17)  # fmt: skip
        if cfg is not None:  # the config's folder, rotation and caps
            rcfg = replace(cfg.recording, prefix=rcfg.prefix, queue_size=1 << 17)
        rcfg = replace(rcfg, origin_lat_lon_deg=origin)
    return OutputSettings(
        voice_backend="wav" if opts.voice_to else "none",
        wav_path=opts.voice_to or "",
        telemetry=tcfg,
        recording=rcfg,
        session=session,
        drain_speech=opts.voice_to is not None,
        speaker_factory=_live_voice if not opts.voice_to and opts.voice != "none" else None,
    )


def _live_voice(clock: Callable[[], float]) -> Speaker | None:
    """A live voice if this machine can speak; None otherwise (the prompts are printed anyway)."""
    from guidance.voice import make_speaker
    from guidance.voice.speakers import TextSpeaker

    spk = make_speaker("voice", clock=clock, text_stream=io.StringIO())
    if isinstance(spk, TextSpeaker):
        spk.close()
        return None
    return spk


def wav_has_speech(path: str, min_s: float = 0.3, min_rms: float = 100.0) -> bool:
    """True when ``path`` is a WAV file holding at least ``min_s`` of sound above ``min_rms``
    (16-bit): what the summary may call "prompts recorded"."""
    import wave

    import numpy as np

    try:
        with wave.open(path, "rb") as w:
            if w.getsampwidth() != 2 or w.getframerate() <= 0:
                return False
            rate = w.getframerate()
            a = np.frombuffer(w.readframes(w.getnframes()), dtype=np.int16).astype(float)
    except (OSError, EOFError, wave.Error):
        return False
    loud = np.abs(a) > min_rms
    return bool(a.size >= min_s * rate and np.count_nonzero(loud) >= 0.1 * min_s * rate)


# ----------------------------------------------------------------------------- the command


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


def _run_on_simulated_devices(config_path: str, *, as_json: bool = False) -> int:
    from hal_sim.sim_run import run_on_simulated_devices

    return run_on_simulated_devices(config_path, as_json=as_json)


def register(sub: Any) -> None:
    from guidance.app.run import register_device_runner

    # `guidance run` on a config with [sim] devices = true drives the simulated city
    register_device_runner("sim", _run_on_simulated_devices)
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
    opts = replace(opts, **changes)

    drive_and_report(opts, app_config, as_json=args.json)
    return 0


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
