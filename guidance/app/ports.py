"""The app's ports: one interface per kind of device (HOUSE_STYLE), real and simulated devices
implement them, and one per thing ``App`` drives (recogniser, speaker, output sinks, recorder,
notifier).

A source owns its blocking I/O on its own thread and hands each message to the
``sink`` it was started with; the application's sink forwards it to the event
loop with ``loop.call_soon_threadsafe``. Sources count what they read and what
they rejected, by reason, in ``stats()``; a bad byte is a counted rejection,
never an exception out of ``start``/``stop``.

``OutputSink`` is ``guidance.outputs.sink.MessageSink`` (the one output path, shared by
telemetry and the recorder: ``publish`` and ``send`` of any row of the output table).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, TypeAlias, TypeVar, runtime_checkable

from guidance.core.messages import (
    CameraFrame,
    CancelReport,
    CompassHeading,
    EstimateState,
    Health,
    IntersectionScene,
    LandmarkFix,
    RawSink,
    TurnCompleted,
    WheelOdometry,
)
from guidance.voice.speaker import Speaker

__all__ = ["Speaker"]  # the voice's port, named here with the app's other ports

if TYPE_CHECKING:
    from guidance.outputs.sink import MessageSink

    OutputSink: TypeAlias = MessageSink
    """Where outputs go (telemetry, the recorder): ``send(kind, item, context)``."""

T_co = TypeVar("T_co", covariant=True)

NO_CANDIDATE = "no_candidate"
"""The null recogniser's reason: no landmark to compare (``landmark_db.recognise``'s own)."""


@runtime_checkable
class Source(Protocol[T_co]):
    """A device source delivering messages of one type to the sink it was started with."""

    name: str

    def start(self, sink: Callable[[T_co], None]) -> None: ...
    def stop(self) -> None: ...
    def stats(self) -> Mapping[str, int]:
        """Counters by name; ``read`` (units of data judged) and ``rejected`` (of those, by the
        parser) when the source judges its data: the pipeline's garbled-input check."""


"""``(kind, t_s, fields)``: "can" with id, data, is_extended_id, is_error_frame, channel;
"nmea" with line, port (``drivers._reader.ThreadedSource`` offers each unit it reads)."""


@runtime_checkable
class ReportsStatus(Protocol):
    """A source that hands its status flips (``disconnected``...) to a sink (the drivers)."""

    def set_status_sink(self, status_sink: Callable[[Health], None] | None) -> None: ...


@runtime_checkable
class BackPressured(Protocol):
    """A source that holds (merges or drops) data while the consumer's backlog is too long."""

    def set_backlog(self, backlog: Callable[[], int], limit: int = ...) -> None: ...


@runtime_checkable
class RecordsRaw(Protocol):
    """A source that offers every raw unit it reads (CAN frame, NMEA line) before decoding."""

    def set_raw_sink(
        self, raw_sink: RawSink | None, order: threading.Lock | None = None
    ) -> None: ...


@runtime_checkable
class OdometrySource(Source[WheelOdometry], Protocol):
    """Wheel odometry increments."""


@runtime_checkable
class CompassSource(Source[CompassHeading], Protocol):
    """Compass readings."""


@runtime_checkable
class CameraSource(Source[CameraFrame], Protocol):
    """Camera frames."""


@runtime_checkable
class RoadwayScene(Source[IntersectionScene | TurnCompleted | CancelReport], Protocol):
    """Tells the app that an intersection is coming and which exits it has, and what was taken."""


class Recognition(Protocol):
    """What a recogniser says about one frame (``landmark_db.recognise.RecognitionResult``):
    a fix, or the reason there is none."""

    @property
    def fix(self) -> LandmarkFix | None: ...
    @property
    def reason(self) -> str | None: ...


@dataclass(frozen=True, slots=True)
class Recognised:
    """A plain ``Recognition`` (the null recogniser's, a test double's)."""

    fix: LandmarkFix | None = None
    reason: str | None = None


@runtime_checkable
class Recogniser(Protocol):
    """Matches a camera frame against the landmarks the current estimate gates in
    (``landmark_db.recognise.Recogniser``). Called off the event loop, one frame at a time;
    rejections are counted by reason in ``stats()``."""

    def process(self, frame: CameraFrame, state: EstimateState) -> Recognition: ...
    def stats(self) -> Mapping[str, int]: ...


class NullRecogniser:
    """Recognises nothing: the default until a landmark database is configured."""

    def __init__(self) -> None:
        self._frames = 0

    def process(self, frame: CameraFrame, state: EstimateState) -> Recognised:
        self._frames += 1
        return Recognised(None, NO_CANDIDATE)

    def stats(self) -> Mapping[str, int]:
        return {"frames": self._frames, "fixes": 0, NO_CANDIDATE: self._frames}

    def close(self) -> None:
        return None


@runtime_checkable
@runtime_checkable
class InputRecorder(Protocol):
    """The recorder's input side (``guidance.recording.writer.Recorder``): what arrived, as it
    arrived. Its output side is an ``OutputSink``. Never blocks; False when not queued."""

    def record(self, topic: str, t_s: float, message: Mapping[str, object]) -> bool: ...
    def record_camera(self, frame: CameraFrame) -> bool: ...
    def record_can(
        self,
        t_s: float,
        arbitration_id: int,
        data: bytes,
        *,
        is_extended_id: bool = False,
        is_error_frame: bool = False,
        channel: str = "",
    ) -> bool: ...
    def record_nmea(self, t_s: float, line: str | bytes, *, port: str = "") -> bool: ...


@runtime_checkable
class SteppedClock(Protocol):
    """A message clock that its owner steps instead of one read off the wall (a simulated
    world's clock). ``App`` hands it ``App.tick`` when it starts (``set_tick``, as a source is
    handed its sink) and takes it back when it stops; the owner runs the time-driven work after
    each step of its clock, at reproducible times, and the app's ticker keeps only the loop's
    heartbeat (its lag, the watchdog). Any other clock (``time.monotonic``) is read by the
    ticker, which runs ``App.tick`` once per period."""

    def __call__(self) -> float:
        """Now, on the message clock."""

    def set_tick(self, tick: Callable[[float], object] | None) -> None:
        """What to run at each step (``App.tick``), or None once the app stops."""


@runtime_checkable
class Notifier(Protocol):
    """Tells the service manager how the app is doing (``guidance.app.watchdog``)."""

    def ready(self, status: str | None = None) -> None:
        """Devices are open, the loop is starting."""

    def tick(self, lag_s: float) -> bool:
        """Once per ticker period, with the loop's lateness; True when a keep-alive was sent."""

    def stopping(self) -> None:
        """A clean shutdown has begun."""
