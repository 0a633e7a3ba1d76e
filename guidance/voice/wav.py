"""Prompts rendered to a WAV file (Pico by default, or espeak-ng), for the demo and tests;
level-normalised as the played voice is (``guidance.voice.level``)."""

from __future__ import annotations

import io
import logging
import math
import shutil
import subprocess
import threading
import time
import wave
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from guidance.core.messages import Priority
from guidance.voice.level import normalise_level
from guidance.voice.queue import (
    DEFAULT_QUEUE_SIZE,
    DEFAULT_RATE_WPM,
    Clock,
    PromptQueue,
    QueuedPrompt,
)
from guidance.voice.speaker import Speaker
from guidance.voice.speakers import (
    SpeechEngineError,
    _Failover,
    _QueuedSpeaker,
)

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------- WAV output

Renderer = Callable[[str], tuple[bytes, int]]
"""Renders text to 16-bit mono PCM; returns (frames, sample rate in Hz)."""


def default_renderer(voice: str = "en", rate_wpm: int = DEFAULT_RATE_WPM) -> Renderer:
    """The espeak-ng command line when installed, else the library from the ``espeakng-loader``
    wheel (a non-root machine without the Debian package); SpeechEngineError when neither."""
    try:
        return EspeakNgRenderer(voice, rate_wpm)
    except SpeechEngineError as cli_missing:
        from guidance.voice import libespeak

        if not libespeak.available():
            raise cli_missing from None
        return libespeak.LibEspeakRenderer(voice, rate_wpm)


class EspeakNgRenderer:
    """Renders text with the espeak-ng command line (``--stdout``), one process per prompt.

    Chosen over pyttsx3's ``save_to_file`` for recording (docs/voice.md):
    pyttsx3 2.99 prints "Audio saved to ..." on stdout for every file, shares
    one process-wide espeak engine and callback with the live voice, and
    assumes 22050 Hz; the command line is isolated (a crash is an exit status,
    not a dead app), reports errors, and states its sample rate in the header.
    """

    def __init__(
        self,
        voice: str = "en",
        rate_wpm: int = DEFAULT_RATE_WPM,
        executable: str | None = None,
        timeout_s: float = 10.0,
    ) -> None:
        exe = executable or shutil.which("espeak-ng")
        if exe is None:
            raise SpeechEngineError("espeak-ng not found (Debian package espeak-ng)")
        self._cmd = [exe, "--stdin", "--stdout", "-v", voice, "-s", str(rate_wpm)]
        self._timeout_s = timeout_s

    def __call__(self, text: str) -> tuple[bytes, int]:
        try:
            r = subprocess.run(
                self._cmd, input=text.encode(), capture_output=True, timeout=self._timeout_s
            )
        except (OSError, subprocess.TimeoutExpired) as e:
            raise SpeechEngineError(f"espeak-ng failed: {e}") from e
        if r.returncode != 0:
            detail = r.stderr.decode(errors="replace").strip() or f"exit status {r.returncode}"
            raise SpeechEngineError(f"espeak-ng failed: {detail}")
        try:
            with wave.open(io.BytesIO(r.stdout), "rb") as w:
                if w.getnchannels() != 1 or w.getsampwidth() != 2:
                    raise SpeechEngineError("espeak-ng produced audio that is not 16-bit mono")
                # espeak-ng streams with a placeholder length: read what is there.
                frames = w.readframes(w.getnframes())
                rate = w.getframerate()
        except (wave.Error, EOFError) as e:
            raise SpeechEngineError(f"espeak-ng produced no valid WAV: {e}") from e
        if not frames:
            raise SpeechEngineError("espeak-ng produced no audio")
        return frames, rate


@dataclass(frozen=True, slots=True)
class RecordedPrompt:
    """A prompt as recorded: asked for at ``t_s``, started at ``start_s`` (message clock)."""

    text: str
    priority: Priority
    t_s: float
    start_s: float
    offset_s: float
    duration_s: float


