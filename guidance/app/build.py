"""Building the app's outputs and resuming its state: shared by ``guidance run`` and the
simulated drive (``hal_sim.drive``), so the simulator exercises the car's own wiring.

``open_outputs`` opens the speaker, telemetry and recorder a run asks for, writes the
recording's ``/session`` record, and closes all three on the way out (on an error too);
``resume_car`` is the car's checkpoint policy on the resume mechanics the simulator shares
(``guidance.app.checkpoint.resume_from_checkpoint``), and ``start_checkpoints`` the whole of it
for ``guidance run`` (identity, resume, the writer).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import AsyncIterator, Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from guidance.app.checkpoint import (
    Checkpointer,
    Resumption,
    checkpoint_age_s,
    resume_from_checkpoint,
    trip_identity,
)
from guidance.app.ports import Speaker
from guidance.errors import UserError

if TYPE_CHECKING:
    from guidance.app.ports import OutputSink
    from guidance.core.pipeline import Pipeline
    from guidance.recording.config import RecordingConfig
    from guidance.recording.writer import Recorder
    from guidance.telemetry.config import Ros2Config, TelemetryConfig
    from guidance.telemetry.publisher import Telemetry
    from guidance.telemetry.ros2 import Ros2Sink

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OutputSettings:
    """What to open: each part is optional."""

    voice_backend: str = "none"
    """auto, pico, espeak, voice, wav, text or none (``guidance.voice.make_speaker``)."""
    wav_path: str = ""
    voice: str = "en"
    rate_wpm: int = 170
    volume: float = 1.0
    device: str = "default"
    """The ALSA playback device of a live voice."""
    telemetry: TelemetryConfig | None = None
    recording: RecordingConfig | None = None
    ros2: Ros2Config | None = None
    """``[ros2] enabled``: one more sink, the estimate as ROS 2 messages (telemetry/ros2.py)."""
    session: dict[str, Any] | None = None
    """The recording's /session record (``session_record``)."""
    drain_speech: bool = False
    """On close, let the speaker finish what is queued (a WAV file) instead of cutting it."""
    speaker_factory: Callable[[Callable[[], float]], Speaker | None] | None = None
    """Builds the speaker instead of ``voice_backend`` (the simulator's "voice if it can")."""


@dataclass
class OpenOutputs:
    speaker: Speaker | None = None
    telemetry: Telemetry | None = None
    recorder: Recorder | None = None
    ros2: Ros2Sink | None = None

    @property
    def sinks(self) -> list[OutputSink]:
        """Where the outputs go (``App(sinks=...)``): telemetry, the recorder, ROS 2."""
        return [s for s in (self.telemetry, self.recorder, self.ros2) if s is not None]


def build_speaker(
    backend: str,
    wav_path: str,
    clock: Callable[[], float],
    *,
    voice: str = "en",
    rate_wpm: int = 170,
    volume: float = 1.0,
    device: str = "default",
) -> Speaker | None:
    """The configured voice (``none`` for no speaker)."""
    if backend == "none":
        return None
    from guidance.voice import SPEAKER_KINDS, make_speaker

    kind = next((k for k in SPEAKER_KINDS if k == backend), None)
    if kind is None:
        names = ", ".join((*SPEAKER_KINDS, "none"))
        raise UserError(f"[voice] backend must be one of {names}, not {backend!r}")
    return make_speaker(
        kind,
        wav_path or None,
        clock=clock,
        voice=voice,
        rate_wpm=rate_wpm,
        volume=volume,
        device=device,
    )


def session_record(pipeline: Pipeline, config_path: str = "", **extra: Any) -> dict[str, Any]:
    """What replay needs to rebuild the pipeline: its configuration as plain data."""
    return {
        "schema": "guidance.session/1",
        "config_path": config_path,
        "pipeline": pipeline.config.describe(),
        **extra,
    }


