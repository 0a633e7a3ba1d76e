"""A simulated drive's options (the ``guidance sim`` flags, a sim TOML's ``[sim]`` defaults), its
result, and the outputs the options ask for: shared by the drive (``hal_sim.drive``), the
simulated devices (``hal_sim.sim_run``) and the command (``hal_sim.sim_cli``), so none of them
imports another in a cycle.
"""

from __future__ import annotations

import io
import os
import tomllib
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
    comes into view, so the voice's own timing (guidance.core.plan.announce: about 8 s ahead, at
    least 35 m) decides when the driver hears it, as in the car. The studies use 30 m."""
    cap_factor: float = 3.0
    cap_extra_m: float = 2000.0
    config: str | None = field(default=None, metadata=rule(read=False))
    vehicle_id: str = field(default="", metadata=rule(read=False))
    """From ``[vehicle] id``; "" (none given): ``sim_vehicle_id``, one per drive."""
    profile: str = field(default="gm_global_a", metadata=rule(read=False))
    """From ``[odometry] profile``."""
    print_prompts: bool = True
    duration_s: float | None = None
    """Field protocol (SPEC 5): on arrival a new random goal is set and driving goes on until
    this much simulated time has passed; being lost does not stop it (soak runs)."""
    relocalise: bool = True
    """A car with landmarks finds itself again while lost (the world's sightings stand for the
    whole-database search; with ``camera_hz`` the real recogniser searches): being lost does not
    end the drive, it goes on until the car arrives or the cap. False (``--no-relocalise``):
    the paper's definition, a lost car's trip ends there."""
    start_unknown: bool = False
    """"Start anywhere" (``--start-unknown``): the car is not told where it starts; it waits
    at the goal, 10 km wide, until its first landmark (needs landmarks and ``relocalise``)."""


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
    chance_at_start: float | None = None
    """The car's first published chance of reaching the goal (``guidance.core.plan.chance``)."""
    lowest_chance: float | None = None
    frames_sent: int = 0
    compass_lines: int = 0
    relocalisations: int = 0
    """Places found by a whole-database search while lost (the position reset there)."""
    lost_episodes: int = 0
    """Times the car was declared lost."""

    def to_json(self) -> dict[str, Any]:
        return {
            "outcome": self.outcome,
            "driven_km": round(self.driven_km, 4),
            "final_error_m": round(self.final_error_m, 3),
            "prompts": self.prompts,
            "landmark_updates": self.landmark_updates,
            "relocalisations": self.relocalisations,
            "lost_episodes": self.lost_episodes,
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
            "chance_at_start": _round(self.chance_at_start),
            "lowest_chance": _round(self.lowest_chance),
        }


def _round(v: float | None) -> float | None:
    return None if v is None else round(v, 4)


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
    with open(path, "rb") as f:  # an id given in the file, not [vehicle]'s default
        given = "id" in tomllib.load(f).get("vehicle", {})
    opts = replace(opts, vehicle_id=cfg.vehicle_id if given else "")
    if cfg.odometry is not None:
        opts = replace(opts, profile=cfg.odometry.config.profile)
    return opts, cfg


def sim_vehicle_id(opts: DriveOptions) -> str:
    """The drive's vehicle id: the config's, else ``sim<seed>-<pid>``, so two drives side by
    side are two cars on a monitor (issue 41), and one drive keeps its id all along."""
    return opts.vehicle_id or f"sim{opts.seed}-{os.getpid()}"


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

        vid = sim_vehicle_id(opts)
        tcfg = cfg.telemetry if cfg is not None else TelemetryConfig(vehicle_id=vid)
        if cfg is None or tcfg.vehicle_id == cfg.vehicle_id:  # [telemetry] did not name one
            tcfg = replace(tcfg, vehicle_id=vid)
        # the city's place; a drive beside another on one endpoint joins it (issue 41)
        tcfg = replace(tcfg, origin_lat_lon_deg=origin, join_if_taken=True)
    if opts.record:
        from guidance.recording.config import RecordingConfig

        rcfg = RecordingConfig(directory=str(Path(opts.out) / "recordings"),
                               prefix=f"sim-seed{opts.seed}", vehicle_id=sim_vehicle_id(opts),
                               queue_size=1 << 17)  # fmt: skip
        if cfg is not None:  # the config's folder, rotation and caps
            rcfg = replace(cfg.recording, prefix=rcfg.prefix, queue_size=1 << 17,
                           vehicle_id=rcfg.vehicle_id)
        rcfg = replace(rcfg, origin_lat_lon_deg=origin)
    return OutputSettings(
        voice_backend="wav" if opts.voice_to else "none",
        wav_path=opts.voice_to or "",
        telemetry=tcfg,
        recording=rcfg,
        ros2=None if cfg is None else cfg.ros2,
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
