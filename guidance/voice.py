"""Spoken driver prompts: a bounded priority queue, the Speaker backends, prompt timing.

SPEC section 6 and issue 4 ("Voice"); design notes in docs/voice.md.

* ``PromptQueue`` is pure logic: bounded, priority tiers, de-duplication of
  pending text, staleness measured on the message clock (a callable passed in).
* ``Pyttsx3Speaker`` speaks through pyttsx3 (espeak-ng on Linux) on its own
  thread; ``WavSpeaker`` records what a real-time voice would say into one WAV
  (``--voice-to FILE.wav``); ``TextSpeaker`` shows prompts as text lines.
  ``make_speaker`` picks one and falls back to text with a single warning.
* A speech engine that fails mid-drive is logged once; the process keeps
  running and the remaining prompts are shown as text (issue 7).
* ``announcement_distances_m``/``due_announcements`` time the two turn
  announcements by speed (Organic Maps' two-notification scheme). When the
  distance to the next intersection is unknown (in the car), the app announces
  the next decision right after each intersection instead.
"""

from __future__ import annotations

import io
import logging
import math
import shutil
import subprocess
import sys
import threading
import time
import wave
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, replace
from enum import IntEnum
from pathlib import Path
from typing import Literal, Protocol, TextIO

from drivers.health import DeviceHealth
from guidance.interfaces import Speaker

log = logging.getLogger(__name__)

Clock = Callable[[], float]
"""Returns the current time on the message clock (monotonic seconds)."""


class SpeechEngineError(RuntimeError):
    """The speech engine is missing, cannot start, or failed while speaking."""


class Priority(IntEnum):
    """Prompt tiers: a higher tier is spoken first and dropped last.

    ``LOST`` is an alias of ``SAFETY``: "position lost" shares the top tier
    with sensor and uncertainty warnings.
    """

    INFO = 0
    GUIDANCE = 1
    SAFETY = 2
    LOST = 2

    @classmethod
    def of(cls, value: int) -> Priority:
        """Clamp a plain int (the Speaker protocol's ``priority``) onto a tier."""
        return cls(min(max(int(value), int(cls.INFO)), int(cls.SAFETY)))


DEFAULT_MAX_AGE_S: Mapping[Priority, float] = {
    Priority.SAFETY: 15.0,  # a warning or "lost" is still true a while later
    Priority.GUIDANCE: 5.0,  # 70 m at 50 km/h: a turn prompt older than this misleads
    Priority.INFO: 10.0,
}
"""How old (message-clock seconds since ``t_s``) a prompt may be when it starts."""

DEFAULT_QUEUE_SIZE = 8
DEFAULT_RATE_WPM = 170
"""Speech rate: a little slower than espeak-ng's 175 wpm, for a driver in traffic."""


# --------------------------------------------------------------------------- queue


@dataclass(frozen=True, slots=True)
class Prompt:
    """One pending prompt. ``seq`` is the arrival order (FIFO within a tier)."""

    text: str
    priority: Priority
    t_s: float
    max_age_s: float
    seq: int

    @property
    def deadline_s(self) -> float:
        """The last message-clock time at which speaking it may start."""
        return self.t_s + self.max_age_s

    def is_stale(self, now_s: float) -> bool:
        return now_s > self.deadline_s


QUEUE_COUNTERS = (
    "queued",
    "popped",
    "deduplicated",
    "dropped_stale",
    "dropped_overflow",
    "discarded",
)


