"""The co-driver's spoken words -> co-driver lines: pocketsphinx with a JSGF grammar (issue 39).

pocketsphinx (BSD, its en-us acoustic model and dictionary inside the wheel) is wrapped here and
nowhere else. ``CommandRecogniser.decode`` runs one utterance through two searches:

* the **grammar** of the co-driver's words (``GRAMMAR``: one to four exits "left straight right",
  "bear left", "hard right", "U turn"; "turned left"; "repeat", "mute", "help", "cancel"), which
  always answers with some phrase of the grammar, and
* a **free phone loop** (pocketsphinx's allphone search with its phone language model), which
  says what was heard with no grammar at all.

The **confidence** is how well the two agree: one minus the phone error rate between the grammar
phrase's dictionary pronunciation and the free phone string (0: nothing alike, 1: the same). A
phrase of the grammar forced onto other speech has a pronunciation unlike what the phone loop
hears. It separates commands from other speech in quiet (``ACCEPT``, ``SAY_AGAIN``: set on Pico
en-US renderings of the commands and of the car's own prompts, docs/voice.md), but not in cabin
noise, where the phone loop hears little of anything: so it gates only the always-listening
mode. With push-to-talk every complete phrase of the grammar is taken, and an incomplete one
(the search ended inside a phrase: "turned bear") or none is answered "say again".

``utterances`` cuts a longer recording at the pauses (pocketsphinx's ``Endpointer``, its voice
activity detector); an utterance longer than ``MAX_COMMAND_S`` is not a command (the longest,
four exits, takes under 3 s to say) and is not decoded.
"""

from __future__ import annotations

import io
import re
import threading
import wave
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from guidance import files

RATE_HZ = 16000
"""The acoustic model's sample rate: everything is resampled to it."""
MAX_COMMAND_S = 4.0
"""An utterance longer than this is not a command (four exits take under 3 s)."""
MIN_COMMAND_S = 0.25
"""Shorter is a click or a cough, not a word."""
ACCEPT = 0.55
"""Confidence from which a phrase is taken when always listening, from a null model
(benchmarks/voice_confidence.py): the confidences of short talk that is not a command but that
the grammar turns into one (the phrases of ``RADIO_TEXT`` by Pico en-US and espeak-ng en-us in
cabin noise at 20 dB: 85 such utterances, the highest 0.50) set it at the next 0.05 above them;
a new one from that population passes with probability at most 1/86. Measured on talk, voices
and noise levels it was not chosen on: 1 false command in 29.5 minutes (0.30, the value before,
let 20 through); its price is most commands (always listening takes 0-5 of 20 from the
held-out voices). Push-to-talk does not use it (docs/voice.md)."""
SAY_AGAIN = 0.5
"""Confidence from which, below ``ACCEPT``, the speaker is asked to say it again (the null
model's highest score): below this the sound is ignored, as talk not meant for the car."""

WAKE_WORD = "navigator"
"""Said before a command when the input listens for it (``talk = "wake"``): four syllables in
pocketsphinx's dictionary, unlike any word of the grammar, and not a word of radio talk or of
the car's own sentences (a short everyday word, "car" or "okay", is said all the time)."""
WAKE_THRESHOLD = 1e-20
"""pocketsphinx's keyword-spotting threshold for ``WAKE_WORD`` (the keyphrase's path score
against its phone-loop garbage model; smaller spots more). From benchmarks/voice_wake.py's
choosing set (Pico en-US and espeak-ng en-us; radio-like talk at 20 dB and the wake word before
each command at 10 dB): the loosest step of a ladder of thresholds (1e-10 .. 1e-40) at which no
talk is spotted, one step stricter for a margin; measured on other voices and talk
(docs/voice.md)."""
WAKE_WINDOW_S = 4.0
"""After the wake word said alone, the next utterance starting within this is the command."""

EXIT_WORDS: dict[str, str] = {
    "left": "l",
    "right": "r",
    "straight": "s",
    "bear left": "bl",
    "bear right": "br",
    "hard left": "hl",
    "hard right": "hr",
    "u turn": "u",
}
"""Spoken exit -> the co-driver line's token (``guidance.core.co_driver.EXIT_TOKENS``)."""
COMMAND_WORDS = ("repeat", "mute", "help", "cancel")
MAX_EXITS = 4

