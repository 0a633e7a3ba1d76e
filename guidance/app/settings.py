"""The config file's tables that the core's own config dataclasses do not hold, read by
``guidance.config_tables.from_table`` (``[vehicle]``, ``[start]``/``[goal]``/``[[landmarks]]``,
a device's common keys, ``[estimator] model``, ``[scene]``, ``[voice]``, ``[loop]``,
``[checkpoint]``): each field is a key, its type and ``rule`` say what the key takes
(docs/app.md, "Configuration"). A setting the core's config also has is not mirrored here:
``[navigation]``, ``[health]``, ``[chance]``, ``[estimator]`` and ``[compass]``'s own keys are
read into the core's dataclasses by their rules; where a table here offers the same quantity
(``[vehicle] track_m``, a device's ``expected_rate_hz``) it takes the core field's rule
(``config_tables.like``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from guidance.app.backends import SCENE_BACKENDS
from guidance.config_tables import from_table, like, rule
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.localize.gyro import YAW_SOURCES
from guidance.core.pipeline_config import (
    COORDINATE,
    MAX_STATE_PERIOD_S,
    MIN_STATE_PERIOD_S,
    PipelineConfig,
)
from guidance.errors import UserError
from guidance.voice import SPEAKER_KINDS


@dataclass(frozen=True, slots=True)
class Place:
    """A place in ``[start]``, ``[goal]`` or ``[[landmarks]]``: latitude and longitude, or local
    metres (east, north of the start)."""

    lat_deg: float | None = field(default=None, metadata=rule(lo=-90.0, hi=90.0))
    lon_deg: float | None = field(default=None, metadata=rule(lo=-180.0, hi=180.0))
    x_m: float | None = field(default=None, metadata=COORDINATE)
    y_m: float | None = field(default=None, metadata=COORDINATE)

    @property
    def geodetic(self) -> bool:
        return self.lat_deg is not None or self.lon_deg is not None

    @property
    def local(self) -> bool:
        return self.x_m is not None or self.y_m is not None


@dataclass(frozen=True, slots=True)
class StartSettings(Place):
    """``[start]``."""

    heading_deg: float | None = field(default=None, metadata=rule(lo=0.0, hi=360.0))
    """True heading, degrees clockwise from north (None: from the first compass reading)."""
    unknown: bool = False
    """Start anywhere: no position; the car finds itself at its first landmark (it needs a
    camera and a landmark database)."""


@dataclass(frozen=True, slots=True)
class LandmarkPlace(Place):
    """One ``[[landmarks]]`` entry (positions only; ``[landmarks] database`` is the other
    spelling, ``guidance.app.landmarks``)."""

    id: int | None = None
    """None: its index in the list."""
    name: str = ""


@dataclass(frozen=True, slots=True)
class DeviceSettings:
    """A device table's common keys (``[odometry]``, ``[compass]``, ``[camera]``); the rest
    are the driver's own (its config dataclass, named in ``guidance.app.backends``)."""

    enabled: bool = True
    backend: str = ""
    expected_rate_hz: float = field(
        default=1.0, metadata=like(PipelineConfig, "expected_rates_hz")
    )


@dataclass(frozen=True, slots=True)
class EstimatorSettings:
    """``[estimator]``'s one key beside ``EstimatorConfig``'s fields."""

    model: str = field(default="car", metadata=rule(choices=("car", "paper")))
    """``car``: the car model's states and defaults (``estimator.car_model``); ``paper``: the
    paper's white-noise model, where the car model's keys are refused."""


@dataclass(frozen=True, slots=True)
class VoiceSettings:
    """``[voice]``."""

    backend: str = field(default="auto", metadata=rule(choices=(*SPEAKER_KINDS, "none")))
    wav_path: str = ""
    voice: str = "en"
    """The voice's language (en, en-us, en-gb, de...; Pico speaks en, de, es, fr, it, espeak-ng
    the others)."""
    rate_wpm: int = field(default=170, metadata=rule(lo=80, hi=400))
    """Speech rate in words per minute (a little slower than espeak-ng's 175, for traffic)."""
    volume: float = field(default=1.0, metadata=rule(lo=0, hi=1))
    device: str = "default"
    """The ALSA playback device (``aplay -D``): default, plughw:1,0, null (plays into nothing)."""

    def __post_init__(self) -> None:
        if self.backend == "wav" and not self.wav_path:
            raise UserError("[voice] wav_path is required with backend = 'wav'")


