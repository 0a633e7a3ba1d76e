"""SVOX Pico (the ``py-nanotts`` wheel) as a Renderer: the default voice (issue 39).

The wheel (Apache-2.0, 5.3 MB) holds the Pico engine compiled as a CPython extension and its
lingware for en-US, en-GB, de-DE, es-ES, fr-FR and it-IT; nothing is downloaded. Each call
initialises the engine, loads the voice and renders 16 kHz mono 16-bit PCM (12-22 ms a prompt
here, benchmarks/voice_speed.py). A language Pico lacks is spoken by espeak-ng instead
(``guidance.voice.make_speaker``).

Text is prepared for speech before Pico reads it (``speakable``): Pico spells a hyphen out
("U hyphen turn"), so a hyphen between letters becomes a space, and the punctuation that only
structures the screen text (";", ":") becomes a comma pause.
"""

from __future__ import annotations

import re
import threading

from guidance.voice.queue import DEFAULT_RATE_WPM
from guidance.voice.speakers import SpeechEngineError

PICO_RATE_HZ = 16000
PICO_VOICES: dict[str, str] = {
    "en": "en-US",
    "en-us": "en-US",
    "en-gb": "en-GB",
    "de": "de-DE",
    "de-de": "de-DE",
    "es": "es-ES",
    "es-es": "es-ES",
    "fr": "fr-FR",
    "fr-fr": "fr-FR",
    "it": "it-IT",
    "it-it": "it-IT",
}
"""``[voice] voice`` (espeak-ng's language codes, as before) -> Pico's voice. ``en`` is en-US:
its word error rate through the recogniser is lower than en-GB's (docs/voice.md)."""

PICO_NATURAL_WPM = 170
"""``rate_wpm`` at which Pico speaks at its own speed (speed 1.0); the default rate."""

_HYPHEN_RE = re.compile(r"(?<=[A-Za-z])-(?=[A-Za-z])")
_LOCK = threading.Lock()


def pico_voice(voice: str) -> str | None:
    """Pico's voice for a ``[voice] voice`` code, or None when Pico has no such language."""
    code = voice.strip().lower().replace("_", "-").split("/")[-1]  # "gmw/en-us" too
    return PICO_VOICES.get(code)


def pico_available() -> bool:
    """True when the py-nanotts wheel imports (its native extension loads)."""
    try:
        import py_nanotts  # noqa: F401
    except ImportError:
        return False
    return True


def speakable(text: str) -> str:
    """The text as Pico should read it: "U-turn" -> "U turn"; ";" and ":" -> ","."""
    text = _HYPHEN_RE.sub(" ", text)
    return text.replace(";", ",").replace(":", ",")


class PicoRenderer:
    """Renders text with Pico to 16-bit mono PCM at 16 kHz (the ``Renderer`` shape)."""

    def __init__(self, voice: str = "en", rate_wpm: int = DEFAULT_RATE_WPM) -> None:
        pico = pico_voice(voice)
        if pico is None:
            raise SpeechEngineError(f"Pico has no voice for {voice!r} (it has en, en-gb, de, es, "
                                    "fr, it)")  # fmt: skip
        try:
            import py_nanotts
        except ImportError as exc:
            raise SpeechEngineError(f"Pico not installed (py-nanotts): {exc}") from None
        self.voice = pico
        self.speed = min(max(rate_wpm / PICO_NATURAL_WPM, 0.5), 2.5)
        self._tts = py_nanotts.NanoTTS()

    def __call__(self, text: str) -> tuple[bytes, int]:
        spoken = speakable(" ".join(text.split()))
        if not spoken:
            raise SpeechEngineError("nothing to say")
        try:
            with _LOCK:  # one engine at a time: the extension keeps no state, but be safe
                pcm = self._tts.speak(spoken, voice=self.voice, speed=self.speed)
        except (RuntimeError, ValueError, OSError) as exc:
            raise SpeechEngineError(f"Pico failed: {exc}") from exc
        if not pcm:
            raise SpeechEngineError("Pico produced no audio")
        return bytes(pcm), PICO_RATE_HZ
