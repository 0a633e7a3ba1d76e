"""The co-driver's spoken reports: a microphone as one more co-driver input (issue 39).

The microphone is read with ALSA's ``arecord`` (16 kHz mono, 16-bit) on a reader thread, the
same sound system the car's voice plays through (docs/dependencies.md); a WAV file or a FIFO of
raw samples reads the same way (tests, ``guidance voice listen``). The reader thread only moves
audio blocks: cutting utterances and decoding them (``drivers.speech_worker.UtteranceStream``,
``drivers.speech_grammar.CommandRecogniser``) run in a worker process (``ProcessListener``), or
in this one when a recogniser is given (tests, tools). Each utterance, when it is a command
heard with enough
confidence, to ``drivers.keyboard.CoDriverLines`` as the line the keypad would have sent: the
same acknowledgements, help and commands. Every report is read back through ``read_back`` as
an event (``Say(Speech.READ_BACK, line=...)``: "Left, straight, right." in the sentence table,
``guidance.core.speech``), so a driver alone knows what was heard; a doubtful one is answered
``Speech.SAY_AGAIN``.

**When it listens** (``talk``):

* ``key`` (the default, push-to-talk): only while the keypad's talk key (``5``, unused
  otherwise) is held (``set_talking``); the utterance is what was said between press and release.
  Cars put the voice button on the steering wheel for the same reasons: no false command from
  the radio, a passenger or the car itself, no wake word to say before every report, and the
  recogniser runs only while the key is down.
* ``wake``: voice activity cuts the audio into utterances, and one is a command only after the
  wake word (``drivers.speech_grammar.WAKE_WORD``, "navigator": "navigator, left straight
  right", or the wake word alone and the command within 4 s), spotted by pocketsphinx's
  keyword search; what follows it is heard as a held key's. For a car with no keypad.
* ``always``: voice activity cuts the audio into utterances and every one is tried, the
  confidence threshold alone keeping talk out: it takes few commands (docs/voice.md).

**The car's own voice is never a command**: the input is deaf while the car speaks and for
``deaf_tail_s`` after (``car_voice.busy``: what ``guidance.voice.activity.CarVoice`` reports),
and a phrase whose words are a run of words of a sentence the car said in the last
``echo_window_s`` is refused (counted ``refused_echo``).
"""

from __future__ import annotations

import functools
import os
import re
import select
import shutil
import stat
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from drivers._reader import ThreadedSource
from drivers.keyboard import CoDriverLines, Feedback, SceneMessage
from drivers.speech_grammar import RATE_HZ, WAKE_WORD, CommandRecogniser, Heard, read_wav_16k
from drivers.speech_worker import (
    TALK_MODES,
    Listener,
    Outcome,
    ProcessListener,
    UtteranceStream,
)
from guidance.core.messages import Say, Speech

CHUNK = 480
"""Samples read at a time: 30 ms, the voice activity detector's frame."""


class CarVoiceState(Protocol):
    """What the speech input asks of the car's voice (``guidance.voice.activity.CarVoice``)."""

    def busy(self, tail_s: float = 0.0, at_s: float | None = None) -> bool: ...
    def recent(self, within_s: float = 30.0) -> tuple[str, ...]: ...


@dataclass(frozen=True, slots=True)
class SpeechInputConfig:
    """``[scene] speech``: the microphone and when it listens."""

    device: str = "default"
    """The ALSA capture device (``arecord -D``), or a WAV file or FIFO of raw 16 kHz samples."""
    talk: str = "key"
    """``key``: push-to-talk on the keypad's talk key; ``wake``: a command after the wake word
    ("navigator, left straight right"); ``always``: every stretch of voice is tried."""
    deaf_tail_s: float = 0.7
    """Deaf this long after the car stops speaking (its echo in the cabin, the read-back)."""
    echo_window_s: float = 8.0
    """A phrase the car started saying within this many seconds is refused (a prompt lasts
    2-4 s; beyond the deaf tail this catches a late echo or a voice not reported)."""
    stale_after_s: float = 2.0
    """The microphone sends 32 kB/s even in silence: 2 s of nothing is a dead device."""
    reconnect_max_s: float = 5.0


_WORD_RE = re.compile(r"[a-z]+")


def _words(text: str) -> list[str]:
    return _WORD_RE.findall(text.lower().replace("-", " "))


def is_echo(heard: str, said: tuple[str, ...]) -> bool:
    """True when the words of ``heard`` are a run of words of one of the sentences ``said``."""
    h = _words(heard)
    if not h:
        return False
    for sentence in said:
        s = _words(sentence)
        if any(s[i : i + len(h)] == h for i in range(len(s) - len(h) + 1)):
            return True
    return False


