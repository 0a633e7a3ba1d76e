"""The config tables that map 1:1 onto a dataclass, read by ``guidance.config_tables.from_table``
(``[vehicle]``, ``[navigation]``, ``[scene]``, ``[voice]``, ``[health]``, ``[loop]``,
``[checkpoint]``): each field is a key, its type and ``rule`` say what the key takes
(docs/app.md, "Configuration"). A setting that the core's own config also has takes its default
from there (``field_default``): each default is written once."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from guidance.app.backends import SCENE_BACKENDS
from guidance.config_tables import Rule, field_default, from_table, rule
from guidance.core.pipeline_config import PipelineConfig
from guidance.core.plan.navigator import Method, NavigatorConfig
from guidance.core.speech import Units
from guidance.errors import UserError
from guidance.voice import SPEAKER_KINDS

_NAV = NavigatorConfig()
_UNITS: Units = field_default(PipelineConfig, "units")
_STRAIGHT_AFTER_M: float = field_default(PipelineConfig, "straight_after_m")
_UNCERTAIN_WARN_M: float = field_default(PipelineConfig, "uncertain_warn_m")
_STOP_AT_ARRIVAL: bool = field_default(PipelineConfig, "stop_at_arrival")


@dataclass(frozen=True, slots=True)
class NavigationSettings:
    """``[navigation]``: the navigator's settings and the pipeline's advice distances; the
    defaults are ``NavigatorConfig``'s and ``PipelineConfig``'s."""

    method: Method = _NAV.method
    units: Units = _UNITS
    arrival_radius_m: float = field(default=_NAV.arrival_radius_m, metadata=rule(positive=True))
    hybrid_switch_m: float = field(default=_NAV.hybrid_switch_m, metadata=rule(positive=True))
    lookahead_m: float = field(default=_NAV.lookahead_m, metadata=rule(positive=True))
    landmark_pass_radius_m: float = field(
        default=_NAV.landmark_pass_radius_m, metadata=rule(positive=True)
    )
    tabu_step_deg: float | None = field(default=None, metadata=rule(lo=0.0))
    """Degrees (the navigator's ``tabu_step_rad``); None: its default."""
    straight_after_m: float = field(default=_STRAIGHT_AFTER_M, metadata=rule(positive=True))
    uncertain_warn_m: float = field(default=_UNCERTAIN_WARN_M, metadata=rule(positive=True))
    stop_at_arrival: bool = _STOP_AT_ARRIVAL

    def navigator(self) -> NavigatorConfig:
        deg = self.tabu_step_deg
        return dataclasses.replace(
            _NAV,
            tabu_step_rad=_NAV.tabu_step_rad if deg is None else math.radians(deg),
            method=self.method,
            arrival_radius_m=self.arrival_radius_m,
            hybrid_switch_m=self.hybrid_switch_m,
            lookahead_m=self.lookahead_m,
            landmark_pass_radius_m=self.landmark_pass_radius_m,
        )


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
    talk: str = field(default="auto", metadata=rule(choices=("auto", "key", "always")))
    """When the speech input listens: ``key`` while the keypad's 5 is held, ``always`` (voice
    activity), ``auto``: ``key`` with a keypad (input = "evdev"), else ``always``."""

    @property
    def listens(self) -> bool:
        """The microphone is one of the co-driver inputs."""
        return self.input == "speech" or self.speech

    @property
    def talk_mode(self) -> str:
        """``key`` or ``always`` (``auto`` resolved)."""
        if self.talk != "auto":
            return self.talk
        return "key" if self.input == "evdev" else "always"


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
    track_m: float | None = field(default=None, metadata=rule(positive=True))
    """None: the ``[odometry] profile``'s track width."""


@dataclass(frozen=True, slots=True)
class LoopSettings:
    """``[loop]``."""

    tick_hz: float = field(default=20.0, metadata=rule(positive=True))
    state_rate_hz: float = field(default=10.0, metadata=rule(positive=True))
    health_publish_period_s: float = field(default=1.0, metadata=rule(positive=True))
    max_lag_s: float = field(default=0.5, metadata=rule(positive=True))


HEALTH_RULES = {
    "silence_periods": Rule(positive=True),
    "min_timeout_s": Rule(positive=True),
    "max_reject_fraction": Rule(lo=0, hi=1),
    "min_reads_for_validity": Rule(read=False),
}
"""``[health]`` is ``HealthConfig`` (guidance/core/health.py) without its last field."""


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
            "without a keypad use talk = 'always'"
        )
    return scene