GRAMMAR = f"""#JSGF V1.0;
grammar codriver;
public <command> = <exits> | <turned> | <control>;
<exit> = {" | ".join(EXIT_WORDS)};
<exits> = <exit>{" [<exit>]" * (MAX_EXITS - 1)};
<turned> = turned <exit>;
<control> = {" | ".join(COMMAND_WORDS)};
"""
"""The co-driver's vocabulary as a JSGF grammar (the keypad's, spoken)."""

_EXIT_RE = re.compile("|".join(sorted(EXIT_WORDS, key=len, reverse=True)))
_FILLERS = ("<s>", "</s>", "<sil>", "SIL", "[NOISE]")


@dataclass(frozen=True, slots=True)
class Heard:
    """One utterance: when (s from the start of the audio), the grammar's phrase, the co-driver
    line it makes ("" when the confidence is too low: "say again"), the confidence (0-1)."""

    t_s: float
    text: str
    line: str
    confidence: float
    duration_s: float = 0.0


def to_line(words: str) -> str | None:
    """A phrase of the grammar -> a co-driver line: "left straight right" -> "l s r", "turned
    left" -> "t l", "repeat" -> "repeat"; None for anything else."""
    words = " ".join(words.split())
    if words in COMMAND_WORDS:
        return words
    turned = words.startswith("turned ")
    rest = words.removeprefix("turned ") if turned else words
    tokens: list[str] = []
    pos = 0
    for m in _EXIT_RE.finditer(rest):
        if rest[pos : m.start()].strip():
            return None
        tokens.append(EXIT_WORDS[m.group(0)])
        pos = m.end()
    if rest[pos:].strip() or not tokens or (turned and len(tokens) != 1):
        return None
    return ("t " if turned else "") + " ".join(tokens)


