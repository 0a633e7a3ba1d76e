"""``guidance run``: the in-car application, one asyncio process (SPEC section 6, docs/app.md).

``App`` wires the hardware abstraction layer to the pure ``Pipeline``:

* each source (odometry, compass, scene, ...) runs its blocking I/O on its own thread and
  hands messages over with ``loop.call_soon_threadsafe``; the pipeline processes them on the
  loop in arrival order, and its outputs go to the speaker, Zenoh telemetry and the MCAP
  recorder (all non-blocking);
* camera frames go to a one-slot ring; the recogniser (``ports.Recogniser``:
  ``process(frame, state)`` -> a fix or a reason) matches the latest one in a worker thread,
  off the loop, and its fixes come back as pipeline inputs;
* a ticker task at absolute monotonic deadlines measures loop lag, pings the systemd watchdog,
  evaluates health (silent or garbled inputs), publishes health and writes checkpoints (the
  time-driven work, ``App.tick``; on a ``ports.SteppedClock`` its owner runs that instead,
  after each step of the clock);
* everything starts under one ``asyncio.TaskGroup`` and every device is released in a
  ``finally``.

The simulation (``hal_sim.drive``) builds the same ``App`` around simulated devices and
steps it in lockstep with the simulated world (``hal_sim.lockstep``: its clock is a stepped
clock, and it wraps the sources' sink: ``wrap_source_sink``); replay feeds the pipeline directly.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from functools import partial
from typing import TYPE_CHECKING, Any, TypeAlias, TypeVar

from guidance.app import ports
from guidance.app.checkpoint import Checkpointer
from guidance.app.logonce import LogOnce
from guidance.app.ports import InputRecorder, Notifier, NullRecogniser, Recogniser, Speaker
from guidance.app.settings import LoopSettings
from guidance.core.codec import to_record
from guidance.core.health import DeviceStatus
from guidance.core.messages import (
    CameraFrame,
    EstimateState,
    Health,
    LandmarkFix,
    RawCanFrame,
    RawNmeaLine,
    RawRecord,
)
from guidance.outputs.kinds import HEALTH, OUTPUTS, HealthReport, OutputContext
from guidance.outputs.sink import NO_CONTEXT

if TYPE_CHECKING:  # the estimator stack (filterpy, scipy, numba) loads on first use only
    from guidance.app.ports import OutputSink
    from guidance.core.pipeline import Input, Outputs, Pipeline

    Message: TypeAlias = Input | CameraFrame
    """What the sources hand to ``App.sink``: the pipeline's inputs, or a camera frame."""
    Source: TypeAlias = ports.Source[Message]
    """What every device source offers (``guidance.app.ports.Source``)."""

W = TypeVar("W", bound="Callable[[Message], None]")
"""A wrapper of the sources' sink (``App.wrap_source_sink``)."""
log = logging.getLogger(__name__)

LATENCY_SAMPLES = 100_000
RECENT_LAG_SAMPLES = 200
"""The health message's lag p99 is over the last 200 ticks (10 s at 20 Hz): sorting all of
``loop_lag_s`` (100,000 after 83 minutes) every second would cost the loop 12 ms."""
GIL_SWITCH_INTERVAL_S = 0.001
"""``sys.setswitchinterval`` in the car: a pure-Python thread (CAN and compass readers,
recorder, telemetry) hands the GIL back to the loop within 1 ms instead of Python's 5 ms
(benchmarks/loop_latency.py: loop lateness p99 4.8 -> 3.7 ms on a loaded 2-core machine)."""


DEFAULT_LOOP = LoopSettings()
"""``[loop]``'s defaults (``guidance.app.settings.LoopSettings``)."""


