"""Every prompt the product can say, and the word error rate of a voice over them (issue 39).

``prompt_corpus`` reads the sentence table (``guidance.core.speech.SPEECH``): ``corpus_events``
gives every event (``Speech``) with the numbers that make each form of its sentence (every
manoeuvre, "then", each way a distance is said, landmark names, every input and status, the
chance, the operator's and the speech input's sentences), and each is worded in metric and in
imperial; an event without an entry here is an error, so the intelligibility figure follows any
change of wording or any new sentence. ``word_error_rate`` compares what a recogniser wrote with
what was meant, after ``normalise``: numbers as words, British spellings as the recogniser's
dictionary writes them ("metres" -> "meters": spelling, not hearing), punctuation and hyphens
out.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence

import numpy as np

from guidance.core.messages import Say, Speech
from guidance.core.speech import BEARINGS, COMPONENT_WORDS, SENSOR_WORDS, Units, words
from guidance.voice.wav import Renderer

MANOEUVRE_DEG = (0.0, 45.0, -45.0, 90.0, -90.0, 150.0, -150.0, 180.0)
"""continue straight, bear left/right, turn left/right, turn sharp left/right, U-turn."""
DISTANCES_M = (30.0, 80.0, 150.0, 300.0, 650.0, 1200.0, 1500.0, 4000.0, 12000.0)
"""One of each way a distance is said, metric and imperial (tens, fifties, decimals, whole)."""
READ_BACK_LINES = ("l s r", "bl br", "hl hr u", "t l", "repeat", "mute")


def _turn_events() -> list[Say]:
    rad = [math.radians(d) for d in MANOEUVRE_DEG]
    out = [Say(Speech.TURN, a) for a in rad]
    out += [Say(Speech.TURN, rad[k % len(rad)], d) for k, d in enumerate(DISTANCES_M)]
    for i, a in enumerate(rad[1:]):  # each manoeuvre as the second of two
        out.append(Say(Speech.TURN, rad[1 + (i + 3) % 7], 120.0 + 10 * i, a, 80.0))
    out += [Say(Speech.TURN, rad[4], 120.0, changed=True), Say(Speech.TURN, rad[3], changed=True),
            Say(Speech.TURN, rad[3], again=True)]  # fmt: skip
    # a manoeuvre said by its side or its road's direction (the heading too uncertain)
    wide = math.radians(40.0)
    out += [Say(Speech.TURN, rad[3], 200.0, band_rad=wide),
            Say(Speech.TURN, rad[4], band_rad=wide)]  # fmt: skip
    out += [Say(Speech.TURN, 0.0, 90.0, band_rad=math.pi, exit_heading_rad=math.radians(90 - b))
            for b in range(0, 360, 45 * 3)]  # fmt: skip
    assert len(BEARINGS) == 8
    return out


def corpus_events(landmark_names: Sequence[str]) -> list[Say]:
    """Every event of the sentence table, with the numbers that make each form of its words."""
    names = list(dict.fromkeys(landmark_names))
    out = _turn_events()
    out += [Say(Speech.LANDMARK, name=n) for n in [*names, ""]]
    out += [Say(Speech.FOUND, name=n, again=True) for n in [*names[:: max(1, len(names) // 4)], ""]]
    out += [Say(Speech.FOUND, name=n) for n in (names[0], "")]  # a car that started anywhere
    out += [Say(Speech.UNCERTAIN, distance_m=d) for d in (80.0, 350.0)]
    out += [Say(Speech.NEW_DESTINATION, remote=r) for r in (False, True)]
    out += [Say(Speech.LOST, searching=s) for s in (False, True)]
    out += [Say(Speech.ARRIVED), Say(Speech.WAITING_FOR_HEADING), Say(Speech.POSITION_UNKNOWN)]
    out += [Say(Speech.SENSOR, input=i, status=st) for i, t in SENSOR_WORDS.items() for st in t]
    out += [Say(Speech.COMPONENT, input=c, status=st) for c, t in COMPONENT_WORDS.items()
            for st in t]  # fmt: skip
    out += [Say(Speech.COMPASS_UNUSABLE, status=r) for r in ("interference", "uncalibrated")]
    out += [Say(Speech.CHANCE, chance=p) for p in (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8,
                                                   0.9)]  # fmt: skip
    out += [Say(Speech.READ_BACK, line=line) for line in READ_BACK_LINES]
    out += [Say(s) for s in (Speech.DIFFERENT_EXIT, Speech.NO_CO_DRIVER_INPUT, Speech.SAY_AGAIN,
                             Speech.REPORT_CANCELLED, Speech.CANNOT_CANCEL)]  # fmt: skip
    missing = set(Speech) - {say.speech for say in out}
    if missing:
        raise ValueError(f"the voice corpus says nothing of {sorted(missing)}")
    return out


def prompt_corpus(landmark_names: Sequence[str]) -> list[str]:
    """Every sentence the car says (``corpus_events``), in metric and in imperial, once each."""
    events = corpus_events(landmark_names)
    return list(dict.fromkeys(words(say, units) for say in events for units in Units))


_ONES = (
    "zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten",
    "eleven", "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen",
    "nineteen",
)
_TENS = (
    "_", "_", "twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety",
)
_SPELLING = {"metres": "meters", "metre": "meter", "kilometres": "kilometers",
             "kilometre": "kilometer", "theatre": "theater", "centre": "center"}  # fmt: skip


def number_words(n: int) -> str:
    """0-999999 as the recogniser writes them: 150 -> "one hundred fifty" (no "and")."""
    if n < 0 or n >= 1_000_000:
        raise ValueError(f"out of range: {n}")
    if n < 20:
        return _ONES[n]
    if n < 100:
        return _TENS[n // 10] + ("" if n % 10 == 0 else " " + _ONES[n % 10])
    if n < 1000:
        rest = n % 100
        return f"{_ONES[n // 100]} hundred" + (f" {number_words(rest)}" if rest else "")
    rest = n % 1000
    return f"{number_words(n // 1000)} thousand" + (f" {number_words(rest)}" if rest else "")


def _numbers(text: str) -> str:
    def spell(m: re.Match[str]) -> str:
        whole, _, frac = m.group(0).partition(".")
        words = number_words(int(whole))
        return words + (" point " + " ".join(_ONES[int(c)] for c in frac) if frac else "")

    return re.sub(r"\d+(?:\.\d+)?", spell, text)


def normalise(text: str) -> list[str]:
    """Lower-case words: numbers spelled out, American spelling, no punctuation or hyphens;
    "and" between two number words dropped (en-GB voices say "one hundred and fifty")."""
    text = _numbers(text.lower()).replace("-", " ")
    words = [_SPELLING.get(w, w) for w in re.findall(r"[a-z']+", text)]
    numeric = set(_ONES) | set(_TENS) | {"hundred", "thousand"}
    return [w for i, w in enumerate(words)
            if not (w == "and" and 0 < i < len(words) - 1 and words[i - 1] in numeric
                    and words[i + 1] in numeric)]  # fmt: skip


def edit_distance(ref: Sequence[str], hyp: Sequence[str]) -> int:
    row = list(range(len(hyp) + 1))
    for i, r in enumerate(ref, 1):
        prev, row[0] = row[:], i
        for j, h in enumerate(hyp, 1):
            row[j] = min(prev[j] + 1, row[j - 1] + 1, prev[j - 1] + (r != h))
    return row[-1]


def word_error_rate(pairs: Iterable[tuple[str, str]]) -> float:
    """Σ edits / Σ reference words over (meant, heard) pairs, both normalised."""
    edits = words = 0
    for meant, heard in pairs:
        ref = normalise(meant)
        edits += edit_distance(ref, normalise(heard))
        words += len(ref)
    return edits / words if words else 0.0


# ------------------------------------------------------------------------- voices under test


def flite_renderer(voice: str = "slt") -> Renderer:
    """Festival Lite's command line (Debian ``flite``; voices kal, awb, rms, slt) as a Renderer:
    a voice the product did not make, for the speech input's tests."""
    import io
    import shutil
    import subprocess
    import tempfile
    import wave

    from guidance.voice.speakers import SpeechEngineError

    exe = shutil.which("flite")
    if exe is None:
        raise SpeechEngineError("flite not found (Debian package flite)")

    def render(text: str) -> tuple[bytes, int]:
        with tempfile.NamedTemporaryFile(suffix=".wav") as f:
            subprocess.run([exe, "-voice", voice, "-t", text, "-o", f.name], check=True,
                           capture_output=True, timeout=30)  # fmt: skip
            with wave.open(io.BytesIO(open(f.name, "rb").read())) as w:
                return w.readframes(w.getnframes()), w.getframerate()

    return render


