"""Speaker backends: text, pyttsx3 (with failover to text), and their health
(docs/voice.md).
"""

from __future__ import annotations

import io
import logging
import shutil
import subprocess
import sys
import threading
import time
import wave
from collections.abc import Callable, Mapping
from typing import Protocol, TextIO

from guidance.core.messages import Health, Priority, Say, Speech
from guidance.core.speech import words
from guidance.voice.queue import (
    DEFAULT_QUEUE_SIZE,
    DEFAULT_RATE_WPM,
    Clock,
    PromptQueue,
    QueuedPrompt,
)
from guidance.voice.speaker import Speaker

log = logging.getLogger(__name__)


class SpeechEngineError(RuntimeError):
    """The speech engine is missing, cannot start, or failed while speaking."""


# ------------------------------------------------------------------------ health


def _speaker_health(
    name: str, failed_reason: str | None, counters: Mapping[str, int], closed: bool = False
) -> Health:
    """A speaker's health, the drivers' record (docs/reliability.md).

    ``alive``: prompts reach the driver (spoken, or shown as text after a failure);
    ``valid``: they are spoken as configured. ``status`` is "ok", "text_fallback" (the
    engine failed or never started) or "stopped"; ``detail`` says why. ``age_s`` is None.
    """
    if failed_reason is not None:
        return Health(
            name,
            "text_fallback",
            alive=True,
            valid=False,
            counters=counters,
            detail=failed_reason,
            warning=words(Say(Speech.COMPONENT, input="voice", status="text_fallback")),
        )
    return Health(
        name, "stopped" if closed else "ok", alive=not closed, valid=not closed, counters=counters
    )


# ------------------------------------------------------------------------ speakers


