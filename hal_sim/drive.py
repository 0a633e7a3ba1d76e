"""``guidance sim``: a simulated drive through the full in-car stack (issue 4, ``make demo``).

The simulated world (``hal_sim.sim_world.SimWorld``) drives the truth. Its wheel speeds go out
as CAN frames encoded with the reference car's DBC on a python-can virtual bus
(``SimCanWheels``) and come back through the real ``CanOdometry`` driver; its compass headings
go out as NMEA sentences into a pseudo-terminal (``SimCompassPty``) read by the real
``SerialCompass``; the roadway scene comes from the city graph (``SimScene``); landmark fixes
come from the world's sighting events (``SimSightings``, a stand-in for camera + matcher), or,
with ``--camera``, from simulated camera frames through the real recogniser. The outputs are
opened by the car's own ``guidance.app.build.open_outputs``, and the ``App`` and ``Pipeline``
are the ones ``guidance run`` uses.

``SimDrive`` holds one drive: ``run`` opens the devices and the outputs, then steps the world;
each step's frames and sentences are sent, then the simulation waits until the app has
processed them (``hal_sim.lockstep``), so the drive is reproducible for a seed however fast
the machine is, and ``--speed``/``--realtime`` only pace it against the wall clock. The
command's flags and summary are ``hal_sim.sim_cli``.
"""

from __future__ import annotations

import asyncio
import copy
import logging
import math
import time
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drivers.can_odometry import MAX_GAP_S
from guidance.app.app import App
from guidance.app.build import OpenOutputs, open_outputs, session_record
from guidance.app.checkpoint import INVALID, Checkpointer, resume_from_checkpoint
from guidance.app.magnetic import declination_deg
from guidance.core.messages import GoalUpdate
from guidance.core.pipeline import Input, Pipeline, PipelineConfig
from guidance.core.pipeline import Outputs as PipelineOutputs
from guidance.core.plan.chance import ChanceSettings
from guidance.core.plan.navigator import Landmark, Method, NavigatorConfig
from guidance.errors import UserError
from hal_sim.car_inputs import DeviceWire
from hal_sim.drive_options import DriveOptions, DriveResult, output_settings, wav_has_speech
from hal_sim.lockstep import LockstepClock, LockstepSink, recognise_now
from hal_sim.params import SimParams, estimator_config
from hal_sim.plots import DriveTrace, plot_drive
from hal_sim.sim_camera import SIM_ORIGIN
from hal_sim.sim_checks import check_drive_options, stop_on_signals
from hal_sim.sim_run import SimDevices, open_sim_camera, open_sim_devices
from hal_sim.sim_screen import SimScreen
from hal_sim.sim_world import SimWorld, StepEvents, WorldSpec

if TYPE_CHECKING:
    from hal_sim.sim_camera import SimCamera
    from landmark_db.recognise import Recogniser

log = logging.getLogger(__name__)

SIM_ORIGIN_LAT_LON = (SIM_ORIGIN.lat_deg, SIM_ORIGIN.lon_deg)
"""Where the simulated city is placed for the magnetic declination (Ithaca, NY)."""
SIM_DATE = "2026-06-01"
ELLIPSE_EVERY_M = 150.0
TRACK_EVERY_S = 1.0


