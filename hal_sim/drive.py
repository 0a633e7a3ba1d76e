"""``guidance sim``: a simulated drive through the full in-car stack (issue 4, ``make demo``).

The simulated world (``hal_sim.sim_scene.SimWorld``) drives the truth. Its wheel speeds go out
as CAN frames encoded with the reference car's DBC on a python-can virtual bus
(``SimCanWheels``) and come back through the real ``CanOdometry`` driver; its compass headings
go out as NMEA sentences into a pseudo-terminal (``SimCompassPty``) read by the real
``SerialCompass``; the roadway scene comes from the city graph (``SimScene``); landmark fixes
come from the world's sighting events (``SimSightings``, a stand-in for camera + matcher; a
recogniser with ``process(frame, state)`` plugs into ``App`` instead when a simulated camera
exists). The ``App`` and ``Pipeline`` are the ones ``guidance run`` uses.

The world and the app run in lockstep on one simulated clock: each step's frames and
sentences are sent, then the simulation waits until the app has processed them, so the
drive is reproducible for a seed however fast the machine is, and ``--speed``/``--realtime``
only pace it against the wall clock.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import copy
import io
import itertools
import json
import logging
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from guidance.errors import UserError

log = logging.getLogger(__name__)

SIM_ORIGIN_LAT_LON = (42.4440, -76.5019)
"""Where the simulated city is placed for the magnetic declination (Ithaca, NY)."""
SIM_DATE = "2026-06-01"
ELLIPSE_EVERY_M = 150.0
TRACK_EVERY_S = 1.0
_channel_ids = itertools.count()


@dataclass(frozen=True, slots=True)
class DriveOptions:
    """Everything a simulated drive depends on (the CLI flags)."""

    seed: int = 7
    method: str = "hybrid"
    compass_deg: float | None = 20.0
    density_per_km2: float = 1.0
    detection_rate: float = 0.6
    area_km2: float = 9.0
    goal_min_m: float = 1200.0
    goal_max_m: float = 2500.0
    speed: float | None = None
    """Simulated seconds per wall second; None: as fast as possible."""
    voice: str = "auto"
    """auto (speak if possible), none, or wav (``voice_to``)."""
    voice_to: str | None = None
    out: str = "out/sim"
    png: bool = True
    record: bool = True
    telemetry: bool = True
    checkpoint: str | None = None
    checkpoint_interval_s: float = 5.0
    can_silent: tuple[float, float] | None = None
    """Fault: no CAN frames from t to t + duration (simulated seconds)."""
    compass_garbage: tuple[float, float] | None = None
    """Fault: garbage instead of NMEA sentences from t to t + duration."""
    camera_hz: float | None = None
    """Simulated camera (``hal_sim.sim_camera``) + the real landmark recogniser at this frame
    rate (simulated time), instead of the world's sighting events."""
    landmark_db: str | None = None
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
    config: str | None = None
    vehicle_id: str = "sim1"
    profile: str = "gm_global_a"
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


def _in(window: tuple[float, float] | None, t: float) -> bool:
    return window is not None and window[0] <= t < window[0] + window[1]


def options_from_config(path: str, opts: DriveOptions) -> tuple[DriveOptions, Any]:
    """Read a sim TOML config (config/sim.toml); its [sim] table gives option defaults."""
    from guidance.app.config import load_config

    cfg = load_config(path, require_goal=False)
    known = {f for f in DriveOptions.__dataclass_fields__}
    changes: dict[str, Any] = {}
    for key, value in cfg.sim.items():
        if key not in known or key in ("config",):
            raise UserError(f"[sim] unknown key {key!r}")
        changes[key] = tuple(value) if isinstance(value, list) else value
    changes["method"] = changes.get("method", cfg.pipeline.navigator.method.value)
    sigma = cfg.pipeline.estimator.compass_two_sigma_deg
    changes.setdefault("compass_deg", sigma)
    changes["vehicle_id"] = cfg.vehicle_id
    if cfg.odometry is not None:
        changes["profile"] = cfg.odometry.config.profile
    return replace(opts, **changes), cfg