def resample(x: np.ndarray, rate_hz: int, to_hz: int = RATE_HZ) -> np.ndarray:
    """Band-limited resampling of a whole signal (FFT: exact for a finite recording)."""
    if rate_hz == to_hz or x.size == 0:
        return x.astype(np.float64)
    n = max(1, round(x.size * to_hz / rate_hz))
    spectrum = np.fft.rfft(x.astype(np.float64))
    keep = np.zeros(n // 2 + 1, dtype=complex)
    m = min(keep.size, spectrum.size)
    keep[:m] = spectrum[:m]
    return np.asarray(np.fft.irfft(keep, n) * (n / x.size))


def to_pcm16(x: np.ndarray) -> bytes:
    return bytes(np.clip(np.round(x), -32768, 32767).astype("<i2").tobytes())


def read_wav_16k(path: str | Path) -> np.ndarray:
    """A 16-bit PCM WAV (mono, or the first channel) as float samples at 16 kHz (read through
    the one door: a regular file of at most 512 MiB, ``files.FileRefused`` otherwise)."""
    data = files.read_bytes(path, "wav")
    try:
        return _wav_samples(data)
    except (wave.Error, EOFError, ValueError) as exc:
        raise files.FileRefused("WAV recording", path, f"not a 16-bit PCM WAV ({exc})") from None


def _wav_samples(data: bytes) -> np.ndarray:
    with wave.open(io.BytesIO(data), "rb") as w:
        if w.getsampwidth() != 2:
            raise ValueError(f"not 16-bit PCM ({8 * w.getsampwidth()}-bit)")
        rate, channels = w.getframerate(), w.getnchannels()
        raw = w.readframes(w.getnframes())
    x = np.frombuffer(raw, dtype="<i2")[::channels].astype(np.float64)
    return resample(x, rate)


def phone_error_rate(ref: Sequence[str], hyp: Sequence[str]) -> float:
    """Levenshtein distance over ``len(ref)`` (1.0 when ``ref`` is empty)."""
    if not ref:
        return 1.0
    row = list(range(len(hyp) + 1))
    for i, r in enumerate(ref, 1):
        prev, row[0] = row[:], i
        for j, h in enumerate(hyp, 1):
            row[j] = min(prev[j] + 1, row[j - 1] + 1, prev[j - 1] + (r != h))
    return row[-1] / len(ref)


class CommandRecogniser:
    """pocketsphinx with the co-driver grammar and a phone loop (see the module docstring).

    Not thread-safe: one per reader thread. ``decode`` is one utterance; ``recognise`` a whole
    recording cut at its pauses (``guidance voice listen``)."""

    def __init__(self, accept: float = ACCEPT, say_again: float = SAY_AGAIN) -> None:
        from pocketsphinx import Decoder, get_model_path

        self.accept = accept
        self.say_again = say_again
        self._grammar: Any = Decoder(samprate=RATE_HZ, loglevel="FATAL", lm=None)
        self._grammar.add_jsgf_string("codriver", GRAMMAR)
        self._grammar.activate_search("codriver")
        self._phones: Any = Decoder(
            samprate=RATE_HZ, loglevel="FATAL", lm=None,
            allphone=get_model_path("en-us/en-us-phone.lm.bin"),
        )  # fmt: skip
        self._lock = threading.Lock()
        self._wake: Any = None
        self.wake_threshold = WAKE_THRESHOLD

    def wake_end(self, samples: np.ndarray) -> int | None:
        """Where ``WAKE_WORD`` ends in the utterance (a sample index), or None when it is not
        spotted (pocketsphinx's keyword search at ``wake_threshold``)."""
        from pocketsphinx import Decoder

        if samples.size == 0:  # pocketsphinx refuses an empty buffer (IndexError)
            return None
        with self._lock:
            if self._wake is None:
                self._wake = Decoder(samprate=RATE_HZ, loglevel="FATAL", lm=None,
                                     keyphrase=WAKE_WORD, kws_threshold=self.wake_threshold)
            d = self._wake
            d.start_utt()
            d.process_raw(to_pcm16(samples), full_utt=True)
            d.end_utt()
            segs = [s for s in (d.seg() or []) if s.word == WAKE_WORD]
        return None if not segs else min(samples.size, (int(segs[0].end_frame) + 1) * 160)

    def _words(self, decoder: Any, pcm: bytes) -> list[str]:
        decoder.start_utt()
        decoder.process_raw(pcm, full_utt=True)
        decoder.end_utt()
        return [s.word for s in (decoder.seg() or []) if s.word not in _FILLERS
                and not s.word.startswith(("+", "["))]  # fmt: skip

    def _pronunciation(self, words: Sequence[str]) -> list[str]:
        out: list[str] = []
        for w in words:
            p = self._grammar.lookup_word(w.split("(")[0])
            out += p.split() if p else []
        return out

    def decode(self, samples: np.ndarray) -> tuple[str, float]:
        """One utterance (16 kHz samples) -> (the grammar's phrase, confidence 0-1)."""
        if samples.size == 0:  # pocketsphinx refuses an empty buffer (IndexError)
            return "", 0.0
        pcm = to_pcm16(samples)
        with self._lock:
            words = [w.split("(")[0] for w in self._words(self._grammar, pcm)]
            if not words:
                return "", 0.0
            phones = self._words(self._phones, pcm)
            ref = self._pronunciation(words)
        return " ".join(words), max(0.0, 1.0 - phone_error_rate(ref, phones))

    def hear(
        self, samples: np.ndarray, t_s: float = 0.0, *, push_to_talk: bool = False
    ) -> Heard | None:
        """One utterance -> what the co-driver input does with it: a ``Heard`` with a line, a
        ``Heard`` with line "" ("say again"), or None (not meant for the car: ignored).

        Always listening: too short or too long is None; otherwise the confidence decides
        (``accept``, ``say_again``). Push-to-talk: the driver meant to say something, so every
        complete phrase of the grammar is taken and anything else is "say again"."""
        duration_s = samples.size / RATE_HZ
        if not push_to_talk and not MIN_COMMAND_S <= duration_s <= MAX_COMMAND_S:
            return None
        text, confidence = self.decode(samples)
        line = to_line(text)
        if push_to_talk:
            return Heard(t_s, text, line or "", confidence, duration_s)
        if line is None or confidence < self.say_again:
            return None
        return Heard(t_s, text, line if confidence >= self.accept else "", confidence, duration_s)

    def recognise(self, samples: np.ndarray) -> list[Heard]:
        """Every utterance of a recording at 16 kHz, heard in turn."""
        out = []
        for t0, chunk in utterances(samples):
            heard = self.hear(chunk, t0)
            if heard is not None:
                out.append(heard)
        return out


RUMBLE_CUT_HZ = 250.0
"""Below this a car cabin is engine and road rumble, and speech carries little the recogniser
uses (its lowest filter is at 133 Hz): cut before the voice activity detector, which otherwise
takes 20 dB of cabin noise for one endless utterance (measured: one 10 s segment for two
sentences and a command; with the cut, the three)."""
_TAPS = 401


def _high_pass_taps(cut_hz: float = RUMBLE_CUT_HZ) -> np.ndarray:
    n = np.arange(_TAPS) - _TAPS // 2
    fc = cut_hz / RATE_HZ
    low = np.sinc(2 * fc * n) * 2 * fc * np.hamming(_TAPS)
    high = -low
    high[_TAPS // 2] += 1.0
    return np.asarray(high)


class HighPass:
    """Streaming linear-phase high-pass (``RUMBLE_CUT_HZ``; a windowed-sinc FIR, 12.5 ms delay):
    feed chunks in order, get filtered chunks of the same length."""

    def __init__(self) -> None:
        self._taps = _high_pass_taps()
        self._tail = np.zeros(_TAPS - 1)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        buf = np.concatenate([self._tail, x])
        self._tail = buf[-(_TAPS - 1) :]
        return np.asarray(np.convolve(buf, self._taps, mode="valid"))


def utterances(samples: np.ndarray) -> Iterator[tuple[float, np.ndarray]]:
    """(start s, samples) of each stretch of speech in a 16 kHz recording (``Segmenter``)."""
    seg = Segmenter()
    yield from seg.feed(samples)
    yield from seg.flush()


HISTORY_S = MAX_COMMAND_S + 4.0
"""Audio kept to cut utterances from: the longest a command may take, and some."""


class Segmenter:
    """Streaming utterance cutter: pocketsphinx's ``Endpointer`` (its voice activity detector)
    listens to the audio with the rumble cut (``HighPass``), and each utterance it finds is cut
    from the audio as it came (the recogniser does better with all of it: cutting the rumble
    before decoding cost 4 of 20 Pico en-GB commands at 10 dB). Feed samples as they come; an
    utterance is yielded once the pause after it is heard. An utterance longer than
    ``HISTORY_S`` comes out shortened (it is no command anyway)."""

    def __init__(self) -> None:
        from pocketsphinx import Endpointer

        self._ep: Any = Endpointer(window=0.3, ratio=0.9, vad_mode=2, sample_rate=RATE_HZ)
        self._frame = int(self._ep.frame_bytes) // 2
        self._rumble = HighPass()
        self._pending = np.zeros(0)
        self._history = np.zeros(0)
        self._history_end = 0  # samples fed so far (the index after the history's last)
        self._start_s: float | None = None

    def _cut(self, start_s: float, end_s: float) -> tuple[float, np.ndarray]:
        delay = _TAPS // 2
        first = self._history_end - self._history.size
        a = max(first, round(start_s * RATE_HZ) - delay)
        b = min(self._history_end, round(end_s * RATE_HZ) - delay)
        return (a / RATE_HZ, self._history[a - first : max(a, b) - first])

    def _step(self, frame: np.ndarray, end: bool = False) -> Iterator[tuple[float, np.ndarray]]:
        pcm = to_pcm16(frame)
        speech = self._ep.end_stream(pcm) if end else self._ep.process(pcm)
        if speech is None:
            return
        if self._start_s is None:
            self._start_s = float(self._ep.speech_start)
        if not self._ep.in_speech:
            start, self._start_s = self._start_s, None
            yield self._cut(start, float(self._ep.speech_end))

    def feed(self, samples: np.ndarray) -> Iterator[tuple[float, np.ndarray]]:
        raw = samples.astype(np.float64)
        keep = int(HISTORY_S * RATE_HZ)
        self._history = np.concatenate([self._history, raw])[-keep:]
        self._history_end += raw.size
        buf = np.concatenate([self._pending, self._rumble(raw)])
        n = buf.size // self._frame
        for k in range(n):
            yield from self._step(buf[k * self._frame : (k + 1) * self._frame])
        self._pending = buf[n * self._frame :]

    def flush(self) -> Iterator[tuple[float, np.ndarray]]:
        """The end of the audio: the utterance in progress, if any."""
        if self._pending.size:  # end_stream takes a last, short frame (not an empty one)
            yield from self._step(self._pending, end=True)
        if self._start_s is not None:  # the detector had not closed it
            start, self._start_s = self._start_s, None
            yield self._cut(start, self._history_end / RATE_HZ + (_TAPS // 2) / RATE_HZ)
        self._pending = np.zeros(0)


class Transcriber:
    """pocketsphinx's general English dictation (its en-us language model): what a listener
    with no idea of the car's sentences makes of a prompt (the intelligibility figure)."""

    def __init__(self) -> None:
        from pocketsphinx import Decoder

        self._decoder: Any = Decoder(samprate=RATE_HZ, loglevel="FATAL")

    def __call__(self, samples: np.ndarray) -> str:
        d = self._decoder
        d.start_utt()
        d.process_raw(to_pcm16(samples), full_utt=True)
        d.end_utt()
        hyp = d.hyp()
        return str(hyp.hypstr) if hyp is not None else ""
