"""``guidance run``: the in-car process. Load the config, build the devices by name, open the
outputs (``guidance.app.build``, shared with the simulated drive), resume from a checkpoint,
and guide until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import atexit
import contextlib
import logging
import os
import signal
import stat
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from guidance.app.app import GIL_SWITCH_INTERVAL_S, App
from guidance.app.backends import import_backend
from guidance.app.build import OutputSettings, open_outputs, session_record, start_checkpoints
from guidance.app.landmarks import landmark_warnings, open_landmarks
from guidance.app.operator_session import SCREEN_MODES, OperatorSession
from guidance.app.screen import banner_rows
from guidance.errors import UserError

if TYPE_CHECKING:
    from guidance.app.app import Source
    from guidance.app.config import AppConfig, SceneSettings
    from guidance.app.ports import CameraSource, Recogniser
    from guidance.core.pipeline import Pipeline

log = logging.getLogger(__name__)

DeviceRunner = Callable[..., int]
"""``runner(config_path, *, as_json, screen)``: ``guidance run`` on devices the product does
not build itself; ``screen`` is the ``--screen`` mode (``SCREEN_MODES``), "off" with
``as_json`` (the prompts and the result as JSON, no operator screen). The ``guidance`` command
names them in its table (``guidance.tools.cli.DEVICE_RUNNERS``: "sim" for a config whose
``[sim]`` table says ``devices = true``), so the product never names the simulator's package
(ARCHITECTURE.md: the product does not import the simulator)."""


def stdin_problem(stream: TextIO | None) -> str:
    """Why co-driver lines cannot come from ``stream`` (stdin), or "" when they can: a
    terminal, a pipe or a file can; /dev/null (what systemd gives a service) cannot."""
    try:
        fd = stream.fileno() if stream is not None else -1
        if fd < 0:
            return "there is no stdin"
        if os.isatty(fd):
            return ""
        st = os.fstat(fd)
    except (OSError, ValueError):
        return "stdin is closed"
    if stat.S_ISFIFO(st.st_mode) or stat.S_ISREG(st.st_mode):
        return ""
    if stat.S_ISCHR(st.st_mode) and st.st_rdev == os.stat(os.devnull).st_rdev:
        return "stdin is /dev/null (as under systemd)"
    return "stdin is not a terminal"


def co_driver_problem(scene: SceneSettings, stdin: TextIO | None) -> str:
    """Why the configured co-driver input will not work now, or ""."""
    if scene.input == "none":
        return "[scene] input = 'none'"
    if scene.input == "evdev":
        return "" if os.path.exists(scene.device) else f"input device {scene.device} not found"
    if scene.input == "speech":
        return ""  # the microphone's health says whether it hears
    problem = stdin_problem(stdin)
    return f"{problem}; name a keypad in [scene] (input = 'evdev', device)" if problem else ""


async def run_car(
    config_path: str,
    *,
    resume: bool = True,
    screen: str = "auto",
    stdout: TextIO | None = None,
) -> int:
    """``guidance run``: open the configured devices and guide until SIGINT/SIGTERM.

    ``screen``: the operator screen on ``stdout`` ("auto": live on a terminal, plain lines
    otherwise; "live", "plain", "off")."""
    from guidance.app.config import load_config
    from guidance.app.watchdog import SystemdNotifier
    from guidance.core.messages import GoalUpdate

    cfg = load_config(config_path)
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    pipeline, recogniser = await build_pipeline(cfg)
    checkpointer = start_checkpoints(
        pipeline,
        cfg.checkpoint.path,
        interval_s=cfg.checkpoint.interval_s,
        max_age_s=cfg.checkpoint.max_age_s,
        vehicle_id=cfg.vehicle_id,
        resume=resume,
    )
    learned_lock = _lock_learned(cfg)
    learned = _start_learned(
        cfg, pipeline, resumed=checkpointer is not None and checkpointer.resumed
    )
    session = OperatorSession(cfg, pipeline, screen=screen, stream=stdout)
    sources, camera = build_devices(cfg, session, lambda: pipeline.estimate.heading_rad)
    no_input = co_driver_problem(cfg.scene, sys.stdin)
    settings = output_settings(cfg, pipeline)
    stop = asyncio.Event()
    app: App | None = None

    def on_goal(x_m: float, y_m: float) -> None:
        if app is not None:
            app.feed(GoalUpdate(time.monotonic(), x_m, y_m, "remote"))

    async with open_outputs(settings, time.monotonic, on_goal=on_goal) as out:
        speaker = session.attach(out.speaker)
        voice = type(out.speaker).__name__ if out.speaker is not None else "none"
        co_driver = {
            "evdev": f"keypad {cfg.scene.device}",
            "keyboard": "keyboard (stdin)",
            "speech": f"microphone {cfg.scene.microphone}",
        }.get(cfg.scene.input, "none")
        if cfg.scene.speech:
            co_driver += f" + microphone {cfg.scene.microphone} (talk: {cfg.scene.talk_mode})"
        if no_input:
            co_driver += f" - NOT AVAILABLE: {no_input}"
        app = App(
            pipeline,
            sources=sources,
            camera=camera,
            recogniser=recogniser,
            speaker=speaker,
            sinks=out.sinks,
            notifier=SystemdNotifier(max_lag_s=cfg.loop.max_lag_s),
            checkpointer=checkpointer,
            loop=cfg.loop,
        )
        app.stop_event = stop
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        if session.on:
            app.listeners.append(session.operator)
        if no_input:
            session.no_co_driver(no_input)
        keeper = asyncio.create_task(
            _keep_learned(cfg, pipeline, learned, stop, held=learned_lock is not None)
        )
        try:
            session.start(
                banner_rows(cfg, voice=f"{cfg.voice.backend} ({voice})", co_driver=co_driver)
            )
            await app.run_until_stopped()
        finally:
            session.stop()
            keeper.cancel()
        app.save_checkpoint(time.monotonic(), finished=True)  # a clean stop: not resumed
        if learned_lock is not None:
            _save_learned(cfg, pipeline, learned)
            learned_lock.release()
        log.info("%s", stop_line(app.lag_summary()))
    return 0


async def build_pipeline(cfg: AppConfig) -> tuple[Pipeline, Recogniser | None]:
    """The car's pipeline, with the landmark database's landmarks and its matcher when one is
    configured (opened off the event loop: it reads the whole database)."""
    from guidance.core.pipeline import Pipeline

    recogniser = None
    pcfg = cfg.pipeline
    if cfg.landmark_db is not None:
        recogniser, landmarks = await asyncio.get_running_loop().run_in_executor(
            None, open_landmarks, cfg.landmark_db, cfg.origin_lat_lon_deg
        )
        pcfg = replace(pcfg, landmarks=landmarks)
        log.info("landmarks: %d from %s", len(landmarks), cfg.landmark_db.database)
    return Pipeline(pcfg), recogniser


def build_devices(
    cfg: AppConfig, session: OperatorSession, heading_fn: Callable[[], float]
) -> tuple[dict[str, Source], CameraSource | None]:
    """The device table: every configured input by the name the pipeline judges it under
    (odometry, compass, and the co-driver's "scene", its keys acknowledged on the operator
    screen), and the camera. Each is built (its config checked) before anything starts."""
    sources: dict[str, Source] = {}
    for name, device in (("odometry", cfg.odometry), ("compass", cfg.compass)):
        if device is not None:
            sources[name] = device.build()
    scene = session.co_driver_input(heading_fn)
    if scene is not None:
        sources["scene"] = scene
    speech = session.speech_beside(heading_fn)
    if speech is not None:
        sources["speech"] = speech
    camera = cfg.camera.build() if cfg.camera is not None else None
    return sources, camera


def output_settings(cfg: AppConfig, pipeline: Pipeline) -> OutputSettings:
    """The voice, telemetry and recording of the car, with the session record of its
    pipeline (what a replay rebuilds)."""
    return OutputSettings(
        voice_backend=cfg.voice.backend,
        wav_path=cfg.voice.wav_path,
        voice=cfg.voice.voice,
        rate_wpm=cfg.voice.rate_wpm,
        volume=cfg.voice.volume,
        device=cfg.voice.device,
        telemetry=cfg.telemetry,
        recording=cfg.recording,
        ros2=cfg.ros2,
        session=session_record(pipeline, cfg.path, can_profile=_can_profile(cfg)),
    )


def _can_profile(cfg: AppConfig) -> str | None:
    """The CAN profile the car's odometry decodes with (``/session``: what ``replay --raw``
    decodes the recorded frames with), None without CAN odometry."""
    profile = getattr(cfg.odometry.config, "profile", None) if cfg.odometry else None
    return profile if isinstance(profile, str) else None


def stop_line(lag: dict[str, float | None]) -> str:
    """The clean stop's one log line (INFO: a stop asked for is not a warning), readable."""

    def ms(key: str) -> str:
        v = lag.get(key)
        return "-" if v is None else f"{v:.1f} ms"

    return (
        f"stopped cleanly; event-loop lag p50 {ms('loop_lag_p50_ms')}, "
        f"p99 {ms('loop_lag_p99_ms')}, max {ms('loop_lag_max_ms')}"
    )