async def drive_async(
    opts: DriveOptions,
    printer: Callable[[str], None] | None = None,
    app_config: Any = None,
    on_progress: Callable[[float], None] | None = None,
) -> DriveResult:
    """Run one simulated drive; ``printer`` receives one line per prompt.

    ``on_progress`` is called with the simulated time about once per simulated minute.
    """
    from drivers.can_odometry import MAX_GAP_S, CanOdometry, CanOdometryConfig
    from drivers.compass import SerialCompass, SerialCompassConfig
    from guidance.app.app import App
    from guidance.app.build import OutputSettings, open_outputs, session_record
    from guidance.app.checkpoint import Checkpointer, load_checkpoint
    from guidance.app.magnetic import declination_deg
    from guidance.core.messages import GoalUpdate
    from guidance.core.model import heading_to_compass
    from guidance.core.navigator import Method, NavigatorConfig
    from guidance.core.pipeline import Pipeline, PipelineConfig
    from hal_sim.lockstep import LockstepSink
    from hal_sim.params import SimParams, estimator_config
    from hal_sim.sim_can import SimCanWheels
    from hal_sim.sim_checks import check_drive_options, stop_on_signals
    from hal_sim.sim_compass import SimCompassPty
    from hal_sim.sim_scene import SimScene, SimSightings, SimWorld, WorldSpec

    wall0 = time.monotonic()
    check_drive_options(opts)  # one clear line before anything starts (hal_sim/sim_checks.py)
    try:
        method = Method(opts.method)
    except ValueError:
        raise UserError(
            f"--method must be one of {', '.join(m.value for m in Method)}, not {opts.method!r}"
        ) from None
    if opts.compass_deg is not None and not (0 < opts.compass_deg <= 180):
        raise UserError(f"--compass-deg must be in (0, 180] or 'none', not {opts.compass_deg}")
    if opts.density_per_km2 < 0:
        raise UserError("--density must be >= 0 landmarks per km²")
    if not 0.0 <= opts.detection_rate <= 1.0:
        raise UserError("--detection-rate must be within [0, 1]")
    if opts.speed is not None and opts.speed <= 0:
        raise UserError("--speed must be > 0")
    if opts.duration_s is not None and opts.duration_s <= 0:
        raise UserError("--duration must be > 0 simulated seconds")
    field_protocol = opts.duration_s is not None
    end_t = math.inf if opts.duration_s is None else opts.duration_s

    sim = SimParams(decision_distance_m=opts.decision_distance_m)
    est_cfg = estimator_config(sim, opts.compass_deg)
    nav_cfg = NavigatorConfig(method=method)
    spec = WorldSpec(
        opts.seed,
        opts.area_km2,
        opts.goal_min_m,
        opts.goal_max_m,
        opts.density_per_km2,
        opts.detection_rate,
    )
    world = SimWorld(spec, sim, est_cfg, nav_cfg)
    origin = SIM_ORIGIN_LAT_LON
    if app_config is not None and app_config.origin_lat_lon_deg is not None:
        origin = app_config.origin_lat_lon_deg
    decl = declination_deg(origin[0], origin[1], _date(SIM_DATE))
    sx, sy, th0 = world.start_pose
    landmarks = world.landmarks()
    camera = recogniser = None
    if opts.camera_hz is not None:
        camera, recogniser, landmarks = _sim_camera(world, opts, out_dir_for(opts))
    gx, gy = world.goal_xy
    rates: dict[str, float | None] = {"odometry": 1.0 / world.dt_s}
    if opts.compass_deg is not None:
        rates["compass"] = sim.compass_rate_hz
    pcfg = PipelineConfig(
        estimator=est_cfg,
        navigator=nav_cfg,
        start_xy_m=(sx, sy),
        goal_xy_m=(gx, gy),
        start_heading_rad=th0,
        landmarks=landmarks,
        declination_deg=decl,
        expected_rates_hz=rates,
        stop_at_arrival=not field_protocol,
    )
    pipeline = Pipeline(pcfg)
    manhattan = abs(gx - sx) + abs(gy - sy)
    cap_m = math.inf if field_protocol else opts.cap_factor * manhattan + opts.cap_extra_m
    goals_reached = 0
    next_progress_t = 0.0

    out_dir = out_dir_for(opts)
    track_truth: list[tuple[float, float]] = []
    track_est: list[tuple[float, float]] = []
    ellipses: list[tuple[float, float, list[list[float]]]] = []
    axis_track: list[tuple[float, float]] = []  # (distance driven, 2-sigma major axis)
    fixes: list[tuple[float, float, float, int]] = []  # (distance, x, y, landmark id)
    resumed_at: float | None = None
    checkpointer = None
    if opts.checkpoint:
        checkpointer = Checkpointer(opts.checkpoint, opts.checkpoint_interval_s)
        doc = load_checkpoint(opts.checkpoint)
        if doc is not None:
            extra = doc.get("extra", {})
            if extra.get("seed") != opts.seed or extra.get("method") != method.value:
                raise UserError(
                    f"checkpoint {opts.checkpoint} is for seed {extra.get('seed')} "
                    f"method {extra.get('method')}; delete it or use the same options"
                )
            try:  # a damaged or hostile checkpoint: one line, and it is moved aside
                Pipeline(pcfg).restore(doc["pipeline"])  # checked on a throwaway first
                world.replay_to(int(extra["step"]), extra["route"])
                pipeline.restore(doc["pipeline"])
                track_truth = [(float(a), float(b)) for a, b in extra.get("track_truth", [])]
                track_est = [(float(a), float(b)) for a, b in extra.get("track_est", [])]
            except (ValueError, KeyError, TypeError, IndexError, AttributeError) as exc:
                from guidance.app.checkpoint import set_aside

                set_aside(opts.checkpoint, f"cannot be resumed: {exc}")
                raise UserError(
                    f"checkpoint {opts.checkpoint} cannot be resumed ({exc}); it was moved "
                    "aside: run again to start afresh"
                ) from None
            resumed_at = world.t_s
            log.warning("resumed from checkpoint %s at t=%.1f s", opts.checkpoint, resumed_at)

    def extra_state() -> dict[str, Any]:
        return {
            "seed": opts.seed,
            "method": method.value,
            "step": world.step_count,
            "route": [list(r) for r in world.route],
            "track_truth": [list(p) for p in track_truth],
            "track_est": [list(p) for p in track_est],
        }

    result_prompts: list[tuple[float, str]] = []
    health_warnings: list[str] = []
    channel = f"sim-can-{os.getpid()}-{next(_channel_ids)}"
    tx = odo = pty = compass = None
    stack = contextlib.AsyncExitStack()
    try:
        tx = SimCanWheels(channel, profile=opts.profile).open()
        odo = CanOdometry(
            CanOdometryConfig(
                interface="virtual",
                channel=channel,
                profile=opts.profile,
                clock="frame",
                bitrate=None,
            )
        )
        sources: dict[str, Any] = {"odometry": odo}
        if opts.compass_deg is not None:
            pty = SimCompassPty()
            compass = SerialCompass(
                SerialCompassConfig(port=pty.port, baudrate=4800), clock=lambda: world.t_s
            )
            sources["compass"] = compass
        scene = SimScene(world)
        sightings = SimSightings(world)
        sources["scene"] = scene
        sources["landmark"] = sightings
        tcfg = None
        if opts.telemetry:
            from guidance.telemetry.config import TelemetryConfig

            tcfg = (
                app_config.telemetry
                if app_config is not None
                else TelemetryConfig(vehicle_id=opts.vehicle_id)
            )
            tcfg = replace(tcfg, origin_lat_lon_deg=origin)  # the city's place: lat/lon
        rcfg = None
        if opts.record:
            from guidance.recording.config import RecordingConfig

            rcfg = RecordingConfig(
                directory=str(out_dir / "recordings"),
                prefix=f"sim-seed{opts.seed}",
                vehicle_id=opts.vehicle_id,
                queue_size=1 << 17,
            )
            if app_config is not None:  # the config's folder, rotation and caps
                rcfg = replace(app_config.recording, prefix=rcfg.prefix, queue_size=1 << 17)
            rcfg = replace(rcfg, origin_lat_lon_deg=origin)
        live_voice = not opts.voice_to and opts.voice != "none"
        settings = OutputSettings(
            voice_backend="wav" if opts.voice_to else "none",
            wav_path=opts.voice_to or "",
            telemetry=tcfg,
            recording=rcfg,
            session=session_record(
                pipeline, opts.config or "", sim={"seed": opts.seed, "method": method.value}
            ),
            drain_speech=opts.voice_to is not None,
            speaker_factory=_live_voice if live_voice else None,
        )
        outs = await stack.enter_async_context(open_outputs(settings, lambda: world.t_s))
        speaker, recorder = outs.speaker, outs.recorder
        app = App(
            pipeline,
            sources=sources,
            recogniser=recogniser,
            speaker=speaker,
            sinks=outs.sinks,
            recorder=recorder,
            checkpointer=checkpointer,
            checkpoint_extra=extra_state,
            clock=lambda: world.t_s,
            external_ticks=True,
        )

        def on_output(_msg: Any, out: Any) -> None:
            for p in out.prompts:
                result_prompts.append((p.t_s, p.text))
                if printer is not None:
                    printer(f"[{p.t_s:7.1f} s] {p.text}")
            for h in out.health:
                st = h.status
                if not (st.alive and st.valid):
                    health_warnings.append(f"{h.t_s:.1f} s {st.name}: {st.detail}")
            for fix in out.landmark_updates:
                x = pipeline.estimator.x
                fixes.append((pipeline.odometer_m, float(x[0]), float(x[1]), fix.landmark_id))
                axis_track.append((pipeline.odometer_m, pipeline.estimator.major_axis_m))

        app.listeners.append(on_output)
        lockstep = LockstepSink(app.sink)  # the world waits for the app (hal_sim/lockstep.py)
        app.source_sink = lockstep
        outcome = "timeout"
        expect_odo = expect_heading = expect_lines = 0
        last_can_t: float | None = None
        next_track_t = world.t_s
        next_ellipse_m = pipeline.odometer_m
        next_frame_t = world.t_s
        copy.deepcopy(world).step()  # compile the world's numba step before the loop's clock
        async with app.running():
            stop_signal = stop_on_signals()  # SIGINT/SIGTERM: end with the summary
            if compass is not None and not await lockstep.wait_until(
                lambda: compass.connected, 5.0
            ):
                raise UserError("the simulated compass pty did not open")
            if pipeline.finished:
                outcome = "arrived" if pipeline.arrived else "lost"
            pace0_wall, pace0_sim = time.monotonic(), world.t_s
            first_step = world.step_count
            while not pipeline.finished:
                if stop_signal.is_set():
                    outcome = "stopped"
                    break
                ev = world.step()
                t = ev.t_s
                if ev.step == first_step + 10:  # lag figures without the start-up (JIT load)
                    app.loop_lag_s.clear()
                # Wheel speeds -> CAN frames -> CanOdometry -> pipeline.
                if not _in(opts.can_silent, t):
                    tx.set_speeds(ev.left_mps, ev.right_mps)
                    tx.send(t)
                    if last_can_t is not None and t - last_can_t <= MAX_GAP_S:
                        expect_odo += 1
                        n_odo = expect_odo
                        if not await lockstep.wait_until(
                            _at_least(app.counts, "WheelOdometry", n_odo), 2.0
                        ):
                            log.warning("t=%.1f s: odometry frame not delivered", t)
                            expect_odo = app.counts["WheelOdometry"]
                    last_can_t = t
                # Compass heading -> NMEA on the pty -> SerialCompass -> pipeline.
                if pty is not None and compass is not None and ev.heading_rad is not None:
                    expect_lines += 1
                    n_lines = expect_lines
                    if _in(opts.compass_garbage, t):
                        pty.write_raw(b"$HCHDG,12x.4,,,,*7Z\r\n")
                    else:
                        pty.write_heading(float(heading_to_compass(ev.heading_rad, decl)))
                        expect_heading += 1
                    n_head = expect_heading
                    ok = await lockstep.wait_until(
                        _compass_done(app.counts, compass, n_head, n_lines),
                        2.0,
                    )
                    if not ok:
                        log.warning("t=%.1f s: compass sentence not delivered", t)
                        expect_heading = app.counts["CompassHeading"]
                        expect_lines = compass.parser.lines
                if camera is not None and recogniser is not None:
                    if t >= next_frame_t:  # the real matcher, off the loop, in lockstep
                        next_frame_t = t + 1.0 / (opts.camera_hz or 1.0)
                        tx_, ty_, _ = world.truth
                        frame = camera.frame_at(t, tx_, ty_)
                        pipeline.health.observe("camera", t)
                        loop = asyncio.get_running_loop()
                        state = pipeline.state()
                        fix = await loop.run_in_executor(None, app.match_frame, frame, state)
                        if fix is not None:
                            app.feed(fix)
                elif ev.landmark is not None:
                    sightings.sighted(t, ev.landmark)
                    await lockstep.drained()
                app.tick(t)
                if recorder is not None:  # the true pose, on its own topics (rate-limited)
                    recorder.record_truth(t, *world.truth)
                if t >= next_track_t:
                    next_track_t = t + TRACK_EVERY_S
                    tx_, ty_, _ = world.truth
                    x = pipeline.estimator.x
                    track_truth.append((tx_, ty_))
                    track_est.append((float(x[0]), float(x[1])))
                    axis_track.append((pipeline.odometer_m, pipeline.estimator.major_axis_m))
                if pipeline.odometer_m >= next_ellipse_m:
                    next_ellipse_m = pipeline.odometer_m + ELLIPSE_EVERY_M
                    x, P = pipeline.estimator.x, pipeline.estimator.P
                    ellipses.append((float(x[0]), float(x[1]), P[:2, :2].tolist()))
                if pipeline.finished:
                    outcome = "arrived" if pipeline.arrived else "lost"
                    break
                if on_progress is not None and t >= next_progress_t:
                    next_progress_t = t + 60.0
                    on_progress(t)
                if field_protocol:
                    if pipeline.arrived:  # the field protocol: a new random goal
                        goals_reached += 1
                        world.new_goal()
                        ngx, ngy = world.goal_xy
                        app.feed(GoalUpdate(t, ngx, ngy, "field_protocol"))
                        await lockstep.drained()
                    if t >= end_t:
                        outcome = "time_limit"
                        break
                if world.driven_m >= cap_m:
                    outcome = "timeout"
                    break
                scene.update(ev)
                if ev.decide:
                    before = pipeline.navigator.decisions
                    scene.announce(ev)
                    await lockstep.drained()
                    if pipeline.navigator.decisions > before and pipeline.last_decision:
                        scene.follow(pipeline.last_decision.exit_index)
                if opts.speed is not None:
                    ahead = (t - pace0_sim) / opts.speed - (time.monotonic() - pace0_wall)
                    if ahead > 0:
                        await asyncio.sleep(ahead)
            tx_, ty_, _ = world.truth
            x = pipeline.estimator.x
            track_truth.append((tx_, ty_))
            track_est.append((float(x[0]), float(x[1])))
            app.save_checkpoint(world.t_s)
        lag_ms = app.lag_summary()
        lag = lag_ms["loop_lag_p99_ms"]
    finally:
        if recogniser is not None:
            recogniser.close()
        for closer in (compass, odo):
            if closer is not None:
                with contextlib.suppress(Exception):
                    closer.stop()
        if tx is not None:
            tx.close()
        if pty is not None:
            pty.close()
        await stack.aclose()  # speaker (drained for a WAV), recorder, telemetry

    tx_, ty_, _ = world.truth
    x = pipeline.estimator.x
    final_error = math.hypot(tx_ - float(x[0]), ty_ - float(x[1]))
    png = None
    if opts.png:
        png = str(out_dir / f"drive-seed{opts.seed}.png")
        from hal_sim.plots import DriveTrace, plot_drive

        trace = DriveTrace(track_truth, track_est, ellipses, axis_track, fixes)
        plot_drive(png, world, trace, outcome, opts)
    return DriveResult(
        outcome=outcome,
        driven_km=world.driven_m / 1000.0,
        final_error_m=final_error,
        prompts=pipeline.prompt_count,
        landmark_updates=pipeline.landmark_updates,
        decisions=pipeline.navigator.decisions,
        png=png,
        sim_s=world.t_s,
        wall_s=time.monotonic() - wall0,
        seed=opts.seed,
        method=method.value,
        wav=opts.voice_to if opts.voice_to and wav_has_speech(opts.voice_to) else None,
        recording=[str(p) for p in (recorder.files if recorder is not None else [])],
        resumed_at_s=resumed_at,
        health_warnings=health_warnings,
        prompt_log=result_prompts,
        loop_lag_p99_ms=lag,
        loop_lag_ms=lag_ms,
        goals_reached=goals_reached,
        frames_sent=tx.frames_sent if tx is not None else 0,
        compass_lines=pty.sentences_written if pty is not None else 0,
    )


