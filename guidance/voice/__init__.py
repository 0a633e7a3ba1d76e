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
from guidance.voice.wav import WavSpeaker, default_renderer

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------- choice

SpeakerKind = Literal["auto", "voice", "wav", "text"]
SPEAKER_KINDS: tuple[SpeakerKind, ...] = typing.get_args(SpeakerKind)
"""The one list of speaker names (``[voice] backend`` takes these, or ``none``)."""


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
                wav_path,
                renderer=default_renderer(voice, rate_wpm),
                clock=clock,
                maxsize=maxsize,
                max_age_s=max_age_s,
                text_stream=text_stream,
                volume=volume,
            )
        if kind in ("voice", "auto"):
            return Pyttsx3Speaker(
                driver_name,
                rate_wpm=rate_wpm,
                voice=voice,
                volume=volume,
                clock=clock,
                maxsize=maxsize,
                max_age_s=max_age_s,
                text_stream=text_stream,
            )
    except SpeechEngineError as e:
        log.warning("no speech engine (%s); prompts are shown as text%s", e, suffix)
        return TextSpeaker(text_stream, clock, fallback_reason=str(e))
    raise ValueError(f"unknown speaker kind {kind!r}; expected {', '.join(SPEAKER_KINDS)}")
