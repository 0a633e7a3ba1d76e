"""The car's loudspeaker: rendered prompts played through ALSA's ``aplay`` (issue 39).

Why ``aplay`` and not a Python audio library (docs/dependencies.md): it is the car's sound
system already (alsa-utils is a dependency for pyttsx3), it needs no wheel with native code
in the app's process, a crash in the audio stack is an exit status rather than a dead app,
and ``aplay`` reports a missing or unplugged device in that exit status, which we check for
every prompt (pyttsx3 ignores it). The microphone is read with ``arecord`` from the same
package (``drivers/speech.py``). ALSA's ``null`` device (``[voice] device = "null"``) plays
into nothing at once: the tests' sound card.

``PlayedSpeaker`` is the live voice for any Renderer (Pico by default, espeak-ng's command
line): the prompt queue, on a thread of its own, renders each prompt, normalises its level
(``guidance.voice.level``) and plays it, telling ``CarVoice`` what is being said so the speech
input is deaf to it.
"""

from __future__ import annotations

import logging
import shutil
import subprocess
import threading
import time
from collections.abc import Mapping
from typing import TextIO

from guidance.core.messages import Priority
from guidance.voice.activity import CAR_VOICE, CarVoice
from guidance.voice.level import normalise_level
from guidance.voice.queue import DEFAULT_QUEUE_SIZE, Clock, PromptQueue, QueuedPrompt
from guidance.voice.speaker import Speaker
from guidance.voice.speakers import SpeechEngineError, _Failover, _QueuedSpeaker
from guidance.voice.wav import Renderer

log = logging.getLogger(__name__)

PLAY_MARGIN_S = 10.0
"""``aplay`` may take this long beyond the prompt's own duration before it counts as hung."""


class AplayPlayer:
    """Plays 16-bit mono PCM through ``aplay -D device``; SpeechEngineError when it cannot."""

    def __init__(self, device: str = "default", executable: str | None = None) -> None:
        exe = executable or shutil.which("aplay")
        if exe is None:
            raise SpeechEngineError("aplay not found (Debian package alsa-utils)")
        self.device = device or "default"
        self._exe = exe

    def play(self, pcm: bytes, rate_hz: int) -> None:
        duration_s = len(pcm) / 2 / rate_hz
        cmd = [self._exe, "-q", "-D", self.device, "-t", "raw", "-f", "S16_LE",
               "-r", str(rate_hz), "-c", "1", "-"]  # fmt: skip
        try:
            r = subprocess.run(
                cmd, input=pcm, capture_output=True, timeout=duration_s + PLAY_MARGIN_S
            )
        except (OSError, subprocess.TimeoutExpired) as e:
            raise SpeechEngineError(f"aplay failed: {e}") from e
        if r.returncode != 0:
            lines = r.stderr.decode(errors="replace").strip().splitlines()
            detail = lines[-1] if lines else f"exit status {r.returncode}"
            raise SpeechEngineError(f"no audio output on {self.device!r}: {detail}")

    def check(self) -> None:
        """Play 50 ms of silence: fails now, not on the first turn, when there is no device."""
        self.play(b"\0\0" * 800, 16000)


class PlayedSpeaker(_QueuedSpeaker):
    """Speaks prompts: rendered, level-normalised and played on its own thread.

    ``say`` never blocks. A render or playback failure is logged once; the prompt in hand, the
    pending and the later prompts go to text (issue 7), as for ``Pyttsx3Speaker``.
    """

    def __init__(
        self,
        renderer: Renderer,
        player: AplayPlayer,
        *,
        engine: str = "Pico",
        clock: Clock = time.monotonic,
        maxsize: int = DEFAULT_QUEUE_SIZE,
        max_age_s: Mapping[Priority, float] | None = None,
        text_stream: TextIO | None = None,
        fallback: Speaker | None = None,
        volume: float = 1.0,
        car_voice: CarVoice = CAR_VOICE,
        check: bool = True,
    ) -> None:
        self._render = renderer
        self._player = player
        self.engine = engine
        self._volume = volume
        self._car_voice = car_voice
        if check:
            renderer("ready")
            player.check()
        self._clock = clock
        self._queue = PromptQueue(maxsize, clock, max_age_s)
        self._lock = threading.Lock()
        self._failover = _Failover(fallback, text_stream, clock)
        self._counts = {"said": 0, "spoken": 0}
        self._thread = threading.Thread(target=self._run, name="voice-play", daemon=True)
        self._thread.start()

    def say(
        self,
        text: str,
        priority: int = 0,
        t_s: float | None = None,
        max_age_s: float | None = None,
    ) -> None:
        self._enqueue(text, priority, t_s, max_age_s)

    def close(self, drain: bool = True, timeout_s: float = 30.0) -> None:
        """Stop taking prompts; play (``drain``) or discard the pending ones; join the thread."""
        if not drain:
            self._queue.clear()
        self._queue.close()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("voice thread still busy after %.1f s; leaving it behind", timeout_s)
        if self._failover.failed:
            self._failover.speaker.close()

    def _run(self) -> None:
        while True:
            prompt = self._queue.get()
            if prompt is None or self._failover.failed:
                return
            try:
                pcm, rate = self._render(prompt.text)
                pcm = normalise_level(pcm, self._volume)
                self._car_voice.started(prompt.text, len(pcm) / 2 / rate)
                try:
                    self._player.play(pcm, rate)
                finally:
                    self._car_voice.finished()
            except Exception as e:
                reason = str(e) if isinstance(e, SpeechEngineError) else f"{type(e).__name__}: {e}"
                self._fail(reason, prompt)
                return
            with self._lock:
                self._counts["spoken"] += 1

    def _fail(self, reason: str, current: QueuedPrompt | None) -> None:
        with self._lock:
            text = self._failover.fail(reason, f"speech engine ({self.engine})")
            self._queue.close()
            pending = ([current] if current is not None else []) + self._queue.take_all()
            for p in pending:  # under the lock: later prompts cannot overtake these
                text.say(p.text, p.priority, p.t_s)
