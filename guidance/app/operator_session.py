"""The operator screen of one ``guidance run``, wired to its pipeline, its co-driver input and
its speaker (docs/app.md, "Operator screen").

``OperatorSession`` builds, from the car's config and pipeline, the view, the screen
(``guidance.app.screen.OperatorScreen``) and the ``Operator`` glue; ``co_driver_input`` builds
the configured co-driver input (``[scene] input``) with every key acknowledged on the screen;
``attach`` wraps the outputs' speaker so the co-driver can mute it (and has the text speaker's
lines shown as rows under the live view); ``start`` prints the banner and starts drawing,
``stop`` leaves the last state on the screen. ``guidance run`` on the car's devices
(``guidance.app.run.run_car``) and a registered runner of simulated devices use the same one,
so both show the same screen.
"""

from __future__ import annotations

import asyncio
import logging
import sys
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TextIO

from guidance.app.operator_view import OperatorView
from guidance.app.screen import (
    MutableSpeaker,
    Operator,
    OperatorScreen,
    ScreenTextStream,
)

if TYPE_CHECKING:
    from guidance.app.app import Source
    from guidance.app.config import AppConfig
    from guidance.app.ports import Speaker
    from guidance.core.messages import Say
    from guidance.core.pipeline import Pipeline

SCREEN_MODES = ("auto", "live", "plain", "off")
"""``--screen``: auto (live on a terminal, plain lines otherwise), live, plain or off."""

log = logging.getLogger(__name__)


