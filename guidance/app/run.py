"""``guidance run``: the in-car process. Load the config, build the devices by name, open the
outputs (``guidance.app.build``, shared with the simulated drive), resume from a checkpoint,
and guide until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any

from guidance.app.app import GIL_SWITCH_INTERVAL_S, App, Source
from guidance.app.build import OutputSettings, open_outputs, resume_from_checkpoint, session_record
from guidance.app.checkpoint import Checkpointer, load_checkpoint
from guidance.errors import UserError

log = logging.getLogger(__name__)


async def run_car(config_path: str, *, resume: bool = True) -> int:
    """``guidance run``: open the configured devices and guide until SIGINT/SIGTERM."""
    from guidance.app.backends import SCENE_BACKENDS, import_backend
    from guidance.app.config import load_config
    from guidance.app.watchdog import SystemdNotifier
    from guidance.core.messages import GoalUpdate
    from guidance.core.pipeline import Pipeline

    cfg = load_config(config_path)
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    pipeline = Pipeline(cfg.pipeline)
    checkpointer = None
    if cfg.checkpoint.path:
        checkpointer = Checkpointer(cfg.checkpoint.path, cfg.checkpoint.interval_s)
        doc = load_checkpoint(cfg.checkpoint.path) if resume else None
        age_s = time.time() - float(doc.get("wall_time_unix_s", 0.0)) if doc else math.inf
        resume_from_checkpoint(pipeline, doc, age_s, cfg.checkpoint.max_age_s, cfg.checkpoint.path)
    # Devices are built (and their configs checked) before anything starts.
    sources: dict[str, Source] = {}
    if cfg.odometry is not None:
        sources["odometry"] = cfg.odometry.build()
    if cfg.compass is not None:
        sources["compass"] = cfg.compass.build()
    if cfg.keyboard:
        keyboard = import_backend(SCENE_BACKENDS["keyboard"])
        sources["scene"] = keyboard(lambda: float(pipeline.estimator.x[2]))
    camera = cfg.camera.build() if cfg.camera is not None else None

    settings = OutputSettings(
        voice_backend=cfg.voice.backend,
        wav_path=cfg.voice.wav_path,
        telemetry=cfg.telemetry,
        recording=cfg.recording,
        session=session_record(pipeline, cfg.path),
    )
    stop = asyncio.Event()
    app: App | None = None

    def on_goal(x_m: float, y_m: float) -> None:
        if app is not None:
            app.feed(GoalUpdate(time.monotonic(), x_m, y_m, "remote"))

    async with open_outputs(settings, time.monotonic, on_goal=on_goal) as out:
        app = App(
            pipeline,
            sources=sources,
            camera=camera,
            speaker=out.speaker,
            telemetry=out.telemetry,
            recorder=out.recorder,
            notifier=SystemdNotifier(max_lag_s=cfg.max_loop_lag_s),
            checkpointer=checkpointer,
            tick_hz=cfg.tick_hz,
            health_publish_period_s=cfg.health_publish_period_s,
            max_loop_lag_s=cfg.max_loop_lag_s,
        )
        app.stop_event = stop
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await app.run_until_stopped()
        log.warning("stopping: %s", json.dumps(app.lag_summary()))
    return 0


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
        "--fresh", action="store_true", help="ignore an existing checkpoint (start afresh)"
    )
    run.set_defaults(func=_cli_run)


def _cli_run(args: argparse.Namespace) -> int:
    if args.check:
        from guidance.app.config import load_config

        cfg = load_config(args.config)
        print(  # noqa: T201  (the command output)
            f"{args.config}: OK (vehicle {cfg.vehicle_id}, method "
            f"{cfg.pipeline.navigator.method.value})"
        )
        return 0
    if not args.config.is_file():
        raise UserError(f"config file not found: {args.config}")
    return asyncio.run(run_car(str(args.config), resume=not args.fresh))