class PromptQueue:
    """Bounded, thread-safe priority FIFO of driver prompts.

    * Order: highest ``Priority`` first, then arrival order.
    * De-duplication: a prompt whose text is already pending refreshes that
      entry (higher priority, later deadline) and keeps its place.
    * Staleness: a prompt that would start after ``t_s + max_age_s`` is dropped
      (on ``put`` and when popped), measured on ``clock``: the message clock.
    * Full: the lowest-priority, oldest prompt is dropped, possibly the new one.

    Every drop is counted in ``stats()``. ``now_s`` arguments override the
    clock (the WAV recorder runs on a virtual speaking clock).
    """

    def __init__(
        self,
        maxsize: int = DEFAULT_QUEUE_SIZE,
        clock: Clock = time.monotonic,
        max_age_s: Mapping[Priority, float] | None = None,
    ) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be at least 1, got {maxsize}")
        self.maxsize = maxsize
        self._clock = clock
        self._max_age_s = dict(DEFAULT_MAX_AGE_S if max_age_s is None else max_age_s)
        self._cond = threading.Condition()
        self._items: list[Prompt] = []
        self._seq = 0
        self._closed = False
        self._counts = dict.fromkeys(QUEUE_COUNTERS, 0)

    def put(
        self,
        text: str,
        priority: int = Priority.GUIDANCE,
        t_s: float | None = None,
        max_age_s: float | None = None,
        *,
        now_s: float | None = None,
    ) -> bool:
        """Queue a prompt; False when it was dropped (stale, overflow, empty, closed)."""
        text = " ".join(text.split())
        tier = Priority.of(priority)
        with self._cond:
            now = self._clock() if now_s is None else now_s
            t = now if t_s is None else t_s
            age = (
                self._max_age_s.get(tier, DEFAULT_MAX_AGE_S[tier])
                if max_age_s is None
                else max_age_s
            )
            if not (math.isfinite(t) and math.isfinite(age) and age >= 0):
                raise ValueError(
                    f"prompt time and age must be finite, age >= 0: t_s={t}, max_age_s={age}"
                )
            if not text:
                return False
            if self._closed:
                self._counts["discarded"] += 1
                return False
            self._drop_stale(now)
            new = Prompt(text, tier, t, age, self._seq)
            self._seq += 1
            if new.is_stale(now):
                self._counts["dropped_stale"] += 1
                return False
            for i, old in enumerate(self._items):
                if old.text == text:
                    later = new if new.deadline_s > old.deadline_s else old
                    self._items[i] = replace(
                        old,
                        priority=max(old.priority, tier),
                        t_s=later.t_s,
                        max_age_s=later.max_age_s,
                    )
                    self._counts["deduplicated"] += 1
                    self._cond.notify()
                    return True
            self._items.append(new)
            if len(self._items) > self.maxsize:
                victim = min(self._items, key=lambda p: (p.priority, p.seq))
                self._items.remove(victim)
                self._counts["dropped_overflow"] += 1
                if victim is new:
                    return False
            self._counts["queued"] += 1
            self._cond.notify()
            return True

    def pop(self, now_s: float | None = None) -> Prompt | None:
        """The next prompt to speak now, or None; stale prompts are dropped first."""
        with self._cond:
            return self._pop_locked(self._clock() if now_s is None else now_s)

    def get(self, timeout_s: float | None = None) -> Prompt | None:
        """Block (wall-clock ``timeout_s``) until a fresh prompt is ready; None once closed."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while True:
                prompt = self._pop_locked(self._clock())
                if prompt is not None or self._closed:
                    return prompt
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)

    def take_all(self) -> list[Prompt]:
        """Remove and return every pending prompt in speaking order (for a failover)."""
        with self._cond:
            items = sorted(self._items, key=lambda p: (-p.priority, p.seq))
            self._items.clear()
            return items

    def clear(self) -> int:
        """Discard every pending prompt; returns how many (counted as discarded)."""
        with self._cond:
            n = len(self._items)
            self._items.clear()
            self._counts["discarded"] += n
            return n

    def close(self) -> None:
        """Refuse new prompts and wake ``get``; pending prompts can still be popped."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

    def stats(self) -> dict[str, int]:
        with self._cond:
            return dict(self._counts)

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def _drop_stale(self, now_s: float) -> None:
        fresh = [p for p in self._items if not p.is_stale(now_s)]
        self._counts["dropped_stale"] += len(self._items) - len(fresh)
        self._items[:] = fresh

    def _pop_locked(self, now_s: float) -> Prompt | None:
        self._drop_stale(now_s)
        if not self._items:
            return None
        best = max(self._items, key=lambda p: (p.priority, -p.seq))
        self._items.remove(best)
        self._counts["popped"] += 1
        return best


# ------------------------------------------------------------------------ health

SPEECH_FAILED_WARNING = "Voice prompts failed. Prompts are shown as text."
"""Shown (it cannot be spoken) when the speech engine is missing or fails."""


@dataclass(frozen=True, slots=True)
class SpeakerHealth(DeviceHealth):
    """A speaker's health: the drivers' record (same keys, docs/reliability.md).

    ``alive``: prompts reach the driver (spoken, or shown as text after a failure);
    ``valid``: they are spoken as configured. ``status`` is "ok", "text_fallback" (the
    engine failed or never started) or "stopped". ``age_s`` is always None.
    """