@dataclass(frozen=True, slots=True)
class SceneSettings:
    """``[scene]``: where the co-driver's keys come from."""

    input: str = field(default="keyboard", metadata=rule(choices=(*SCENE_BACKENDS, "none")))
    """keyboard (lines on stdin), evdev (a keypad or keyboard: ``device``), speech (the
    microphone alone) or none."""
    device: str = field(default="", metadata=rule(path=True))
    """The input device for ``evdev``: /dev/input/by-id/...-event-kbd."""
    grab: bool = True
    """evdev: take the device exclusively."""
    speech: bool = False
    """The microphone beside the keypad or keyboard (docs/app.md, "Driving alone")."""
    microphone: str = "default"
    """The ALSA capture device of the speech input (``arecord -D``)."""
    talk: str = field(default="auto", metadata=rule(choices=("auto", "key", "wake", "always")))
    """When the speech input listens: ``key`` while the keypad's 5 is held, ``wake`` (a command
    after the wake word "navigator"), ``always`` (every stretch of voice tried), ``auto``:
    ``key`` with a keypad (input = "evdev"), else ``wake`` (docs/voice.md, "The wake word")."""

    @property
    def listens(self) -> bool:
        """The microphone is one of the co-driver inputs."""
        return self.input == "speech" or self.speech

    @property
    def talk_mode(self) -> str:
        """``key``, ``wake`` or ``always`` (``auto`` resolved)."""
        if self.talk != "auto":
            return self.talk
        return "key" if self.input == "evdev" else "wake"


@dataclass(frozen=True, slots=True)
class CheckpointSettings:
    """``[checkpoint]``."""

    path: str = field(default="", metadata=rule(path=True))
    """Empty: no checkpoints."""
    interval_s: float = field(default=5.0, metadata=rule(positive=True))
    max_age_s: float = field(default=600.0, metadata=rule(positive=True))
    """An older checkpoint (wall clock) is not resumed: the car may be anywhere by now."""
    learned_path: str = field(default="", metadata=rule(path=True))
    """The car's learned parameters (``guidance.app.learned_file``): read at a fresh start
    (not when a checkpoint is resumed, which carries them), written every ``learned_interval_s``
    and at a clean stop. Empty: none kept."""
    learned_interval_s: float = field(default=60.0, metadata=rule(positive=True))
    """How often (wall clock) a drive's learned parameters are saved while it goes on, so a
    killed process whose checkpoint is too old to resume keeps what the drive learned."""


@dataclass(frozen=True, slots=True)
class VehicleSettings:
    """``[vehicle]``."""

    id: str = "car1"
    track_m: float | None = field(
        default=None, metadata=like(EstimatorConfig, "track_m", read=True)
    )
    """None: the ``[odometry] profile``'s track width."""
    yaw_source: str = field(default="wheels", metadata=rule(choices=YAW_SOURCES))
    """What turns the heading: "wheels" (the rear wheels' left/right difference), "gyro"
    (the stability control's yaw-rate sensor; the car model with its bias and scale as
    states) or "both" (the gyro turns, the wheels' turn measures it), docs/estimation.md."""


@dataclass(frozen=True, slots=True)
class LoopSettings:
    """``[loop]``."""

    tick_hz: float = field(default=20.0, metadata=rule(positive=True))
    state_rate_hz: float = field(
        default=10.0, metadata=rule(lo=1.0 / MAX_STATE_PERIOD_S, hi=1.0 / MIN_STATE_PERIOD_S)
    )
    """The pipeline's ``state_period_s``, as a rate (its bounds, inverted)."""
    health_publish_period_s: float = field(default=1.0, metadata=rule(positive=True))
    max_lag_s: float = field(default=0.5, metadata=rule(positive=True))


def read_scene(data: object, base_dir: Path | None) -> SceneSettings:
    """``[scene] input``/``device``/``grab``; ``keyboard = true|false`` is the old spelling."""
    table = dict(data) if isinstance(data, Mapping) else data
    if isinstance(table, dict) and "keyboard" in table:
        if "input" in table:
            raise UserError("[scene] give input or keyboard (the old spelling), not both")
        keyboard = table.pop("keyboard")
        if not isinstance(keyboard, bool):
            raise UserError(f"[scene] keyboard must be true or false, not {keyboard!r}")
        table["input"] = "keyboard" if keyboard else "none"
    scene = from_table(SceneSettings, table, "scene", base_dir)
    if scene.input == "evdev" and not scene.device:
        raise UserError(
            "[scene] device is required with input = 'evdev' "
            "(e.g. /dev/input/by-id/usb-<keypad>-event-kbd)"
        )
    if scene.device and scene.input != "evdev":
        raise UserError(f"[scene] device is only read with input = 'evdev', not {scene.input!r}")
    if scene.talk == "key" and scene.listens and scene.input != "evdev":
        raise UserError(
            "[scene] talk = 'key' is push-to-talk on the keypad's 5: it needs input = 'evdev'; "
            "without a keypad use talk = 'wake'"
        )
    return scene