def out_dir_for(opts: DriveOptions) -> Path:
    return Path(opts.out)


def _sim_camera(world: Any, opts: DriveOptions, out_dir: Path) -> tuple[Any, Any, Any]:
    """The simulated camera, the real recogniser on a database of the city's landmarks, and
    the navigator's landmark list with the database ids."""
    from guidance.core.navigator import Landmark
    from hal_sim.sim_camera import SimCamera, build_sim_landmark_db
    from hal_sim.sim_scene import landmark_name
    from landmark_db.recognise import Recogniser, RecogniserConfig

    if opts.landmark_db:  # made as a user makes one: photos + CSV + landmark-db import
        from hal_sim.sim_run import import_sim_landmark_db
        from landmark_db.store import open_db

        lms = import_sim_landmark_db(opts.landmark_db, world.lm_xy, opts.seed)
        db = open_db(opts.landmark_db, readonly=True)
    else:
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / f"landmarks-seed{opts.seed}.sqlite"
        for old in out_dir.glob(f"landmarks-seed{opts.seed}.sqlite*"):
            old.unlink()
        db, lms = build_sim_landmark_db(path, world.lm_xy, opts.seed)
    recogniser = Recogniser(db, RecogniserConfig(sighting_range_m=world.sim.sighting_range_m))
    camera = SimCamera(lms, opts.seed)
    landmarks = tuple(Landmark(lm.id, lm.x_m, lm.y_m, landmark_name(i)) for i, lm in enumerate(lms))
    return camera, recogniser, landmarks