@contextlib.asynccontextmanager
async def open_outputs(
    settings: OutputSettings,
    clock: Callable[[], float],
    *,
    on_goal: Callable[[float, float], None] | None = None,
) -> AsyncIterator[OpenOutputs]:
    """Open the speaker, telemetry and recorder; close them all when the block ends."""
    out = OpenOutputs()
    try:
        if settings.speaker_factory is not None:
            out.speaker = settings.speaker_factory(clock)
        else:
            out.speaker = build_speaker(
                settings.voice_backend,
                settings.wav_path,
                clock,
                voice=settings.voice,
                rate_wpm=settings.rate_wpm,
                volume=settings.volume,
                device=settings.device,
            )
        if settings.telemetry is not None:
            from guidance.telemetry.publisher import Telemetry

            loop = asyncio.get_running_loop()
            out.telemetry = Telemetry(settings.telemetry, on_goal=on_goal, loop=loop)
            out.telemetry.start()
        if settings.ros2 is not None and settings.ros2.enabled:
            from guidance.telemetry.ros2 import Ros2Sink

            out.ros2 = Ros2Sink(settings.ros2)
            if settings.telemetry is not None:  # the same local frame as /state
                out.ros2.origin_lat_lon_deg = settings.telemetry.origin_lat_lon_deg
            out.ros2.start()
        if settings.recording is not None:
            from guidance.recording.writer import Recorder

            out.recorder = Recorder(settings.recording)
            out.recorder.start()
            if settings.session is not None:
                out.recorder.record("/session", clock(), settings.session)
        yield out
    finally:
        if out.speaker is not None:
            with contextlib.suppress(Exception):
                out.speaker.close(drain=settings.drain_speech)
        if out.recorder is not None:
            out.recorder.close()
        if out.telemetry is not None:
            out.telemetry.close()
        if out.ros2 is not None:
            out.ros2.close()


def resume_car(
    pipeline: Pipeline,
    path: str,
    identity: Mapping[str, Any],
    max_age_s: float,
    *,
    now_unix_s: float | None = None,
) -> Resumption:
    """The car's resume policy on the shared mechanics (``checkpoint.resume_from_checkpoint``):
    this vehicle's trip only (``identity``). Too old (or from the future): start afresh.
    Otherwise restore, on a fresh message clock (the laptop's monotonic clock may have
    restarted), and widen the position by what the last speed covers in the downtime: the car
    kept moving while the process was down."""
    now = time.time() if now_unix_s is None else now_unix_s
    age_s = math.inf

    def too_old(doc: dict[str, Any]) -> str:
        nonlocal age_s
        age_s = checkpoint_age_s(doc, now)
        if math.isfinite(age_s) and 0.0 <= age_s <= max_age_s:
            return ""
        log.warning(
            "checkpoint %s is %.0f s old (limit %.0f s): starting afresh", path, age_s, max_age_s
        )
        return "too old"

    def restore(doc: dict[str, Any]) -> None:
        pipeline.restore(doc["pipeline"], same_clock=False)

    done = resume_from_checkpoint(path, restore, expected=identity, policy=too_old)
    if done.resumed:
        spread = pipeline.estimate.speed_mps * age_s
        pipeline.localizer.widen(spread)
        log.warning(
            "resumed from checkpoint %s written %.1f s ago; position widened by %.0f m",
            path,
            age_s,
            spread,
        )
    return done


def start_checkpoints(
    pipeline: Pipeline,
    path: str,
    *,
    interval_s: float,
    max_age_s: float,
    vehicle_id: str,
    resume: bool = True,
) -> Checkpointer | None:
    """``guidance run``'s checkpoints: resume this vehicle's unfinished trip when the file
    allows it (else start afresh, a bad file moved aside), and the writer for this run."""
    if not path:
        return None
    identity = trip_identity(vehicle_id, pipeline.config.describe())
    ck = Checkpointer(path, interval_s, identity)
    ck.resumed = resume and resume_car(pipeline, path, identity, max_age_s).resumed
    return ck
