"""Speech without the Debian package: espeak-ng's library from the espeakng-loader wheel."""

from __future__ import annotations

import wave
from pathlib import Path

import numpy as np
import pytest

from guidance.voice import libespeak
from guidance.voice.wav import EspeakNgRenderer, WavSpeaker, default_renderer

pytestmark = pytest.mark.skipif(
    not libespeak.available(), reason="espeakng-loader wheel not installed (x86-64 Linux only)"
)


def _rms(pcm: bytes) -> float:
    a = np.frombuffer(pcm, dtype=np.int16).astype(float)
    return float(np.sqrt(np.mean(a * a))) if a.size else 0.0


def test_the_library_renders_speech() -> None:
    pcm, rate = libespeak.LibEspeakRenderer()("In 150 metres, turn left")
    assert rate > 8000
    seconds = len(pcm) / 2 / rate
    assert 1.0 < seconds < 5.0  # a short sentence
    assert _rms(pcm) > 500.0  # speech, not silence


def test_without_the_command_line_the_wav_still_holds_speech(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A machine without /usr/bin/espeak-ng (no PATH entry): the wheel's library is used."""
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(Exception, match="espeak-ng not found"):
        EspeakNgRenderer()
    renderer = default_renderer()
    assert isinstance(renderer, libespeak.LibEspeakRenderer)
    out = tmp_path / "prompts.wav"
    spk = WavSpeaker(out, renderer=renderer)
    spk.say("Turn right", 1, 0.0)
    spk.say("You have arrived at your destination", 1, 5.0)
    spk.close(drain=True)
    with wave.open(str(out), "rb") as w:
        frames = w.readframes(w.getnframes())
        assert w.getnchannels() == 1 and w.getsampwidth() == 2
    assert _rms(frames) > 200.0