def _speaker_health(
    name: str, failed_reason: str | None, counters: Mapping[str, int], closed: bool = False
) -> SpeakerHealth:
    if failed_reason is not None:
        return SpeakerHealth(
            name,
            "text_fallback",
            alive=True,
            valid=False,
            counters=counters,
            last_error=failed_reason,
            warning=SPEECH_FAILED_WARNING,
        )
    return SpeakerHealth(
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

    def close(self, drain: bool = True, timeout_s: float = 0.0) -> None:
        """Nothing to release; present for the Speaker interface."""

    def stats(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def health(self) -> SpeakerHealth:
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


class Pyttsx3Speaker:
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
            engine_factory = _pyttsx3_factory(driver_name, rate_wpm)
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
        with self._lock:
            self._counts["said"] += 1
            if not self._failover.failed:
                self._queue.put(text, priority, t_s, max_age_s)
                return
        self._failover.speaker.say(text, priority, t_s)

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

    @property
    def failed(self) -> bool:
        return self._failover.failed

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {**self._queue.stats(), **self._counts, "failed": int(self.failed)}

    def health(self) -> SpeakerHealth:
        """'text_fallback' after the engine failed; the prompts go on as text."""
        counters = self.stats()
        if self._failover.failed:
            counters["shown_as_text"] = _shown(self._failover.speaker)
        return _speaker_health("voice", self._failover.reason, counters)

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

    def _fail(self, reason: str, current: Prompt | None) -> None:
        with self._lock:
            if self._failover.failed:
                return
            text = self._failover.fail(reason, "speech engine (pyttsx3)")
            self._queue.close()
            pending = ([current] if current is not None else []) + self._queue.take_all()
            for p in pending:  # under the lock: later prompts cannot overtake these
                text.say(p.text, p.priority, p.t_s)


def _pyttsx3_factory(driver_name: str | None, rate_wpm: int | None) -> Callable[[], _Engine]:
    def make() -> _Engine:
        import pyttsx3  # imported on first use: the text backend must work without it

        engine = pyttsx3.init(driver_name)
        if rate_wpm is not None:
            engine.setProperty("rate", rate_wpm)
        made: _Engine = engine
        return made

    return make


# ----------------------------------------------------------------------- WAV output

Renderer = Callable[[str], tuple[bytes, int]]
"""Renders text to 16-bit mono PCM; returns (frames, sample rate in Hz)."""


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


class WavSpeaker:
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
    ) -> None:
        self.path = Path(path)
        self._render = renderer if renderer is not None else EspeakNgRenderer()
        _, self._rate = self._render("ready")  # fail now, not on the first turn
        self._gap_frames = round(gap_s * self._rate)
        self._gap_s = self._gap_frames / self._rate
        self._clock = clock
        self._queue = PromptQueue(maxsize, clock, max_age_s)
        self._failover = _Failover(fallback, text_stream, clock)
        self._cond = threading.Condition()
        self._inbox: list[tuple[str, int, float, float | None]] = []
        self._closing = False
        self._discard = False
        self._recorded: list[RecordedPrompt] = []
        self._counts = {"said": 0, "spoken": 0, "discarded_after_close": 0}
        self._frames = 0
        self._free_s = -math.inf  # when the virtual voice is next free
        # Worker-thread state: the prompt being rendered, arrivals not yet queued.
        self._current: Prompt | None = None
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
    def recorded(self) -> tuple[RecordedPrompt, ...]:
        with self._cond:
            return tuple(self._recorded)

    @property
    def duration_s(self) -> float:
        with self._cond:
            return self._frames / self._rate

    @property
    def failed(self) -> bool:
        return self._failover.failed

    def stats(self) -> dict[str, int]:
        with self._cond:
            return {**self._queue.stats(), **self._counts, "failed": int(self.failed)}

    def health(self) -> SpeakerHealth:
        """'text_fallback' after the renderer failed; the WAV keeps what was recorded."""
        counters = self.stats()
        if self._failover.failed:
            counters["shown_as_text"] = _shown(self._failover.speaker)
        return _speaker_health("voice", self._failover.reason, counters)

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


def _shown(speaker: Speaker) -> int:
    """Prompts a fallback speaker has shown (0 when it does not count them)."""
    stats = getattr(speaker, "stats", None)
    return int(stats().get("shown", 0)) if callable(stats) else 0


# ---------------------------------------------------------------------------- choice

SpeakerKind = Literal["auto", "voice", "wav", "text"]


def make_speaker(
    kind: SpeakerKind = "auto",
    wav_path: str | Path | None = None,
    *,
    clock: Clock = time.monotonic,
    driver_name: str | None = None,
    text_stream: TextIO | None = None,
    maxsize: int = DEFAULT_QUEUE_SIZE,
    max_age_s: Mapping[Priority, float] | None = None,
) -> Speaker:
    """The Speaker asked for, or text with one clear warning when speech cannot start.

    ``auto`` records to ``wav_path`` when given, else speaks. ``clock`` is the
    message clock that prompt times ``t_s`` are on (simulated time in ``sim``).
    """
    if kind == "text":
        return TextSpeaker(text_stream, clock)
    suffix = ""
    try:
        if kind == "wav" or (kind == "auto" and wav_path is not None):
            if wav_path is None:
                raise ValueError("speaker kind 'wav' needs wav_path")
            suffix = f"; {wav_path} is not written"
            return WavSpeaker(
                wav_path, clock=clock, maxsize=maxsize, max_age_s=max_age_s, text_stream=text_stream
            )
        if kind in ("voice", "auto"):
            return Pyttsx3Speaker(
                driver_name,
                clock=clock,
                maxsize=maxsize,
                max_age_s=max_age_s,
                text_stream=text_stream,
            )
    except SpeechEngineError as e:
        log.warning("no speech engine (%s); prompts are shown as text%s", e, suffix)
        return TextSpeaker(text_stream, clock, fallback_reason=str(e))
    raise ValueError(f"unknown speaker kind {kind!r}; expected auto, voice, wav or text")


# --------------------------------------------------------------------- prompt timing

Announcement = Literal["early", "before"]

# Organic Maps, routing/turns_notification_manager.cpp and turns_sound_settings.cpp
# (vehicle, metric): the first notification comes 30 s ahead, clamped to
# 200..2000 m, plus the distance covered while it is spoken; the second when
# the car is within 8 s of the turn, clamped to 35..150 m. No first notification
# when the turn is already within 170 m. OsmAnd's AnnounceTimeDistances agrees:
# "turn in" 22 s ahead (275 m at 45 km/h), "turn now" about 7 s or 45 m ahead.
EARLY_TIME_S = 30.0
EARLY_MIN_M = 200.0
EARLY_MAX_M = 2000.0
BEFORE_TIME_S = 8.0
BEFORE_MIN_M = 35.0
BEFORE_MAX_M = 150.0
EARLY_TOO_CLOSE_M = 170.0


@dataclass(frozen=True, slots=True)
class AnnouncementDistances:
    """Distances to the intersection (m) inside which each announcement is due."""

    early_m: float
    before_m: float
    too_close_for_early_m: float = EARLY_TOO_CLOSE_M


def _clamp(x: float, lo: float, hi: float) -> float:
    return min(max(x, lo), hi)


def _check_speed(speed_mps: float) -> float:
    if not math.isfinite(speed_mps):
        raise ValueError(f"speed must be finite, got {speed_mps}")
    return max(0.0, speed_mps)


def announcement_distances_m(speed_mps: float) -> AnnouncementDistances:
    """Where the early ("In 300 metres, turn left") and just-before ("Turn left") prompts start.

    Both scale with speed so the driver gets about the same time to act; a
    negative speed counts as standstill.
    """
    v = _check_speed(speed_mps)
    before_m = _clamp(BEFORE_TIME_S * v, BEFORE_MIN_M, BEFORE_MAX_M)
    early_m = _clamp(EARLY_TIME_S * v, EARLY_MIN_M, EARLY_MAX_M) + before_m
    return AnnouncementDistances(early_m=early_m, before_m=before_m)


def due_announcements(
    distance_to_intersection_m: float,
    speed_mps: float,
    already_announced: Collection[str],
) -> tuple[Announcement, ...]:
    """Which announcements for the next intersection are due now: (), ("early",) or ("before",).

    The caller adds what it announced to ``already_announced`` and resets it
    after the intersection. "before" supersedes a pending "early" (no double
    prompt), and "early" is skipped when the intersection is already within
    ``EARLY_TOO_CLOSE_M``, as in Organic Maps.
    """
    if not math.isfinite(distance_to_intersection_m):
        raise ValueError(f"distance must be finite, got {distance_to_intersection_m}")
    d = max(0.0, distance_to_intersection_m)
    if "before" in already_announced:
        return ()
    dist = announcement_distances_m(speed_mps)
    if d <= dist.before_m:
        return ("before",)
    if "early" not in already_announced and dist.too_close_for_early_m < d <= dist.early_m:
        return ("early",)
    return ()