class WavSpeaker(_QueuedSpeaker):
    """Records what a real-time voice would say into one WAV (``--voice-to FILE.wav``).

    Prompts are spoken on a virtual timeline kept on the message clock: the
    voice is busy for each prompt's rendered duration plus ``gap_s``, the same
    PromptQueue picks what comes next, and a prompt that would start too late
    is dropped. So an accelerated simulation records the prompts, and drops
    the ones, that a live drive would, and the result does not depend on how
    fast the machine renders. The WAV holds the prompts back to back with
    ``gap_s`` of silence between them; ``recorded`` says where each one is.
    Rendering runs on its own thread; ``say`` never blocks.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        renderer: Renderer | None = None,
        gap_s: float = 0.5,
        clock: Clock = time.monotonic,
        maxsize: int = DEFAULT_QUEUE_SIZE,
        max_age_s: Mapping[Priority, float] | None = None,
        text_stream: TextIO | None = None,
        fallback: Speaker | None = None,
        volume: float = 1.0,
    ) -> None:
        self.path = Path(path)
        self._volume = min(max(float(volume), 0.0), 1.0)
        self._render = renderer if renderer is not None else default_renderer()
        _, self._rate = self._render("ready")  # fail now, not on the first turn
        self._gap_frames = round(gap_s * self._rate)
        self._gap_s = self._gap_frames / self._rate
        self._clock = clock
        self._queue = PromptQueue(maxsize, clock, max_age_s)
        self._failover = _Failover(fallback, text_stream, clock)
        self._cond = threading.Condition()
        self._lock = self._cond
        self._inbox: list[tuple[str, int, float, float | None]] = []
        self._closing = False
        self._discard = False
        self._recorded: list[RecordedPrompt] = []
        self._counts = {"said": 0, "spoken": 0, "discarded_after_close": 0}
        self._frames = 0
        self._free_s = -math.inf  # when the virtual voice is next free
        # Worker-thread state: the prompt being rendered, arrivals not yet queued.
        self._current: QueuedPrompt | None = None
        self._todo: list[tuple[str, int, float, float | None]] = []
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._wav = wave.open(str(self.path), "wb")  # noqa: SIM115  (closed by the thread)
        self._wav.setnchannels(1)
        self._wav.setsampwidth(2)
        self._wav.setframerate(self._rate)
        self._thread = threading.Thread(target=self._run, name="voice-wav", daemon=True)
        self._thread.start()

    def say(
        self,
        text: str,
        priority: int = 0,
        t_s: float | None = None,
        max_age_s: float | None = None,
    ) -> None:
        t = self._clock() if t_s is None else t_s
        age_ok = max_age_s is None or (math.isfinite(max_age_s) and max_age_s >= 0)
        if not (math.isfinite(t) and age_ok):
            raise ValueError(
                f"prompt time and age must be finite, age >= 0: t_s={t}, max_age_s={max_age_s}"
            )
        with self._cond:
            self._counts["said"] += 1
            if not self._failover.failed:
                if self._closing:
                    self._counts["discarded_after_close"] += 1
                else:
                    self._inbox.append((text, priority, t, max_age_s))
                    self._cond.notify()
                return
        self._failover.speaker.say(text, priority, t)

    def close(self, drain: bool = True, timeout_s: float = 30.0) -> None:
        """Record (``drain``) or discard the pending prompts, finish the WAV, join the thread."""
        with self._cond:
            self._closing = True
            self._discard = not drain
            self._cond.notify()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("WAV recorder still busy after %.1f s; leaving it behind", timeout_s)
        if self._failover.failed:
            self._failover.speaker.close()

    @property
    def renderer_name(self) -> str:
        """The engine that renders the prompts ("PicoRenderer", "EspeakNgRenderer"...)."""
        return type(self._render).__name__

    @property
    def recorded(self) -> tuple[RecordedPrompt, ...]:
        with self._cond:
            return tuple(self._recorded)

    @property
    def duration_s(self) -> float:
        with self._cond:
            return self._frames / self._rate

    def _run(self) -> None:
        try:
            while True:
                with self._cond:
                    while not self._inbox and not self._closing:
                        self._cond.wait()
                    self._todo, self._inbox = self._inbox, []
                    closing, discard = self._closing, self._discard
                if discard:
                    self._queue.clear()
                    self._queue.close()
                    for text, priority, t, age in self._todo:  # counted as discarded
                        self._queue.put(text, priority, t, age, now_s=t)
                    break
                while self._todo:
                    text, priority, t, age = self._todo[0]
                    self._advance_to(t)
                    if len(self._queue) == 0:
                        self._free_s = max(self._free_s, t)  # the voice was idle until t
                    self._queue.put(text, priority, t, age, now_s=t)
                    del self._todo[0]
                if closing:
                    self._advance_to(math.inf)
                    break
        except Exception as e:
            self._fail(str(e) if isinstance(e, SpeechEngineError) else f"{type(e).__name__}: {e}")
        finally:
            self._wav.close()

    def _advance_to(self, t_s: float) -> None:
        """Speak, on the virtual timeline, every prompt the voice would start by ``t_s``."""
        while len(self._queue) > 0 and self._free_s <= t_s:
            prompt = self._queue.pop(now_s=self._free_s)
            if prompt is None:
                return
            self._current = prompt
            pcm, rate = self._render(prompt.text)
            pcm = normalise_level(pcm, self._volume)
            if rate != self._rate:
                raise SpeechEngineError(f"sample rate changed from {self._rate} to {rate} Hz")
            gap = self._gap_frames if self._frames else 0
            self._wav.writeframes(b"\0\0" * gap + pcm)
            n = len(pcm) // 2
            offset_s = (self._frames + gap) / self._rate
            duration_s = n / self._rate
            with self._cond:
                self._frames += gap + n
                self._counts["spoken"] += 1
                self._recorded.append(
                    RecordedPrompt(
                        prompt.text, prompt.priority, prompt.t_s, self._free_s, offset_s, duration_s
                    )
                )
            self._current = None
            self._free_s += duration_s + self._gap_s

    def _fail(self, reason: str) -> None:
        """Warn once; show the prompt in hand, the queued and the unqueued ones as text."""
        with self._cond:
            n = len(self._recorded)
            text = self._failover.fail(
                reason, "speech engine (espeak-ng)", f"; {self.path} holds the {n} recorded so far"
            )
            current = [] if self._current is None else [self._current]
            pending = [(p.text, int(p.priority), p.t_s) for p in current + self._queue.take_all()]
            pending += [(s, pr, t) for s, pr, t, _ in self._todo + self._inbox]
            self._todo, self._inbox = [], []
            for s, pr, t in pending:  # under the lock: later prompts cannot overtake these
                text.say(s, pr, t)