class SpeechInput(ThreadedSource[SceneMessage]):
    """Co-driver reports spoken into a microphone (see the module docstring)."""

    sink_kind: ClassVar[str] = "scene"
    unit: ClassVar[str] = "utterances"
    announce_first_connect: ClassVar[bool] = True

    def __init__(
        self,
        config: SpeechInputConfig,
        heading_fn: Callable[[], float],
        *,
        clock: Callable[[], float] = time.monotonic,
        feedback: Feedback | None = None,
        echo: Feedback | None = None,
        on_command: Callable[[str], str] | None = None,
        read_back: Callable[[Say], None] | None = None,
        car_voice: CarVoiceState | None = None,
        recogniser: CommandRecogniser | None = None,
        listener: Listener | None = None,
        name: str = "speech",
    ) -> None:
        if config.talk not in TALK_MODES:
            raise ValueError(f"talk must be one of {', '.join(TALK_MODES)}, not {config.talk!r}")
        super().__init__(name, config, clock=clock)
        self.config = config
        self._device = config.device
        self.lines = CoDriverLines(
            name, heading_fn, clock=clock, feedback=feedback, echo=echo, on_command=on_command
        )
        self.read_back = read_back
        self.car_voice = car_voice
        self.error = ""
        self._talking = threading.Event()
        self._audio_s = 0.0
        self._t0 = 0.0
        self._listener: Listener | None = listener
        """Where utterances are cut and decoded: given (a benchmark), in this process when a
        ``recogniser`` is given (tests, tools), else a worker process this input starts."""
        if listener is None and recogniser is not None:
            self._listener = UtteranceStream(recogniser, config.talk)
        self._own = listener is None and recogniser is None
        self.heard: list[Heard] = []
        """Every utterance taken or answered (the operator screen shows the last)."""

    # -- the talk key ------------------------------------------------------------------------------
    def set_talking(self, down: bool) -> None:
        """The talk key went down (listen) or up (the utterance is complete)."""
        if down:
            self._talking.set()
        else:
            self._talking.clear()

    @property
    def connected(self) -> bool:
        return bool(self._connected)

    def describe(self) -> str:
        """What the operator screen shows for this input."""
        how = {"key": "hold 5 to talk", "wake": f"say {WAKE_WORD!r} first"}.get(
            self.config.talk, "always listening"
        )
        what = f"microphone {self.config.device} ({how})"
        if self._connected:
            last = self.heard[-1] if self.heard else None
            if last is not None:
                said = last.line or "say again"
                what += f"; heard {last.text!r} -> {said} ({last.confidence:.2f})"
            return what
        return f"{what}: MISSING ({self.error})" if self.error else f"{what}: opening"

    def _source_stats(self) -> dict[str, int]:
        return self.lines.stats()

    def _on_stop(self) -> None:
        """The recogniser process this input started goes with it."""
        self._drop_worker()

    def _drop_worker(self) -> None:
        """Close the worker process this input started (the next stream starts another)."""
        if self._own and self._listener is not None:
            listener, self._listener = self._listener, None
            listener.close()

    # -- audio -------------------------------------------------------------------------------------
    def start_stream(self, t0: float | None = None) -> None:
        """A new stream of audio whose first sample is at ``t0`` (monotonic; default now)."""
        if self._listener is None:  # the car's: a worker process, off the loop's GIL
            self._listener = ProcessListener(self.config.talk)
        else:
            self._listener.reset()
        self._audio_s = 0.0
        self._t0 = time.monotonic() if t0 is None else t0

    def feed(self, samples: np.ndarray, sink: Callable[[SceneMessage], None]) -> None:
        """One chunk of 16 kHz audio, in order (the reader calls this; tests may too): 16-bit
        samples as read, or floats. Here it is only passed on, with whether the car's voice
        covered it and whether the talk key is down; what comes back is acted on."""
        if self._listener is None:
            self.start_stream()
        assert self._listener is not None
        at_s = self._t0 + self._audio_s
        self._audio_s += samples.size / RATE_HZ
        self._health.data(True)
        voice = self.car_voice
        deaf = voice is not None and voice.busy(self.config.deaf_tail_s, at_s=at_s)
        if deaf:
            self._count("deaf_chunks")
        for outcome in self._listener.feed(samples, deaf=deaf, talking=self._talking.is_set()):
            self._outcome(outcome, sink)

    def end_stream(self, sink: Callable[[SceneMessage], None]) -> None:
        """The audio ended: the utterance in progress is heard (a WAV that ends mid-phrase)."""
        if self._listener is not None:
            for outcome in self._listener.flush():
                self._outcome(outcome, sink)

    def _outcome(self, outcome: Outcome, sink: Callable[[SceneMessage], None]) -> None:
        self._count("utterances")
        heard = outcome.heard
        if heard is None:
            self._count("not_commands")
            return
        self._utterance(heard, sink)

    def _utterance(self, heard: Heard, sink: Callable[[SceneMessage], None]) -> None:
        self.heard.append(heard)
        del self.heard[:-20]
        if not heard.line:
            self._say_again(heard)
            return
        voice = self.car_voice
        if voice is not None and is_echo(heard.text, voice.recent(self.config.echo_window_s)):
            self._count("refused_echo")
            self.lines.feedback(f"refused {heard.text!r}: the car's own words")
            return
        self._count("commands_heard")
        self.lines.echo(f"heard {heard.text!r} (confidence {heard.confidence:.2f})")
        self.lines.handle(heard.line, functools.partial(self._deliver_scene, sink))
        if self.read_back is not None and heard.line != "cancel":  # the pipeline answers that
            self.read_back(Say(Speech.READ_BACK, line=heard.line))

    def _deliver_scene(self, sink: Callable[[SceneMessage], None], msg: SceneMessage) -> None:
        self._deliver(sink, msg)

    def _say_again(self, heard: Heard | None) -> None:
        self._count("say_again")
        what = f"heard {heard.text!r}, confidence {heard.confidence:.2f}" if heard else "no command"
        self.lines.feedback(f"? say again ({what})")
        if self.read_back is not None:
            self.read_back(Say(Speech.SAY_AGAIN))

    # -- the reader -------------------------------------------------------------------------------
    def _run(self, sink: Callable[[SceneMessage], None]) -> None:
        delay = 0.25
        while not self._stop.is_set():
            try:
                stream = self._open()
            except OSError as exc:
                self.error = str(exc)
                self._set_connected(False, self.error)
                self._stop.wait(delay)
                delay = self._backoff(delay)
                continue
            self.error = ""
            self._set_connected(True)
            try:
                self.start_stream()
                ended = stream.pump(lambda x: self.feed(x, sink), self._stop)
                why = stream.why_ended() if ended else ""
                if self._audio_s > 1.0:  # it worked for a while: retry soon after a failure
                    delay = 0.25
                if ended and not self._stop.is_set() and stream.process is None:
                    self.end_stream(sink)  # a file or FIFO: nothing more will come
            except OSError as exc:  # the device, or the recogniser's worker process
                self.error = str(exc)
                self._set_connected(False, self.error)
                self._drop_worker()
                self._stop.wait(delay)
                delay = self._backoff(delay)
                continue
            finally:
                stream.close()
            if ended and not self._stop.is_set():
                if stream.process is None:
                    self._log.info("%s: end of audio on %s", self.name, self.config.device)
                    self._health.ended()
                    return
                self.error = why
                self._set_connected(False, self.error)
                self._stop.wait(delay)
                delay = self._backoff(delay)

    def _open(self) -> _Audio:
        path = self.config.device
        if os.path.exists(path) and not stat.S_ISCHR(os.stat(path).st_mode):
            if path.lower().endswith(".wav"):
                return _Audio(samples=read_wav_16k(path))
            return _Audio(fd=os.open(path, os.O_RDONLY | os.O_NONBLOCK))
        exe = shutil.which("arecord")
        if exe is None:
            raise OSError("arecord not found (Debian package alsa-utils)")
        proc = subprocess.Popen(
            [exe, "-q", "-D", path, "-f", "S16_LE", "-r", str(RATE_HZ), "-c", "1", "-t", "raw"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        )  # fmt: skip
        assert proc.stdout is not None
        os.set_blocking(proc.stdout.fileno(), False)
        return _Audio(fd=proc.stdout.fileno(), process=proc)


class _Audio:
    """Samples from a whole WAV, a FIFO or file of raw samples, or ``arecord``'s pipe."""

    def __init__(
        self,
        *,
        samples: np.ndarray | None = None,
        fd: int | None = None,
        process: subprocess.Popen[bytes] | None = None,
    ) -> None:
        self.samples, self.fd, self.process = samples, fd, process

    def pump(self, feed: Callable[[np.ndarray], None], stop: threading.Event) -> bool:
        """Feed chunks until the end (True) or ``stop`` (False)."""
        if self.samples is not None:
            for k in range(0, self.samples.size, CHUNK):
                if stop.is_set():
                    return False
                feed(self.samples[k : k + CHUNK])
            return True
        assert self.fd is not None
        rest = b""
        while not stop.is_set():
            if not select.select([self.fd], [], [], 0.2)[0]:
                continue
            data = os.read(self.fd, 2 * CHUNK * 8)
            if not data:
                return True
            data, rest = rest + data, b""
            n = len(data) // (2 * CHUNK) * 2 * CHUNK
            data, rest = data[:n], data[n:]
            for k in range(0, n, 2 * CHUNK):
                feed(np.frombuffer(data[k : k + 2 * CHUNK], dtype="<i2"))
        return False

    def why_ended(self) -> str:
        if self.process is None:
            return "end of audio"
        try:
            self.process.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            return "arecord stopped sending"
        err = self.process.stderr.read().decode(errors="replace") if self.process.stderr else ""
        lines = err.strip().splitlines()
        return lines[-1] if lines else f"arecord exited with status {self.process.returncode}"

    def close(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait()
            for f in (self.process.stdout, self.process.stderr):
                if f is not None:
                    f.close()
        elif self.fd is not None:
            os.close(self.fd)