class SimDrive:
    """One simulated drive: the world and the pipeline (built and, from a checkpoint, resumed
    here), the devices and the car's outputs and ``App`` (opened by ``run``), and the trace of
    the drive for its picture."""

    app: App
    lockstep: LockstepSink
    dev: SimDevices
    wire: DeviceWire
    outputs: OpenOutputs

    def __init__(
        self,
        opts: DriveOptions,
        printer: Callable[[str], None] | None = None,
        app_config: Any = None,
        on_progress: Callable[[float], None] | None = None,
        screen: str = "off",
    ) -> None:
        self.wall0 = time.monotonic()
        check_drive_options(opts)  # one clear line before anything starts (hal_sim/sim_checks.py)
        self.opts, self.printer, self.on_progress = opts, printer, on_progress
        self.app_config = app_config
        self.method = _method(opts.method)
        self.field_protocol = opts.duration_s is not None
        self.end_t = math.inf if opts.duration_s is None else opts.duration_s
        base = app_config.pipeline if app_config is not None else None  # the TOML's car
        self.world = world = make_world(opts, base.navigator if base is not None else None)
        self.clock = LockstepClock(lambda: world.t_s)
        """The simulated clock: the message clock of the drive, stepped with the world."""
        # Compile the numba step now, on a copy, before any replay: the copy draws from numba's
        # one random generator, so a fresh drive and a resumed one must draw it at the same point.
        copy.deepcopy(world).step()
        self.origin = SIM_ORIGIN_LAT_LON
        if app_config is not None and app_config.origin_lat_lon_deg is not None:
            self.origin = app_config.origin_lat_lon_deg
        self.decl = sim_declination_deg(self.origin)
        self.camera: SimCamera | None = None
        self.recogniser: Recogniser | None = None
        landmarks: tuple[Landmark, ...] = world.landmarks()
        if opts.camera_hz is not None:
            self.camera, self.recogniser, landmarks = open_sim_camera(world, opts, Path(opts.out))
        self.pipeline_config = drive_pipeline_config(world, opts, landmarks, self.decl, base)
        self.pipeline = Pipeline(self.pipeline_config)
        self.screen: SimScreen | None = None  # the operator screen (guidance run, not --json)
        if screen != "off" and app_config is not None:
            self.screen = SimScreen(app_config, self.pipeline, screen, self.clock)
        self.cap_m = drive_cap_m(world, opts)
        self.trace = DriveTrace()
        self.checkpointer: Checkpointer | None = None
        self.resumed_at: float | None = None
        if opts.checkpoint:
            self._resume(opts.checkpoint)
        self.prompt_log: list[tuple[float, str]] = []
        self.health_warnings: list[str] = []
        self.goals_reached = 0
        self.chances: list[float] = []
        """The car's chance of reaching the goal, with each state it published."""
        self.expect_odo = self.expect_heading = self.expect_lines = 0
        self.last_can_t: float | None = None
        self.next_track_t = self.next_frame_t = world.t_s
        self.next_ellipse_m = self.pipeline.estimate.odometer_m
        self.next_progress_t = 0.0
        self.pace0 = (time.monotonic(), world.t_s)

    # -- the drive ------------------------------------------------------------------------------
    async def run(self) -> DriveResult:
        """Open the devices and the outputs, drive, close everything; the drive's result."""
        try:
            compass = self.opts.compass_deg is not None
            with open_sim_devices(self.world, self.opts.profile, self.clock, compass=compass,
                                  drive_on_seed=self.opts.seed) as d:  # fmt: skip
                self.dev = d
                self.wire = DeviceWire(self.decl, can_silent=self.opts.can_silent,
                                       compass_garbage=self.opts.compass_garbage,
                                       wheels=d.wheels)  # fmt: skip
                sim = {"seed": self.opts.seed, "method": self.method.value}
                session = session_record(self.pipeline, self.opts.config or "", sim=sim,
                                         can_profile=self.opts.profile)  # fmt: skip
                settings = output_settings(self.opts, self.app_config, self.origin, session)
                async with open_outputs(settings, self.clock, on_goal=self._remote_goal) as outputs:
                    self.outputs = outputs
                    self._build_app()
                    if self.screen is not None:
                        voice = type(outputs.speaker).__name__ if outputs.speaker else "none"
                        self.screen.start(d, self.opts, voice)
                    try:
                        async with self.app.running():
                            outcome = await self._drive()
                            self._track_point()
                            self.app.save_checkpoint(self.world.t_s)
                    finally:
                        if self.screen is not None:
                            self.screen.stop()
                    lag_ms = self.app.lag_summary()
        finally:
            if self.recogniser is not None:
                self.recogniser.close()
        return self._result(outcome, lag_ms)

    async def _drive(self) -> str:
        """One world step at a time, each step's inputs processed before the next; the
        outcome."""
        stop_signal = stop_on_signals()  # SIGINT/SIGTERM: end with the summary
        compass = self.dev.compass
        if compass is not None and not await self.lockstep.wait_until(
            lambda: compass.connected, 5.0
        ):
            raise UserError("the simulated compass pty did not open")
        p, world = self.pipeline, self.world
        outcome = self._end_state() if p.finished else "timeout"
        self.pace0 = (time.monotonic(), world.t_s)
        first_step = world.step_count
        while not p.finished:
            if stop_signal.is_set():
                return "stopped"
            ev = world.step()
            if ev.step == first_step + 10:  # lag figures without the start-up (JIT load)
                self.app.loop_lag_s.clear()
            await self._send_wheels(ev)
            await self._send_compass(ev)
            await self._landmark(ev)
            self._tick(ev.t_s)
            if p.finished:
                return self._end_state()
            self._progress(ev.t_s)
            if await self._field_protocol(ev.t_s):
                return "time_limit"
            if world.driven_m >= self.cap_m:
                return "timeout"
            await self._follow_scene(ev)
            await self._pace(ev.t_s)
        return outcome

    def _remote_goal(self, x_m: float, y_m: float) -> None:
        """A remote goal the telemetry accepted (on the loop): fed to the car as in
        ``guidance run``, at the simulated time; the world's own goal (its plot, the field
        protocol's next one) stays as it was."""
        app = getattr(self, "app", None)
        if app is None:
            log.warning("remote goal (%.1f, %.1f) m before the car was built: ignored", x_m, y_m)
            return
        app.feed(GoalUpdate(self.world.t_s, x_m, y_m, "remote"))

    def _end_state(self) -> str:
        return "arrived" if self.pipeline.arrived else "lost"

    # -- one step -------------------------------------------------------------------------------
    async def _send_wheels(self, ev: StepEvents) -> None:
        """Wheel speeds -> CAN frames -> CanOdometry -> pipeline (unless CAN is silenced)."""
        t = ev.t_s
        frames = self.wire.can_frames(t, ev.left_mps, ev.right_mps)
        if not frames:
            return
        self.dev.wheels.send_frames(frames)
        if self.last_can_t is not None and t - self.last_can_t <= MAX_GAP_S:
            self.expect_odo += 1
            counts, n = self.app.counts, self.expect_odo
            if not await self.lockstep.wait_until(lambda: counts["WheelOdometry"] >= n, 2.0):
                log.warning("t=%.1f s: odometry frame not delivered", t)
                self.expect_odo = counts["WheelOdometry"]
        self.last_can_t = t

    async def _send_compass(self, ev: StepEvents) -> None:
        """Compass heading -> NMEA on the pty (or garbage) -> SerialCompass -> pipeline."""
        pty, compass = self.dev.pty, self.dev.compass
        if pty is None or compass is None or ev.heading_rad is None:
            return
        self.expect_lines += 1
        line, heading = self.wire.compass_line(ev.t_s, ev.heading_rad)
        pty.write_line(line, sentence=heading)
        self.expect_heading += heading
        counts, headings, lines = self.app.counts, self.expect_heading, self.expect_lines
        if not await self.lockstep.wait_until(
            lambda: counts["CompassHeading"] >= headings and compass.parser.lines >= lines, 2.0
        ):
            log.warning("t=%.1f s: compass sentence not delivered", ev.t_s)
            self.expect_heading = counts["CompassHeading"]
            self.expect_lines = compass.parser.lines

    async def _landmark(self, ev: StepEvents) -> None:
        """A camera frame through the real recogniser, or else the world's sighting event."""
        if self.camera is not None:
            await self._camera_frame(ev.t_s)
        elif ev.landmark is not None:
            self.dev.sightings.sighted(ev.t_s, ev.landmark, relocalised=self.pipeline.searching)
            await self.lockstep.drained()

    async def _camera_frame(self, t: float) -> None:
        """At ``camera_hz``: what the car sees now, matched at once by the app's recogniser
        (off the loop, in lockstep)."""
        if self.camera is None or t < self.next_frame_t:
            return
        self.next_frame_t = t + 1.0 / (self.opts.camera_hz or 1.0)
        x, y, _ = self.world.truth
        await recognise_now(self.app, self.camera.frame_at(t, x, y))

    def _tick(self, t: float) -> None:
        """The app's time-driven work, the true pose recorded, the trace for the picture."""
        self.clock.tick()
        if self.outputs.recorder is not None:  # the true pose, on its own topics (rate-limited)
            self.outputs.recorder.record_truth(t, *self.world.truth)
        self._track(t)

    def _track(self, t: float) -> None:
        p, trace = self.pipeline, self.trace
        if t >= self.next_track_t:
            self.next_track_t = t + TRACK_EVERY_S
            self._track_point()
            est = p.estimate
            trace.axis.append((est.odometer_m, est.ellipse.major_axis_m))
        est = p.estimate
        if est.odometer_m >= self.next_ellipse_m:
            self.next_ellipse_m = est.odometer_m + ELLIPSE_EVERY_M
            c = est.covariance
            trace.ellipses.append((est.x_m, est.y_m, [list(c[0][:2]), list(c[1][:2])]))

    def _track_point(self) -> None:
        tx, ty, _ = self.world.truth
        est = self.pipeline.estimate
        self.trace.truth.append((tx, ty))
        self.trace.est.append((est.x_m, est.y_m))

    def _progress(self, t: float) -> None:
        if self.on_progress is not None and t >= self.next_progress_t:
            self.next_progress_t = t + 60.0
            self.on_progress(t)

    async def _field_protocol(self, t: float) -> bool:
        """SPEC 5: on arrival a new random goal; True once the time limit is reached."""
        if not self.field_protocol:
            return False
        if self.pipeline.arrived:
            self.goals_reached += 1
            self.world.new_goal()
            gx, gy = self.world.goal_xy
            self.app.feed(GoalUpdate(t, gx, gy, "field_protocol"))
            await self.lockstep.drained()
        return t >= self.end_t

    async def _follow_scene(self, ev: StepEvents) -> None:
        """The co-driver: the intersection ahead reported once in view (and the one after it
        when that is in view too), its distance as the car approaches, the advice taken."""
        scene, p = self.dev.scene, self.pipeline
        scene.update(ev)
        msg = scene.due_report(ev)
        before = p.reports
        if msg is not None:
            scene.send(msg)
            await self.lockstep.drained()
            if p.reports > before:  # taken (not refused for want of a heading)
                scene.reported(p.last_report_seq)
        scene.follow(p.planned_exit)
        msg = scene.due_next(ev)
        before = p.reports
        if msg is not None:
            scene.send(msg)
            await self.lockstep.drained()
            if p.reports > before:
                scene.reported_next(p.last_report_seq)

    async def _pace(self, t: float) -> None:
        """``--speed``: simulated seconds per wall second."""
        if self.opts.speed is not None:
            wall0, sim0 = self.pace0
            ahead = (t - sim0) / self.opts.speed - (time.monotonic() - wall0)
            if ahead > 0:
                await asyncio.sleep(ahead)

    def _on_output(self, _msg: Input | None, out: PipelineOutputs) -> None:
        """The app's listener: prompts printed and logged, health warnings, fixes traced."""
        for prompt in out.prompts:
            self.prompt_log.append((prompt.t_s, prompt.text))
            if self.printer is not None:
                self.printer(f"[{prompt.t_s:7.1f} s] {prompt.text}")
        for h in out.health:
            st = h.status
            if not (st.alive and st.valid):
                self.health_warnings.append(f"{h.t_s:.1f} s {st.name}: {st.detail}")
        if out.chance is not None:
            self.chances.append(out.chance)
        p = self.pipeline
        for fix in out.landmark_updates:
            est = p.estimate
            self.trace.fixes.append((est.odometer_m, est.x_m, est.y_m, fix.landmark_id))
            self.trace.axis.append((est.odometer_m, est.ellipse.major_axis_m))

    # -- building -------------------------------------------------------------------------------
    def _build_app(self) -> None:
        """The car's ``App`` on the simulated devices, ticked by the drive (its clock is the
        drive's ``LockstepClock``), in lockstep."""
        out, screen = self.outputs, self.screen
        self.app = App(
            self.pipeline,
            sources=self.dev.sources() | (screen.sources() if screen is not None else {}),
            recogniser=self.recogniser,
            speaker=screen.speaker(out.speaker) if screen is not None else out.speaker,
            sinks=out.sinks,
            checkpointer=self.checkpointer,
            clock=self.clock,
        )
        if self.checkpointer is not None:
            self.checkpointer.extra = self._extra_state  # the world, for a resumed drive
        self.app.listeners.append(self._on_output)
        self.lockstep = self.app.wrap_source_sink(LockstepSink)  # the world waits for the app
        if screen is not None:
            screen.listen(self.app)

    # -- checkpoints ----------------------------------------------------------------------------
    def _resume(self, path: str) -> None:
        """The drive's own checkpoint on the car's resume mechanics
        (``checkpoint.resume_from_checkpoint``), with the simulator's policy: same seed and
        method only (else the run is refused), the pipeline restored (every value checked
        first), the world replayed to its step; a bad file moved aside, and the run refused in
        one line."""
        self.checkpointer = Checkpointer(path, self.opts.checkpoint_interval_s)
        done = resume_from_checkpoint(path, self._restore, policy=partial(self._same_drive, path))
        if done.outcome == INVALID:
            raise UserError(
                f"checkpoint {path} cannot be resumed ({done.why}); it was moved "
                "aside: run again to start afresh"
            )
        if done.resumed:
            self.resumed_at = self.world.t_s
            log.warning("resumed from checkpoint %s at t=%.1f s", path, self.resumed_at)

    def _same_drive(self, path: str, doc: dict[str, Any]) -> str:
        """The policy: a checkpoint of this drive's seed and method is resumed (""); another
        drive's refuses the run."""
        extra = doc.get("extra")
        extra = extra if isinstance(extra, dict) else {}
        if extra.get("seed") != self.opts.seed or extra.get("method") != self.method.value:
            raise UserError(
                f"checkpoint {path} is for seed {extra.get('seed')} "
                f"method {extra.get('method')}; delete it or use the same options"
            )
        return ""

    def _restore(self, doc: dict[str, Any]) -> None:
        """The pipeline, then the world replayed to the checkpoint's step and the trace."""
        extra = doc["extra"]
        self.pipeline.restore(doc["pipeline"])  # checked first: a bad value changes nothing
        self.world.replay_to(int(extra["step"]), extra["route"])
        self.trace.truth = [(float(a), float(b)) for a, b in extra.get("track_truth", [])]
        self.trace.est = [(float(a), float(b)) for a, b in extra.get("track_est", [])]

    def _extra_state(self) -> dict[str, Any]:
        w = self.world
        return {
            "seed": self.opts.seed,
            "method": self.method.value,
            "step": w.step_count,
            "route": [list(r) for r in w.route],
            "track_truth": [list(p) for p in self.trace.truth],
            "track_est": [list(p) for p in self.trace.est],
        }

    def _result(self, outcome: str, lag_ms: dict[str, float | None]) -> DriveResult:
        opts, world, recorder = self.opts, self.world, self.outputs.recorder
        tx, ty, _ = world.truth
        est = self.pipeline.estimate
        png = None
        if opts.png:
            png = str(Path(opts.out) / f"drive-seed{opts.seed}.png")
            plot_drive(png, world, self.trace, outcome, opts)
        return DriveResult(
            outcome=outcome,
            driven_km=world.driven_m / 1000.0,
            final_error_m=math.hypot(tx - est.x_m, ty - est.y_m),
            prompts=self.pipeline.st.prompt_count,
            landmark_updates=self.pipeline.landmark_updates,
            relocalisations=self.pipeline.counts["relocalisations"],
            lost_episodes=self.pipeline.counts["lost_episodes"],
            decisions=self.pipeline.navigator.decisions,
            png=png,
            sim_s=world.t_s,
            wall_s=time.monotonic() - self.wall0,
            seed=opts.seed,
            method=self.method.value,
            wav=opts.voice_to if opts.voice_to and wav_has_speech(opts.voice_to) else None,
            recording=[str(p) for p in (recorder.files if recorder is not None else [])],
            resumed_at_s=self.resumed_at,
            health_warnings=self.health_warnings,
            prompt_log=self.prompt_log,
            loop_lag_p99_ms=lag_ms["loop_lag_p99_ms"],
            loop_lag_ms=lag_ms,
            goals_reached=self.goals_reached,
            chance_at_start=self.chances[0] if self.chances else None,
            lowest_chance=min(self.chances) if self.chances else None,
            frames_sent=self.dev.wheels.frames_sent,
            compass_lines=self.dev.pty.sentences_written if self.dev.pty is not None else 0,
        )