def _lock_learned(cfg: Any) -> Any:
    """The car's claim on its learned file for the whole drive (``LearnedLock``): a tool
    that would write it meanwhile (``calibrate --write``) refuses instead of being silently
    overwritten by the car's next save. None when there is no file, or when another process
    holds it (then this drive saves nothing, and says so once)."""
    from guidance.app.learned_file import LearnedBusy, LearnedLock

    if not cfg.checkpoint.learned_path:
        return None
    try:
        return LearnedLock.take(Path(cfg.checkpoint.learned_path))
    except LearnedBusy as exc:
        log.error("%s: this drive will not save what it learns", exc)
        return None


def _start_learned(cfg: Any, pipeline: Any, *, resumed: bool) -> Any:
    """``[checkpoint] learned_path``: a fresh start begins from the car's learned parameters
    (a resumed trip already carries them in its state). One log line either way."""
    from guidance.app.learned_file import counter_after_resume, start_from_learned

    if not cfg.checkpoint.learned_path:
        return None
    if resumed:  # the state carries what was learned; the file keeps its distance counter
        return counter_after_resume(
            Path(cfg.checkpoint.learned_path), cfg.vehicle_id, pipeline.estimate.odometer_m
        )
    used, note = start_from_learned(
        pipeline.localizer, Path(cfg.checkpoint.learned_path), cfg.vehicle_id, time.time()
    )
    (log.info if used is not None and "MOVES" not in note else log.warning)("%s", note)
    return used