def _at_least(counts: Any, key: str, n: int) -> Callable[[], bool]:
    return lambda: bool(counts[key] >= n)


def _compass_done(counts: Any, compass: Any, headings: int, lines: int) -> Callable[[], bool]:
    return lambda: bool(counts["CompassHeading"] >= headings and compass.parser.lines >= lines)


def _date(text: str) -> Any:
    import datetime as dt

    return dt.date.fromisoformat(text)


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


def _live_voice(clock: Callable[[], float]) -> Any:
    """A live voice if this machine can speak; None otherwise (the prompts are printed anyway)."""
    from guidance.voice import make_speaker
    from guidance.voice.speakers import TextSpeaker

    spk = make_speaker("voice", clock=clock, text_stream=io.StringIO())
    if isinstance(spk, TextSpeaker):
        spk.close()
        return None
    return spk


def run_drive(
    opts: DriveOptions,
    printer: Callable[[str], None] | None = None,
    app_config: Any = None,
    on_progress: Callable[[float], None] | None = None,
) -> DriveResult:
    return asyncio.run(drive_async(opts, printer, app_config, on_progress))


# ----------------------------------------------------------------------------- CLI


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
        choices=("straight_to_goal", "landmark_to_landmark", "hybrid"),
        help="navigation method (default hybrid)",
    )
    p.add_argument(
        "--compass-deg",
        type=_compass_arg,
        default="20",
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
        help="the simulated co-driver reports the next intersection M metres ahead (30)",
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
    p.set_defaults(func=_cli_sim, compass_given=None)


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
    if "--compass-deg" in " ".join(sys.argv) or app_config is None:
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

    def printer(line: str) -> None:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()

    result = run_drive(opts, printer, app_config)
    print_summary(result, opts)
    if args.json:
        sys.stdout.write(json.dumps(result.to_json()) + "\n")
    sys.stdout.flush()
    return 0


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