def sim_declination_deg(origin: tuple[float, float] = SIM_ORIGIN_LAT_LON) -> float:
    """The magnetic declination of a simulated drive at ``origin`` (the simulated city's
    place unless a car TOML names another), on ``SIM_DATE``."""
    return declination_deg(origin[0], origin[1], _date(SIM_DATE))


def make_world(opts: DriveOptions, navigator: NavigatorConfig | None = None) -> SimWorld:
    """The simulated city and car of a drive's options (the seed fixes both); ``navigator``:
    the configured car's (``[navigation]``), with the drive's method."""
    sim = SimParams(decision_distance_m=opts.decision_distance_m)
    est_cfg = estimator_config(sim, opts.compass_deg)
    nav_cfg = replace(navigator or NavigatorConfig(), method=_method(opts.method))
    spec = WorldSpec(opts.seed, opts.area_km2, opts.goal_min_m, opts.goal_max_m,
                     opts.density_per_km2, opts.detection_rate)  # fmt: skip
    return SimWorld(spec, sim, est_cfg, nav_cfg)


def drive_pipeline_config(
    world: SimWorld,
    opts: DriveOptions,
    landmarks: tuple[Landmark, ...],
    declination_deg: float,
    base: PipelineConfig | None = None,
) -> PipelineConfig:
    """The car's pipeline for a simulated drive: the configured car (``base``, the TOML's
    pipeline: its ``[navigation]``, ``[health]``, turn detector, units and state rate; else
    the defaults) on the world's sensors: the world's filter settings (its noise is the
    world's), navigator, start and goal, the landmarks the car knows, the simulated compass's
    (uncalibrated, true-mounted) readings and the simulated devices' rates."""
    sx, sy, th0 = world.start_pose
    if opts.start_unknown:  # the car is not told: it waits at the goal, city-wide
        sx, sy = world.goal_xy
    rates: dict[str, float | None] = {"odometry": 1.0 / world.dt_s}
    if opts.compass_deg is not None:
        rates["compass"] = world.sim.compass_rate_hz
    world_fields: dict[str, Any] = {
        "estimator": world.est,
        "navigator": world.nav,
        "start_xy_m": (sx, sy),
        "goal_xy_m": world.goal_xy,
        "start_heading_rad": th0,
        "landmarks": landmarks,
        "declination_deg": declination_deg,
        "mounting_offset_deg": 0.0,
        "compass_deviation_deg": (),
        "expected_rates_hz": rates,
        "stop_at_arrival": opts.duration_s is None,
        "relocalise": opts.relocalise and opts.density_per_km2 > 0.0,
        "start_unknown": opts.start_unknown,
        # the car knows its matcher's recall: the world's detection rate
        "chance": replace(
            base.chance if base is not None else ChanceSettings(),
            detection_rate=opts.detection_rate,
        ),
    }
    if base is None:
        return PipelineConfig(**world_fields)
    return replace(base, **world_fields)