async def _keep_learned(
    cfg: Any, pipeline: Any, before: Any, stop: asyncio.Event, *, held: bool
) -> None:
    """Every ``[checkpoint] learned_interval_s`` while the car drives (and holds the file's
    lock): what it has learned so far (taken on the loop, written off it: the write fsyncs)."""
    from guidance.app.learned_file import save_learned

    if not cfg.checkpoint.learned_path or not held:
        return
    path = Path(cfg.checkpoint.learned_path)
    loop = asyncio.get_running_loop()
    failing = False  # one ERROR line per run of failures, one line when saving works again
    while True:
        try:
            await asyncio.wait_for(stop.wait(), cfg.checkpoint.learned_interval_s)
            return  # the clean stop saves
        except TimeoutError:
            pass
        params = pipeline.localizer.learned(
            cfg.vehicle_id, time.time(), pipeline.estimate.odometer_m, before
        )
        if params is None:
            return  # the paper model learns nothing
        try:
            await loop.run_in_executor(None, save_learned, path, params)
        except OSError as exc:
            if not failing:
                log.error("learned parameters not saved to %s: %s (said once)", path, exc)
            failing = True
        else:
            if failing:
                log.info("learned parameters saved to %s again", path)
            failing = False


def _save_learned(cfg: Any, pipeline: Any, before: Any) -> None:
    """At a clean stop: what this drive taught the car, for the next one."""
    from guidance.app.learned_file import save_learned

    if not cfg.checkpoint.learned_path:
        return
    try:
        params = pipeline.localizer.learned(
            cfg.vehicle_id, time.time(), pipeline.estimate.odometer_m, before
        )
        if params is not None:  # the paper model learns nothing
            save_learned(Path(cfg.checkpoint.learned_path), params)
    except OSError as exc:
        log.error("learned parameters not saved to %s: %s", cfg.checkpoint.learned_path, exc)


# ----------------------------------------------------------------------------- CLI


def register(sub: Any) -> None:
    run = sub.add_parser(
        "run",
        help="guide the driver: the in-car application",
        description=(
            "Run the in-car application: wheel odometry, compass and camera from the devices in "
            "the TOML config, the pose estimator and navigator, voice prompts, Zenoh telemetry "
            "and MCAP recording. Stop with Ctrl-C (or SIGTERM)."
        ),
    )
    run.add_argument("--config", required=True, type=Path, help="the car's TOML configuration")
    run.add_argument("--check", action="store_true", help="validate the configuration and exit")
    run.add_argument(
        "--json",
        action="store_true",
        help="simulated devices ([sim] devices = true): no operator screen, the prompts and a "
        "summary as fast as the drive goes, the last line the result as JSON",
    )
    run.add_argument(
        "--fresh", action="store_true", help="ignore an existing checkpoint (start afresh)"
    )
    run.add_argument(
        "--screen",
        choices=SCREEN_MODES,
        default="auto",
        help="the operator screen on stdout: auto (live on a terminal, plain lines otherwise), "
        "live, plain or off",
    )
    run.set_defaults(func=_cli_run)


