"""Spoken driver prompts: a bounded priority queue, the Speaker backends, prompt timing.

SPEC section 6 and issue 4 ("Voice"); design notes in docs/voice.md.

* ``PromptQueue`` is pure logic: bounded, priority tiers, de-duplication of
  pending text, staleness measured on the message clock (a callable passed in).
* ``PlayedSpeaker`` speaks with a renderer (SVOX Pico by default, ``guidance.voice.pico``)
  through ALSA's ``aplay``; ``Pyttsx3Speaker`` speaks through pyttsx3 (espeak-ng on Linux),
  the fallback and the voice for languages Pico lacks; both on their own thread.
  ``WavSpeaker`` records what a real-time voice would say into one WAV
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

import logging
import time
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Literal, TextIO

from guidance.core.messages import Priority
from guidance.voice.queue import DEFAULT_QUEUE_SIZE, DEFAULT_RATE_WPM, Clock
from guidance.voice.speaker import Speaker
from guidance.voice.speakers import Pyttsx3Speaker, SpeechEngineError, TextSpeaker
from guidance.voice.wav import Renderer, WavSpeaker, default_renderer

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------- choice

SpeakerKind = Literal["auto", "pico", "espeak", "voice", "wav", "text"]
SPEAKER_KINDS: tuple[SpeakerKind, ...] = typing.get_args(SpeakerKind)
"""The one list of speaker names (``[voice] backend`` takes these, or ``none``).

``auto``: the default voice (Pico; espeak-ng for a language Pico lacks or when Pico cannot start),
into ``wav_path`` when given, else aloud. ``pico``, ``espeak``: that engine, into ``wav_path``
when given, else aloud. ``voice``: aloud with the default voice. ``wav``: into ``wav_path`` with
the default voice. ``text``: lines on stderr."""

Engine = Literal["auto", "pico", "espeak"]


def make_renderer(
    engine: Engine = "auto", voice: str = "en", rate_wpm: int = DEFAULT_RATE_WPM
) -> Renderer:
    """The renderer of ``engine`` (``auto``: Pico when it speaks ``voice``, else espeak-ng);
    SpeechEngineError when it cannot start. The car, the WAV and ``guidance voice say`` all
    render through this."""
    from guidance.voice.pico import PicoRenderer

    if engine == "pico" or (engine == "auto" and _pico_speaks(voice)):
        return PicoRenderer(voice, rate_wpm)
    return default_renderer(voice, rate_wpm)


def make_speaker(
    kind: SpeakerKind = "auto",
    wav_path: str | Path | None = None,
    *,
    clock: Clock = time.monotonic,
    driver_name: str | None = None,
    text_stream: TextIO | None = None,
    maxsize: int = DEFAULT_QUEUE_SIZE,
    max_age_s: Mapping[Priority, float] | None = None,
    voice: str = "en",
    rate_wpm: int = DEFAULT_RATE_WPM,
    volume: float = 1.0,
    device: str = "default",
) -> Speaker:
    """The Speaker asked for, or text with one clear warning when speech cannot start.

    ``clock`` is the message clock that prompt times ``t_s`` are on (simulated time in
    ``sim``); ``device`` the ALSA playback device of a live voice (``null``: none).
    """
    if kind == "text":
        return TextSpeaker(text_stream, clock)
    if kind not in SPEAKER_KINDS:
        raise ValueError(f"unknown speaker kind {kind!r}; expected {', '.join(SPEAKER_KINDS)}")
    engine: Engine = kind if kind in ("pico", "espeak") else "auto"
    record = kind == "wav" or (kind != "voice" and wav_path is not None)
    suffix = ""
    try:
        if record:
            if wav_path is None:
                raise ValueError("speaker kind 'wav' needs wav_path")
            suffix = f"; {wav_path} is not written"
            return WavSpeaker(
                wav_path,
                renderer=make_renderer(engine, voice, rate_wpm),
                clock=clock,
                maxsize=maxsize,
                max_age_s=max_age_s,
                text_stream=text_stream,
                volume=volume,
            )
        queue_args: dict[str, typing.Any] = {
            "clock": clock, "maxsize": maxsize, "max_age_s": max_age_s, "text_stream": text_stream
        }  # fmt: skip
        pico_failed = ""
        if engine == "pico" or (engine == "auto" and _pico_speaks(voice)):
            try:
                return _played(make_renderer("pico", voice, rate_wpm), device, volume, queue_args)
            except SpeechEngineError as e:
                if engine == "pico":
                    raise
                pico_failed = str(e)
        try:
            spk = Pyttsx3Speaker(
                driver_name, rate_wpm=rate_wpm, voice=voice, volume=volume, **queue_args
            )
        except SpeechEngineError as e:
            if not pico_failed:
                raise
            raise SpeechEngineError(f"Pico: {pico_failed}; espeak-ng: {e}") from e
        if pico_failed:
            log.warning("Pico cannot speak (%s); speaking with espeak-ng", pico_failed)
        return spk
    except SpeechEngineError as e:
        log.warning("no speech engine (%s); prompts are shown as text%s", e, suffix)
        return TextSpeaker(text_stream, clock, fallback_reason=str(e))


def _pico_speaks(voice: str) -> bool:
    from guidance.voice.pico import pico_available, pico_voice

    return pico_available() and pico_voice(voice) is not None


def _played(
    renderer: Renderer, device: str, volume: float, queue_args: dict[str, typing.Any]
) -> Speaker:
    from guidance.voice.pico import PicoRenderer
    from guidance.voice.playback import AplayPlayer, PlayedSpeaker

    engine = "Pico" if isinstance(renderer, PicoRenderer) else "espeak-ng"
    player = AplayPlayer(device)
    return PlayedSpeaker(renderer, player, engine=engine, volume=volume, **queue_args)