def drive_cap_m(world: SimWorld, opts: DriveOptions) -> float:
    """How far a drive may go before it ends as a timeout (a multiple of the Manhattan
    distance to the goal; none on the field protocol)."""
    if opts.duration_s is not None:
        return math.inf
    (sx, sy, _), (gx, gy) = world.start_pose, world.goal_xy
    return opts.cap_factor * (abs(gx - sx) + abs(gy - sy)) + opts.cap_extra_m


async def drive_async(
    opts: DriveOptions,
    printer: Callable[[str], None] | None = None,
    app_config: Any = None,
    on_progress: Callable[[float], None] | None = None,
    screen: str = "off",
) -> DriveResult:
    """Run one simulated drive; ``printer`` receives one line per prompt, ``on_progress`` the
    simulated time about once per simulated minute; ``screen`` (with ``app_config``): the
    operator screen of ``guidance run`` (``SCREEN_MODES``), "off" for none."""
    return await SimDrive(opts, printer, app_config, on_progress, screen).run()


def run_drive(
    opts: DriveOptions,
    printer: Callable[[str], None] | None = None,
    app_config: Any = None,
    on_progress: Callable[[float], None] | None = None,
    screen: str = "off",
) -> DriveResult:
    return asyncio.run(drive_async(opts, printer, app_config, on_progress, screen))


def _method(name: str) -> Method:
    try:
        return Method(name)
    except ValueError:
        raise UserError(
            f"--method must be one of {', '.join(m.value for m in Method)}, not {name!r}"
        ) from None


def _date(text: str) -> Any:
    import datetime as dt

    return dt.date.fromisoformat(text)