def voice_renderer(name: str) -> Renderer:
    """A voice by name: ``pico:en-US``, ``espeak:en+f3`` (espeak-ng voice and variant),
    ``flite:awb``."""
    from guidance.voice.pico import PicoRenderer
    from guidance.voice.wav import EspeakNgRenderer

    engine, _, voice = name.partition(":")
    if engine == "pico":
        return PicoRenderer(voice or "en")
    if engine == "espeak":
        return EspeakNgRenderer(voice or "en")
    if engine == "flite":
        return flite_renderer(voice or "slt")
    raise ValueError(f"unknown voice {name!r}: pico:V, espeak:V or flite:V")


# ------------------------------------------------------------------ spoken commands and noise

SPOKEN_COMMANDS: tuple[tuple[str, str], ...] = (
    ("left straight right", "l s r"),
    ("bear left", "bl"),
    ("hard right", "hr"),
    ("U turn", "u"),
    ("turned left", "t l"),
    ("repeat", "repeat"),
    ("mute", "mute"),
    ("help", "help"),
    ("cancel", "cancel"),
    ("straight", "s"),
    ("left right", "l r"),
    ("bear right straight", "br s"),
    ("turned right", "t r"),
    ("straight right", "s r"),
    ("hard left straight", "hl s"),
    ("left", "l"),
    ("right", "r"),
    ("turned straight", "t s"),
    ("bear left hard right", "bl hr"),
    ("left straight", "l s"),
)
"""(what the co-driver says, the line it must make): every word of the grammar."""