class TextSpeaker:
    """Shows prompts as text lines: the backend when no speech engine exists.

    Writes at once (nothing to queue); ``stream`` defaults to stderr at call
    time, so stdout stays for the app's own output (``--json``). ``fallback_reason``
    says why text was chosen when speech was asked for (``make_speaker``); the
    health then reports the fallback.
    """

    def __init__(
        self,
        stream: TextIO | None = None,
        clock: Clock = time.monotonic,
        fallback_reason: str | None = None,
    ) -> None:
        self._stream = stream
        self._clock = clock
        self.fallback_reason = fallback_reason
        self._lock = threading.Lock()
        self._counts = {"said": 0, "shown": 0}

    def say(
        self,
        text: str,
        priority: int = 0,
        t_s: float | None = None,
        max_age_s: float | None = None,
    ) -> None:
        t = self._clock() if t_s is None else t_s
        line = f"[prompt {t:9.2f} s {Priority.of(priority).name}] {' '.join(text.split())}\n"
        with self._lock:
            self._counts["said"] += 1
            stream = self._stream if self._stream is not None else sys.stderr
            stream.write(line)
            stream.flush()
            self._counts["shown"] += 1

    def redirect(self, stream: TextIO) -> None:
        """Write to ``stream`` from now on (the operator screen's, while its live view owns
        the terminal: lines written to the terminal would be drawn over it)."""
        with self._lock:
            self._stream = stream

    def close(self, drain: bool = True, timeout_s: float = 0.0) -> None:
        """Nothing to release; present for the Speaker interface."""

    def stats(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def health(self) -> Health:
        return _speaker_health("voice", self.fallback_reason, self.stats())


class _Failover:
    """Switches a speaker to text once, logging the failure exactly once."""

    def __init__(self, fallback: Speaker | None, stream: TextIO | None, clock: Clock) -> None:
        self._fallback = fallback
        self._stream = stream
        self._clock = clock
        self.reason: str | None = None

    @property
    def failed(self) -> bool:
        return self.reason is not None

    def fail(self, reason: str, what: str, suffix: str = "") -> Speaker:
        """Record the first failure (warning once) and return the text backend."""
        if self.reason is None:
            self.reason = reason
            log.warning(
                "%s failed (%s); remaining prompts are shown as text%s", what, reason, suffix
            )
        return self.speaker

    @property
    def speaker(self) -> Speaker:
        if self._fallback is None:
            self._fallback = TextSpeaker(self._stream, self._clock)
        return self._fallback


class _Engine(Protocol):
    """The part of ``pyttsx3.Engine`` this module uses."""

    def say(self, text: str) -> None: ...
    def runAndWait(self) -> None: ...


def _silence_wav(duration_s: float = 0.05, rate: int = 22050) -> bytes:
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(b"\0\0" * int(rate * duration_s))
    return buf.getvalue()


def check_audio_output(timeout_s: float = 5.0) -> None:
    """Raise SpeechEngineError unless ``aplay`` can open the default sound device.

    pyttsx3's espeak driver plays each utterance with ``aplay`` and ignores its
    exit status, so a missing tool or sound card would otherwise go unnoticed.
    """
    aplay = shutil.which("aplay")
    if aplay is None:
        raise SpeechEngineError(
            "aplay not found (Debian package alsa-utils); pyttsx3's espeak driver plays through it"
        )
    try:
        r = subprocess.run(
            [aplay, "-q", "-"], input=_silence_wav(), capture_output=True, timeout=timeout_s
        )
    except (OSError, subprocess.TimeoutExpired) as e:
        raise SpeechEngineError(f"aplay failed: {e}") from e
    if r.returncode != 0:
        lines = r.stderr.decode(errors="replace").strip().splitlines()
        detail = lines[-1] if lines else f"exit status {r.returncode}"
        raise SpeechEngineError(f"no audio output device: {detail}")


def _uses_espeak(driver_name: str | None) -> bool:
    return driver_name == "espeak" or (driver_name is None and sys.platform.startswith("linux"))


class _QueuedSpeaker:
    """What a queued speaker with a text failover reports: ``failed``, ``stats``, ``health``
    (after the engine failed, the prompts go on as text). Subclasses set ``_failover``,
    ``_queue``, ``_counts`` and ``_lock``."""

    _failover: _Failover
    _queue: PromptQueue
    _counts: dict[str, int]
    _lock: threading.Lock | threading.Condition

    @property
    def failed(self) -> bool:
        return self._failover.failed

    def _enqueue(
        self, text: str, priority: int, t_s: float | None, max_age_s: float | None
    ) -> None:
        """Queue a prompt for the engine's thread, or, once the engine failed, hand it to the
        failover (text, or the fallback voice)."""
        with self._lock:
            self._counts["said"] += 1
            if not self._failover.failed:
                self._queue.put(text, priority, t_s, max_age_s)
                return
        self._failover.speaker.say(text, priority, t_s)

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {**self._queue.stats(), **self._counts, "failed": int(self.failed)}

    def health(self) -> Health:
        """'text_fallback' after the engine failed; a WAV keeps what was recorded."""
        counters = self.stats()
        if self._failover.failed:
            counters["shown_as_text"] = _shown(self._failover.speaker)
        return _speaker_health("voice", self._failover.reason, counters)


class Pyttsx3Speaker(_QueuedSpeaker):
    """Speaks prompts through pyttsx3 on its own thread, fed by a PromptQueue.

    ``say`` never blocks. The engine is created and used on the speaking
    thread. If it raises, or one utterance takes longer than ``hang_timeout_s``
    (wall clock), the failure is logged once and the pending and later prompts
    go to text. pyttsx3 shares one engine per driver per process: make one
    Pyttsx3Speaker per process.
    """

    def __init__(
        self,
        driver_name: str | None = None,
        *,
        clock: Clock = time.monotonic,
        maxsize: int = DEFAULT_QUEUE_SIZE,
        max_age_s: Mapping[Priority, float] | None = None,
        rate_wpm: int | None = DEFAULT_RATE_WPM,
        voice: str | None = None,
        volume: float | None = None,
        engine_factory: Callable[[], _Engine] | None = None,
        check_audio: bool = True,
        text_stream: TextIO | None = None,
        fallback: Speaker | None = None,
        init_timeout_s: float = 10.0,
        hang_timeout_s: float = 30.0,
    ) -> None:
        self._clock = clock
        self._queue = PromptQueue(maxsize, clock, max_age_s)
        self._hang_timeout_s = hang_timeout_s
        self._lock = threading.Lock()
        self._failover = _Failover(fallback, text_stream, clock)
        self._counts = {"said": 0, "spoken": 0}
        self._speaking_since: float | None = None
        self._init_error: BaseException | None = None
        self._ready = threading.Event()
        if engine_factory is None:
            if check_audio and _uses_espeak(driver_name):
                check_audio_output()
            engine_factory = _pyttsx3_factory(driver_name, rate_wpm, voice, volume)
        self._thread = threading.Thread(
            target=self._run, args=(engine_factory,), name="voice-pyttsx3", daemon=True
        )
        self._thread.start()
        if not self._ready.wait(init_timeout_s):
            self._queue.close()
            raise SpeechEngineError(f"pyttsx3 did not start within {init_timeout_s:.0f} s")
        if self._init_error is not None:
            self._thread.join(init_timeout_s)
            e = self._init_error
            raise SpeechEngineError(
                f"pyttsx3 driver {driver_name or 'default'!r} did not start: "
                f"{type(e).__name__}: {e}"
            ) from e

    def say(
        self,
        text: str,
        priority: int = 0,
        t_s: float | None = None,
        max_age_s: float | None = None,
    ) -> None:
        since = self._speaking_since
        if since is not None and time.monotonic() - since > self._hang_timeout_s:
            self._fail(f"one utterance took over {self._hang_timeout_s:.0f} s", None)
        self._enqueue(text, priority, t_s, max_age_s)

    def close(self, drain: bool = True, timeout_s: float = 10.0) -> None:
        """Stop taking prompts; speak (``drain``) or discard the pending ones; join the thread."""
        if not drain:
            self._queue.clear()
        self._queue.close()
        # A hung engine will not come back: do not hold up shutdown for it.
        self._thread.join(min(timeout_s, 1.0) if self._failover.failed else timeout_s)
        if self._thread.is_alive():
            log.warning("speech thread still busy after %.1f s; leaving it behind", timeout_s)
        if self._failover.failed:
            self._failover.speaker.close()

    def _run(self, engine_factory: Callable[[], _Engine]) -> None:
        try:
            engine = engine_factory()
        except Exception as e:
            self._init_error = e
            self._ready.set()
            return
        self._ready.set()
        while True:
            prompt = self._queue.get()
            if prompt is None or self._failover.failed:
                break
            self._speaking_since = time.monotonic()
            try:
                engine.say(prompt.text)
                engine.runAndWait()
            except Exception as e:
                self._fail(f"{type(e).__name__}: {e}", prompt)
                break
            finally:
                self._speaking_since = None
            if self._failover.failed:  # declared hung while speaking this one
                break
            with self._lock:
                self._counts["spoken"] += 1

    def _fail(self, reason: str, current: QueuedPrompt | None) -> None:
        with self._lock:
            if self._failover.failed:
                return
            text = self._failover.fail(reason, "speech engine (pyttsx3)")
            self._queue.close()
            pending = ([current] if current is not None else []) + self._queue.take_all()
            for p in pending:  # under the lock: later prompts cannot overtake these
                text.say(p.text, p.priority, p.t_s)


def _pyttsx3_factory(
    driver_name: str | None,
    rate_wpm: int | None,
    voice: str | None = None,
    volume: float | None = None,
) -> Callable[[], _Engine]:
    def make() -> _Engine:
        import pyttsx3  # imported on first use: the text backend must work without it

        engine = pyttsx3.init(driver_name)
        if rate_wpm is not None:
            engine.setProperty("rate", rate_wpm)
        if volume is not None:
            engine.setProperty("volume", min(max(float(volume), 0.0), 1.0))
        if voice:
            try:  # espeak voice ids look like "gmw/en-us"; a language code is matched to one
                ids = [v.id for v in engine.getProperty("voices")]
                match = next((i for i in ids if i == voice or i.endswith("/" + voice)), None)
                if match is not None:
                    engine.setProperty("voice", match)
                else:
                    log.warning("voice %r not found; using the engine's default", voice)
            except Exception:  # a driver without a voice list keeps its default
                log.warning("voice %r could not be set; using the engine's default", voice)
        made: _Engine = engine
        return made

    return make


def _shown(speaker: Speaker) -> int:
    """Prompts a fallback speaker has shown (0 when it does not count them)."""
    stats = getattr(speaker, "stats", None)
    return int(stats().get("shown", 0)) if callable(stats) else 0