class App:
    """The asyncio wiring around one ``Pipeline`` (see the module docstring)."""

    def __init__(
        self,
        pipeline: Pipeline,
        *,
        sources: Mapping[str, Source] | None = None,
        camera: ports.CameraSource | None = None,
        recogniser: Recogniser | None = None,
        speaker: Speaker | None = None,
        sinks: Sequence[OutputSink] = (),
        notifier: Notifier | None = None,
        checkpointer: Checkpointer | None = None,
        clock: Callable[[], float] = time.monotonic,
        loop: LoopSettings = DEFAULT_LOOP,
    ) -> None:
        """``sinks``: telemetry and the recorder (the one among them that records inputs, an
        ``InputRecorder``, gets the inputs too); ``clock``: the message clock (a
        ``ports.SteppedClock`` runs ``tick`` itself, as it steps); ``loop``: the ``[loop]`` table
        (tick rate, health publication period, the lag that counts as late)."""

        self.failures = LogOnce(log)
        """Failures of messages, ticks, stats and the recogniser: logged once, counted."""
        self.pipeline = pipeline
        self.sources = dict(sources or {})
        self.camera = camera
        self.recogniser: Recogniser = recogniser if recogniser is not None else NullRecogniser()
        self.speaker = speaker
        self.sinks: list[OutputSink] = list(sinks)
        """Where outputs go (telemetry, the recorder), each with its own queue policy."""
        self.recorder: InputRecorder | None = next(
            (s for s in self.sinks if isinstance(s, InputRecorder)), None
        )
        """Where the inputs are recorded as they arrive (the sink that is a recorder)."""
        self.notifier = notifier
        self.checkpointer = checkpointer
        self.clock = clock
        self.tick_hz = loop.tick_hz
        self.health_publish_period_s = loop.health_publish_period_s
        self.max_loop_lag_s = loop.max_lag_s
        self.method = pipeline.config.navigator.method.value
        self.listeners: list[Callable[[Input | None, Outputs], None]] = []
        self.counts: Counter[str] = Counter()
        self.loop_lag_s: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self.stop_event = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._source_sink: Callable[[Message], None] = self.sink
        """What the sources are started with: ``sink``, or a wrapper (``wrap_source_sink``)."""
        self._submitted = 0
        self._processed = 0
        self._sub_lock = threading.Lock()
        self._frame: CameraFrame | None = None
        self._frame_lock = threading.Lock()
        self._frame_signalled = False
        self._frame_ready = asyncio.Event()
        self._next_health_pub = -math.inf
        self._next_counts_t = -math.inf
        self._lagging = False
        self._started_sources: list[Source] = []

    # -- input side (any thread) ----------------------------------------------------------------
    def sink(self, msg: Message) -> None:
        """Hand a message to the loop; callable from any thread (the sources' sink)."""
        loop = self._loop
        if loop is None:
            raise RuntimeError("App.sink used before run()")
        with self._sub_lock:
            self._submitted += 1
        loop.call_soon_threadsafe(self._on_message, msg)

    def backlog(self) -> int:
        """Messages handed to ``sink`` and not yet processed (the drivers' back-pressure)."""
        return self._submitted - self._processed

    def _on_message(self, msg: Message) -> None:
        try:
            if isinstance(msg, CameraFrame):  # a camera handed to sink(): use the ring too
                with self._frame_lock:
                    self._frame = msg
                    self.counts["frames"] += 1
                self._on_frame()
            else:
                self.feed(msg)
            self.failures.ok(f"processing {type(msg).__name__}")
        except Exception:
            self.failures.failed(f"processing {type(msg).__name__}")
        finally:
            self._processed += 1

    # -- the loop side ----------------------------------------------------------------------------
    def feed(self, msg: Input) -> Outputs:
        """Process one input on the loop: record it, run the pipeline, hand the outputs out."""
        self._record_input(msg)
        out = self.pipeline.feed(msg)
        self.counts[type(msg).__name__] += 1
        self._handle(msg, out)
        return out

    def tick(self, now_s: float) -> Outputs:
        """Time-driven work on the message clock: health, health publication, checkpoints."""
        if now_s >= self._next_counts_t:
            self._next_counts_t = now_s + 1.0
            for name, src in self.sources.items():
                try:
                    stats = src.stats()  # ports.Source: "read" and "rejected" totals
                    read, rejected = int(stats.get("read", 0)), int(stats.get("rejected", 0))
                    self.failures.ok(f"{name}: stats()")
                except Exception:  # a source's stats must never stop the loop
                    self.failures.failed(f"{name}: stats()")
                    continue
                self.pipeline.update_source_counts(name, read, rejected)
                if "yaw_read" in stats:  # a gyro car's yaw rate from the same bus: its own record
                    yaw = int(stats["yaw_read"]), int(stats.get("yaw_rejected", 0))
                    self.pipeline.update_source_counts("gyro", *yaw)
        out = self.pipeline.tick(now_s)
        self._handle(None, out)
        if now_s >= self._next_health_pub:
            self._next_health_pub = now_s + self.health_publish_period_s
            self._publish_health(now_s)
        if self.checkpointer is not None and self.checkpointer.due(now_s):
            self.save_checkpoint(now_s)
        return out

    def save_checkpoint(self, t_s: float, *, finished: bool = False) -> bool:
        if self.checkpointer is None:
            return False
        more = self.checkpointer.extra
        extra = dict(more()) if more is not None else {}
        state = {"pipeline": self.pipeline.snapshot(), "extra": extra}
        return self.checkpointer.save(t_s, state, finished=finished)

    def camera_sink(self, frame: CameraFrame) -> None:
        """The camera's sink (its thread): a one-slot ring, so a stalled loop or a slow matcher
        holds at most one frame; the loop is woken once per batch of frames, not per frame."""
        loop = self._loop
        if loop is None:
            raise RuntimeError("App.camera_sink used before run()")
        with self._frame_lock:
            if self._frame is not None:
                self.counts["frames_dropped"] += 1
            self._frame = frame
            self.counts["frames"] += 1
            wake = not self._frame_signalled
            self._frame_signalled = True
        if wake:
            loop.call_soon_threadsafe(self._on_frame)

    def _on_frame(self) -> None:
        """On the loop: note the camera alive, record the frame, wake the recogniser."""
        with self._frame_lock:
            self._frame_signalled = False
            frame = self._frame
        if frame is None:
            return
        self.pipeline.camera_seen(frame.t_s)
        self._frame_ready.set()
        if self.recorder is not None:
            self.recorder.record_camera(frame)

    def _handle(self, msg: Input | None, out: Outputs) -> None:
        if self.speaker is not None:
            for prompt in out.prompts:
                self.speaker.say(prompt.text, prompt.priority, prompt.t_s)
        if self.sinks:
            self._send(out)
        if out.health and msg is None:
            self._publish_health(out.health[0].t_s)
        elif out.health:
            self._next_health_pub = -math.inf  # publish at the next tick
        for listener in self.listeners:
            listener(msg, out)

    def _send(self, out: Outputs) -> None:
        """Every output to every sink, kind by kind from the output table; what a message
        needs beyond the output (the state's context) is computed once, not once per sink."""
        p = self.pipeline
        context = NO_CONTEXT
        if out.state is not None:
            context = OutputContext(speed_mps=p.estimate.speed_mps, target=p.target(),
                                    goal=p.navigator.goal, method=self.method,
                                    mode=p.navigator.mode, chance=out.chance)  # fmt: skip
        batch = [
            (kind, items) for kind in OUTPUTS if kind.items and (items := tuple(kind.items(out)))
        ]
        for sink in self.sinks:
            for kind, items in batch:
                for item in items:
                    sink.send(kind, item, context)

    def _publish_health(self, t_s: float) -> None:
        if not self.sinks:
            return
        inputs = self.pipeline.statuses(t_s)
        comps: dict[str, Health | Mapping[str, Any]] = {
            "estimator": self.pipeline.localizer.filter_health(),
            "loop": {
                "lag_p99_s": _percentile(self._recent_lag(), 99),
                "backlog": self._submitted - self._processed,
                "frames_dropped": self.counts["frames_dropped"],
            },
        }
        if self.speaker is not None:
            voice = self.speaker.health()
            comps[voice.name] = voice
        report = HealthReport(t_s, inputs, comps)
        for sink in self.sinks:
            sink.send(HEALTH, report)

    def _device_status(self, name: str, health: Health) -> None:
        """A driver's status flip (on its thread): into the loop like any other input."""
        self.sink(DeviceStatus(self.clock(), name, health))

    def _record_input(self, msg: Input) -> None:
        if self.recorder is not None and not isinstance(msg, DeviceStatus):
            topic, body = to_record(msg)
            self.recorder.record(topic, msg.t_s, body)

    def wrap_source_sink(self, wrap: Callable[[Callable[[Message], None]], W]) -> W:
        """Start the sources with ``wrap(sink)`` instead of ``sink``, and return it: the hook the
        app offers for the simulator's lockstep (``hal_sim.lockstep.LockstepSink`` counts what
        passes). Only before ``running`` (a source already started keeps its sink)."""
        if self._started_sources:
            raise RuntimeError("the sources have started: their sink is set")
        self._source_sink = wrap(self.sink)
        return self._source_sink

    # -- running --------------------------------------------------------------------------------
    @contextlib.asynccontextmanager
    async def running(self) -> AsyncIterator[App]:
        """Start sources and the background tasks; stop and release everything on exit."""
        from guidance.core.warmup import warm_up

        warm_up()  # numba compiles now, not on the first message (no lag, no false "silent")
        self._loop = asyncio.get_running_loop()
        stepped = self.clock if isinstance(self.clock, ports.SteppedClock) else None
        if stepped is not None:  # its owner runs the time-driven work as it steps the clock
            stepped.set_tick(self.tick)
        try:
            async with asyncio.TaskGroup() as tg:
                ticker = self._ticker(tick=stepped is None)
                tasks = [tg.create_task(ticker, name="ticker")]
                if self.camera is not None:
                    tasks.append(tg.create_task(self._recognise(), name="recogniser"))
                try:
                    if self.recorder is not None:
                        for src in self.sources.values():
                            record_raw_inputs(src, self.recorder, self._loop)
                    for name, src in self.sources.items():
                        if isinstance(src, ports.ReportsStatus):  # status flips, as inputs
                            src.set_status_sink(partial(self._device_status, name))
                        if isinstance(src, ports.BackPressured):
                            src.set_backlog(self.backlog)
                        src.start(self._source_sink)
                        self._started_sources.append(src)
                        log.info("started %s (%s)", name, getattr(src, "name", name))
                    if self.camera is not None:
                        self.camera.start(self.camera_sink)
                        self._started_sources.append(self.camera)
                    if self.notifier is not None:
                        self.notifier.ready("guidance running")
                    yield self
                finally:
                    for task in tasks:
                        task.cancel()
        finally:
            if stepped is not None:
                stepped.set_tick(None)
            if self.notifier is not None:
                self.notifier.stopping()
            self._stop_sources()

    def _stop_sources(self) -> None:
        while self._started_sources:
            src = self._started_sources.pop()
            try:
                src.stop()
            except Exception:
                log.exception("stopping %s failed", getattr(src, "name", src))

    async def run_until_stopped(self) -> None:
        """The car: run until ``stop_event`` is set (signal, end of the sim)."""
        async with self.running():
            await self.stop_event.wait()

    async def _ticker(self, *, tick: bool) -> None:
        """Fixed-rate housekeeping on absolute monotonic deadlines; reports lag (Ratekeeper);
        ``tick``: run the time-driven work each period (not on a stepped clock)."""
        period = 1.0 / self.tick_hz
        deadline = time.monotonic() + period
        while True:
            await asyncio.sleep(max(0.0, deadline - time.monotonic()))
            lag = time.monotonic() - deadline
            self.loop_lag_s.append(lag)
            late = lag > self.max_loop_lag_s
            if late != self._lagging:
                self._lagging = late
                if late:
                    log.warning("event loop %.0f ms behind its deadline", lag * 1e3)
                else:
                    log.warning("event loop on time again")
            if self.notifier is not None:
                self.notifier.tick(lag)
            if tick:
                try:
                    self.tick(self.clock())
                    self.failures.ok("tick")
                except Exception:
                    self.failures.failed("tick")
            deadline += period
            if time.monotonic() - deadline > 10 * period:  # stalled: do not burst to catch up
                deadline = time.monotonic() + period

    async def _recognise(self) -> None:
        """Match the latest camera frame in a worker thread; fixes come back as inputs."""
        while True:
            await self._frame_ready.wait()
            self._frame_ready.clear()
            with self._frame_lock:
                frame, self._frame = self._frame, None
            if frame is not None:
                await self.recognise(frame)

    async def recognise(self, frame: CameraFrame) -> None:
        """Match ``frame`` against the current estimate in a worker thread (off the loop) and
        apply the fix it gives; a failure is counted and logged once, never raised."""
        state = self.pipeline.state()
        loop = asyncio.get_running_loop()
        try:
            fix = await loop.run_in_executor(None, self.match_frame, frame, state)
            self.failures.ok("the landmark recogniser")
        except Exception:
            self.counts["recogniser_errors"] += 1
            self.failures.failed("the landmark recogniser")
            return
        self.counts["frames_matched"] += 1
        if fix is not None:
            try:  # a bad fix is the estimator's to reject; it must never end the loop
                self.feed(fix)
            except Exception:
                self.counts["recogniser_errors"] += 1
                self.failures.failed("applying a landmark fix")

    def match_frame(self, frame: CameraFrame, state: EstimateState) -> LandmarkFix | None:
        """Run the recogniser (worker thread): its fix, its rejection reason counted."""
        result = self.recogniser.process(frame, state)
        if result.reason:
            self.counts[f"recognition_{result.reason}"] += 1
        return result.fix

    # -- figures ----------------------------------------------------------------------------------
    def _recent_lag(self) -> list[float]:
        n = len(self.loop_lag_s)
        return list(itertools.islice(self.loop_lag_s, max(0, n - RECENT_LAG_SAMPLES), n))

    def lag_summary(self) -> dict[str, float | None]:
        return {
            "loop_lag_p50_ms": _ms(_percentile(self.loop_lag_s, 50)),
            "loop_lag_p99_ms": _ms(_percentile(self.loop_lag_s, 99)),
            "loop_lag_max_ms": _ms(max(self.loop_lag_s) if self.loop_lag_s else None),
        }