def _cli_run(args: argparse.Namespace) -> int:
    if args.check:
        from guidance.app.config import load_config

        cfg = load_config(args.config, require_goal=False)
        if not cfg.sim.get("devices", False):  # the simulator draws its own goal
            cfg = load_config(args.config)
        from guidance.app.checks import start_problems

        problems, notes = start_problems(args.config, cfg)  # files, folders, the CAN profile
        if problems:
            raise UserError("; ".join(problems))
        for line in notes:
            print(f"warning: {line}", file=sys.stderr)  # noqa: T201
        print(  # noqa: T201  (the command output)
            f"{args.config}: OK (vehicle {cfg.vehicle_id}, method "
            f"{cfg.pipeline.navigator.method.value})"
        )
        if cfg.scene.input == "evdev" and not os.path.exists(cfg.scene.device):
            print(  # noqa: T201
                f"warning: [scene] device {cfg.scene.device} does not exist now: no co-driver "
                "keys until it is plugged in",
                file=sys.stderr,
            )
        elif cfg.scene.input == "none":
            print("warning: [scene] input = 'none': no co-driver input", file=sys.stderr)  # noqa: T201
        db = cfg.landmark_db
        if cfg.sim.get("devices", False) and db is not None and not Path(db.database).exists():
            print(  # noqa: T201  (the simulated devices' runner builds it; not an error)
                f"note: [landmarks] database {os.path.normpath(db.database)} does not exist "
                "yet: the simulated devices build it on first use (about a minute)",
                file=sys.stderr,
            )
            return 0
        for line in landmark_warnings(cfg):
            print(f"warning: {line}", file=sys.stderr)  # noqa: T201
        return 0
    from guidance.app.config import load_config  # the file door says what is wrong with it

    global _end_without_finalizing
    _end_without_finalizing = True  # the program's entry ends the process (``end_process``)
    if load_config(args.config, require_goal=False).sim.get("devices", False):  # simulated city
        where = getattr(args, "device_runners", {}).get("sim")
        if where is None:
            raise UserError(
                f"{args.config}: [sim] devices = true, but this `guidance` command names no "
                "runner for simulated devices (guidance.tools.cli.DEVICE_RUNNERS)"
            )
        runner: DeviceRunner = import_backend(where)
        screen = "off" if args.json else args.screen  # --json: the prompts and the result
        return int(runner(str(args.config), as_json=args.json, screen=screen))
    return asyncio.run(run_car(str(args.config), resume=not args.fresh, screen=args.screen))


# ----------------------------------------------------------------------------- the exit

_end_without_finalizing = False


def end_process(code: int) -> None:
    """End the ``guidance run`` process with ``code`` once everything is flushed, without the
    interpreter's finalization (issue 23, item 8); returns at once after any other command.

    By now the run has closed everything in a defined order: the sources (each joins its
    reader thread), the operator screen, the checkpoint (written, fsynced), the speaker, the
    recorder and the Zenoh session (its callback threads joined), then ``asyncio.run`` joined
    the executor threads. What may still run are daemon threads nothing can wake: a reader
    blocked in a terminal's ``readline``, a zenoh callback thread that missed its join, a
    camera inside OpenCV. Finalization would kill each of them with ``pthread_exit`` the
    next time it takes the GIL; inside zenoh's pyo3 trampoline (or OpenCV's ``catch (...)``)
    that forced unwind is swallowed and glibc aborts the process ("FATAL: exception not
    rethrown", SIGABRT, about 6 stops in 100): systemd saw a crash after a clean stop.
    So the exit does what a normal exit does first (threading's exit hooks, the non-daemon
    threads joined, ``atexit`` handlers: the logging flush among them), flushes stdout and
    stderr, and ends with ``os._exit``: nothing is left for finalization but freeing memory.
    """
    global _end_without_finalizing
    if not _end_without_finalizing:
        return
    _end_without_finalizing = False
    left = [t.name for t in threading.enumerate() if t.daemon and t.is_alive()]
    if left:
        log.debug("exiting with daemon threads left: %s", ", ".join(left))
    shutdown = getattr(threading, "_shutdown", None)  # what Py_FinalizeEx calls first
    if shutdown is not None:
        shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)