RADIO_TEXT = (
    "Good morning, it is eight o'clock and here is the news. The council met last night to "
    "discuss the new bus lanes on the ring road. Traffic is heavy on the bridge this morning, so "
    "leave a little earlier if you can. The weather today will be mostly dry with sunny spells "
    "in the afternoon and a light breeze from the west. In sport, the home side won their match "
    "by two goals to one after a late penalty. Coming up after the break: the best songs of the "
    "summer, a recipe for a quick dinner, and your calls about the new parking rules in the old "
    "town. Now, a look at the markets: shares rose slightly at the opening bell. Stay with us, "
    "we will be right back after these messages. Turn the dial, hold the line, and keep your "
    "eyes on the road. The left lane of the motorway is closed near the junction because of "
    "road works, and drivers heading straight into town should expect delays of ten minutes."
)
"""Radio-like talk for the false-command test, with command words inside ordinary sentences
("right back", "left lane", "straight into town", "turn the dial")."""

RADIO_TEXT_2 = (
    "And that was the last song of the hour. You are listening to the afternoon show, with me "
    "until six. A caller asked whether the new bridge will open before the winter; the answer "
    "from the city is maybe, if the weather holds. Our reporter is standing right outside the "
    "station, where a long queue has formed for the concert tonight. If you missed the start, "
    "you can hear it again tomorrow. Help us choose the next record: send a message, and we will "
    "repeat the best ones at the end of the programme. Please do not mute us yet, the quiz is "
    "coming up straight after the travel news. Roads are clear in the north, the ring road is "
    "slow near the hospital, and there is a hard shoulder closed on the way to the airport. "
    "The match has been cancelled because of the rain, and the players went home early. We "
    "turned the studio lights down and kept the music on."
)
"""Other radio-like talk (the held-out set of the confidence threshold: not used to choose
it), with every control word and exit word inside ordinary sentences."""


def short_phrases(text: str, seed: int) -> list[str]:
    """``text`` cut into runs of one to four words (a command is one to four): what a radio,
    a passenger or the driver says that is as short as a command but is not one (a run that
    is itself a phrase of the co-driver grammar, "right" alone, is left out: no recogniser can
    tell it from the command)."""
    from drivers.speech_grammar import to_line

    rng = np.random.default_rng(seed)
    words = re.findall(r"[A-Za-z']+", text)
    out, k = [], 0
    while k < len(words):
        n = int(rng.integers(1, 5))
        phrase = " ".join(words[k : k + n])
        if to_line(phrase.lower()) is None:
            out.append(phrase)
        k += n
    return out


def cabin_noise(n: int, seed: int = 0, rate_hz: int = 16000) -> np.ndarray:
    """Car-cabin-like noise (unit RMS): road and engine rumble below a few hundred hertz
    falling about 9 dB per octave above 200 Hz, engine orders at 70 Hz and its harmonics,
    and a weaker broadband wind part. A generated stand-in for a recording."""
    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(n, 1.0 / rate_hz)
    shape = 1.0 / np.sqrt(np.maximum(f, 20.0)) / (1.0 + (f / 200.0) ** 1.0)
    shape[f < 20.0] = 0.0
    spec = (rng.normal(size=f.size) + 1j * rng.normal(size=f.size)) * shape
    x = np.fft.irfft(spec, n)
    t = np.arange(n) / rate_hz
    for k, amp in ((1, 0.5), (2, 0.3), (3, 0.15)):
        x += amp * np.std(x) * np.sin(2 * np.pi * 70.0 * k * t + rng.uniform(0, 6.3))
    wind = rng.normal(size=n)
    x = x / np.std(x) + 0.1 * wind
    return np.asarray(x / np.std(x))


def speech_power(x: np.ndarray) -> float:
    """Mean power of the voiced part (samples within 40 dB of the peak), as for SNR."""
    peak = float(np.max(np.abs(x))) if x.size else 0.0
    voiced = x[np.abs(x) > peak * 0.01]
    return float(np.mean(voiced * voiced)) if voiced.size else 0.0


def mix_at_snr(speech: np.ndarray, noise: np.ndarray, snr_db: float) -> np.ndarray:
    """``speech`` plus ``noise`` (same length) scaled to ``snr_db`` against the voiced speech."""
    p_noise = float(np.mean(noise * noise))
    gain = np.sqrt(speech_power(speech) / (p_noise * 10 ** (snr_db / 10))) if p_noise else 0.0
    return np.asarray(speech + gain * noise)