RAW_ORDER = threading.Lock()
"""Held by every recorded reader from a unit's raw record to the hand-over of its message
(``ThreadedSource.set_raw_sink``)."""


def record_raw_inputs(
    source: Source, recorder: InputRecorder, loop: asyncio.AbstractEventLoop | None = None
) -> bool:
    """Record the raw units a driver reads (``/can`` frames, ``/nmea`` lines) through the
    readers' supported hook (``ThreadedSource.set_raw_sink``). True when set.

    With ``loop`` (the app's), each unit is written on the loop, posted just before the
    message it decoded to (``RAW_ORDER`` keeps the two together across readers): the file
    then holds the raw units in the order the loop took their messages, among the inputs the
    loop records as it processes them (the co-driver's), and a replay of the raw units is
    the drive that was recorded. Written on the reader's thread, a CAN frame read while the
    loop was still on an earlier co-driver message came before it in the file: a replay of a
    simulated drive from its raw frames then made other decisions one run in three."""
    if not isinstance(source, ports.RecordsRaw):
        return False

    def write(r: RawRecord) -> None:
        if isinstance(r, RawCanFrame):
            recorder.record_can(r.t_s, r.arbitration_id, r.data, is_extended_id=r.is_extended_id,
                                is_error_frame=r.is_error_frame, channel=r.channel)  # fmt: skip
        elif isinstance(r, RawNmeaLine):
            recorder.record_nmea(r.t_s, r.line, port=r.port)

    def raw_sink(r: RawRecord) -> None:
        if loop is None:
            write(r)
        else:
            loop.call_soon_threadsafe(write, r)

    source.set_raw_sink(raw_sink, RAW_ORDER)
    return True


def _percentile(values: Sequence[float] | deque[float], q: float) -> float | None:
    if not values:
        return None
    s = sorted(values)
    k = min(len(s) - 1, max(0, math.ceil(q / 100.0 * len(s)) - 1))
    return float(s[k])


def _ms(v: float | None) -> float | None:
    return None if v is None else v * 1e3