class OperatorSession:
    """The operator screen of one run (see the module). ``screen`` is a ``SCREEN_MODES`` entry;
    ``clock`` is the message clock (the co-driver's lines and a repeated prompt are stamped
    with it)."""

    def __init__(
        self,
        cfg: AppConfig,
        pipeline: Pipeline,
        *,
        screen: str = "auto",
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if screen not in SCREEN_MODES:
            raise ValueError(f"screen must be one of {', '.join(SCREEN_MODES)}, not {screen!r}")
        self.cfg = cfg
        self.on = screen != "off"
        self.clock = clock
        pcfg = pipeline.config
        view = OperatorView(
            vehicle_id=cfg.vehicle_id,
            landmark_names={lm.id: lm.name for lm in pcfg.landmarks if lm.name},
            lost_major_axis_m=pcfg.estimator.lost_major_axis_m,
            chance_warn_below=pcfg.chance.warn_below,
        )
        live = {"live": True, "plain": False}.get(screen)
        self.screen = OperatorScreen(
            view, stream=stream if stream is not None else sys.stdout, live=live
        )
        self.operator = Operator(self.screen, pipeline, clock=clock)
        self.speaker: MutableSpeaker | None = None
        self.speech: Any = None
        """The speech input beside the keys, when there is one."""

    @property
    def live(self) -> bool:
        """The rich live view owns the terminal."""
        return self.on and self.screen.live

    def co_driver_input(self, heading_fn: Callable[[], float]) -> Source | None:
        """The configured co-driver input (``[scene] input``; None for "none"), its lines
        acknowledged on the screen, key by key for a keypad, and for the terminal keyboard when
        the live view owns the terminal (its echo would otherwise be drawn over)."""
        from guidance.app.backends import SCENE_BACKENDS, SCENE_CONFIGS, import_backend

        scene = self.cfg.scene
        if scene.input == "none":
            return None
        if scene.input == "speech":
            source = self._speech(heading_fn)
            self.operator.co_driver = source
            return source
        per_key = self.on and (scene.input == "evdev" or self.screen.live)
        cls = import_backend(SCENE_BACKENDS[scene.input])
        args: list[Any] = []
        if scene.input in SCENE_CONFIGS:
            conf_cls = import_backend(SCENE_CONFIGS[scene.input])
            args.append(conf_cls(device=scene.device, grab=scene.grab))
        source = cls(
            *args,
            heading_fn,
            feedback=self.screen.ack if self.on else None,
            echo=self.screen.echo if per_key else None,
            on_command=self.operator.on_command,
            clock=self.clock,
        )
        self.operator.co_driver = source
        return source

    def speech_beside(self, heading_fn: Callable[[], float]) -> Source | None:
        """The microphone beside the keypad or keyboard (``[scene] speech = true``), after
        ``co_driver_input``: with a keypad, its 5 is the talk key."""
        if not self.cfg.scene.speech or self.cfg.scene.input == "speech":
            return None
        speech = self._speech(heading_fn)
        keys = self.operator.co_driver
        if keys is not None and hasattr(keys, "on_talk"):
            keys.on_talk = speech.set_talking
        self.operator.co_driver = _KeysAndMicrophone(keys, speech)  # the INPUT row shows both
        self.speech = speech
        return speech

    def _speech(self, heading_fn: Callable[[], float]) -> Any:
        """The speech input (``drivers.speech``): heard reports acknowledged on the screen,
        read back by the car's voice, deaf to it (``guidance.voice.activity.CAR_VOICE``)."""
        from guidance.app.backends import SCENE_BACKENDS, SCENE_CONFIGS, import_backend
        from guidance.voice.activity import CAR_VOICE

        scene = self.cfg.scene
        conf = import_backend(SCENE_CONFIGS["speech"])(device=scene.microphone,
                                                       talk=scene.talk_mode)  # fmt: skip
        return import_backend(SCENE_BACKENDS["speech"])(
            conf,
            heading_fn,
            feedback=self.screen.ack if self.on else None,
            echo=self.screen.echo if self.on else None,
            on_command=self.operator.on_command,
            read_back=self._read_back,
            car_voice=CAR_VOICE,
            clock=self.clock,
        )

    def _read_back(self, say: Say) -> None:
        """Say what the speech input heard ("Left, straight, right."), from its thread."""
        from guidance.core.messages import Priority

        loop = self.operator.loop
        if loop is None:
            return
        loop.call_soon_threadsafe(
            lambda: self.operator.speak(say, Priority.GUIDANCE, self.clock())
        )

    def attach(self, speaker: Speaker | None) -> MutableSpeaker | None:
        """On the loop, once the outputs are open: the speaker the app is given (muted by the
        co-driver's mute key); the text speaker's lines become SAID rows under the live view."""
        redirect = getattr(speaker, "redirect", None)  # the text speaker
        if self.live and redirect is not None:
            redirect(ScreenTextStream(self.screen))  # not printed over the live view
        self.speaker = MutableSpeaker(speaker) if speaker is not None else None
        self.operator.speaker = self.speaker
        self.operator.loop = asyncio.get_running_loop()
        return self.speaker

    def start(self, banner: Sequence[tuple[str, str]]) -> None:
        """The banner, then the screen (nothing with ``screen = "off"``)."""
        if self.on:
            self.screen.print_banner(banner)
            self.screen.start()

    def stop(self) -> None:
        """The last state stays on the screen (a last status line in the journal)."""
        if self.on:
            self.screen.stop()

    def no_co_driver(self, problem: str) -> None:
        """Say it loudly when the co-driver cannot report intersections: in the log, on the
        screen and to the driver (``Speech.NO_CO_DRIVER_INPUT``)."""
        from guidance.core.messages import Priority, Say, Speech

        log.warning("NO CO-DRIVER INPUT: %s; intersections cannot be reported", problem)
        self.screen.fold(
            lambda v: v.add(time.time(), "info", f"NO CO-DRIVER INPUT: {problem}", "bad")
        )
        self.operator.speak(Say(Speech.NO_CO_DRIVER_INPUT), Priority.SAFETY, time.monotonic())


class _KeysAndMicrophone:
    """What the screen's INPUT row says of a keypad (or keyboard) and the microphone beside it:
    both, the microphone with what it last heard."""

    def __init__(self, keys: Any, speech: Any) -> None:
        self.keys, self.speech = keys, speech

    def describe(self) -> str:
        parts = [x.describe() for x in (self.keys, self.speech) if x is not None]
        return " + ".join(parts)

    @property
    def connected(self) -> bool:
        return bool(getattr(self.keys, "connected", True) or self.speech.connected)
