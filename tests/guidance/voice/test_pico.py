"""Pico as the default voice (issue 39): the real py-nanotts engine, real WAV files, ALSA's null
device for the played voice (no sound card here)."""

from __future__ import annotations

import io
import shutil
import subprocess
import sys
import time
import wave
from pathlib import Path

import numpy as np
import pytest

from guidance.voice import make_renderer, make_speaker
from guidance.voice.activity import CarVoice
from guidance.voice.level import TARGET_RMS_DBFS, normalise_level, rms_dbfs
from guidance.voice.pico import PicoRenderer, pico_available, pico_voice, speakable
from guidance.voice.playback import AplayPlayer, PlayedSpeaker
from guidance.voice.speakers import SpeechEngineError, TextSpeaker
from guidance.voice.wav import WavSpeaker

PICO = pytest.mark.skipif(not pico_available(), reason="py-nanotts (Pico) not installed")
APLAY = pytest.mark.skipif(shutil.which("aplay") is None, reason="aplay (alsa-utils) missing")
ESPEAK = pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng missing")


def _wav(path: Path) -> tuple[bytes, int]:
    with wave.open(str(path), "rb") as w:
        assert (w.getnchannels(), w.getsampwidth()) == (1, 2)
        return w.readframes(w.getnframes()), w.getframerate()


def test_speakable_text_has_no_spelled_out_hyphen_or_colon() -> None:
    assert speakable("In 1.5 kilometres, make a U-turn") == "In 1.5 kilometres, make a U turn"
    assert speakable("Position lost. Guidance is unreliable; stop") == (
        "Position lost. Guidance is unreliable, stop"
    )
    assert speakable("Passing the bank: confirmed") == "Passing the bank, confirmed"


def test_pico_voices_by_language_code() -> None:
    assert pico_voice("en") == "en-US" and pico_voice("en-GB") == "en-GB"
    assert pico_voice("gmw/en-us") == "en-US" and pico_voice("de") == "de-DE"
    assert pico_voice("pl") is None and pico_voice("") is None


def test_level_normalisation_brings_loud_and_quiet_speech_to_one_level() -> None:
    t = np.arange(16000) / 16000
    envelope = (np.sin(2 * np.pi * 3 * t) > 0).astype(float)  # syllables and pauses
    for amp in (300.0, 3000.0, 30000.0):
        pcm = (amp * envelope * np.sin(2 * np.pi * 220 * t)).astype("<i2").tobytes()
        assert abs(rms_dbfs(normalise_level(pcm)) - TARGET_RMS_DBFS) < 0.5
    click = np.zeros(16000)
    click[100] = 20000.0
    click[200:1000] = 50.0 * np.sin(np.arange(800))
    out = np.frombuffer(normalise_level(click.astype("<i2").tobytes()), dtype="<i2")
    assert np.max(np.abs(out)) <= 32768 * 10 ** (-1 / 20) + 1  # peak-limited, never clipped
    quiet = normalise_level((3000 * envelope).astype("<i2").tobytes(), volume=0.25)
    assert abs(rms_dbfs(quiet) - (TARGET_RMS_DBFS - 12.04)) < 0.5
    assert normalise_level(b"\0\0" * 100) == b"\0\0" * 100 and normalise_level(b"") == b""


@PICO
def test_pico_renders_a_prompt_as_speech() -> None:
    pcm, rate = PicoRenderer()("In 300 metres, turn left")
    a = np.frombuffer(pcm, dtype="<i2").astype(float)
    assert rate == 16000 and 1.0 < a.size / rate < 4.0
    assert np.sqrt(np.mean(a * a)) > 300.0
    with pytest.raises(SpeechEngineError, match="no voice"):
        PicoRenderer("pl")


@PICO
def test_the_default_wav_is_pico_level_normalised(tmp_path: Path) -> None:
    wav = tmp_path / "p.wav"
    spk = make_speaker("auto", wav, clock=lambda: 0.0)
    assert isinstance(spk, WavSpeaker) and spk.renderer_name == "PicoRenderer"
    texts = ["Turn left", "Position lost. Guidance is unreliable; stop when safe"]
    for i, text in enumerate(texts):
        spk.say(text, 1, float(i))
    spk.close()
    pcm, rate = _wav(wav)
    assert rate == 16000
    for r in spk.recorded:
        part = pcm[round(r.offset_s * rate) * 2 : round((r.offset_s + r.duration_s) * rate) * 2]
        assert abs(rms_dbfs(part) - TARGET_RMS_DBFS) < 1.0, r.text


@ESPEAK
def test_espeak_stays_selectable_and_speaks_what_pico_cannot(tmp_path: Path) -> None:
    spk = make_speaker("espeak", tmp_path / "e.wav", clock=lambda: 0.0)
    assert isinstance(spk, WavSpeaker) and spk.renderer_name == "EspeakNgRenderer"
    spk.close()
    assert type(make_renderer("auto", "pl")).__name__ == "EspeakNgRenderer"  # no Polish Pico


@PICO
@APLAY
def test_the_live_voice_plays_pico_through_alsa_and_tells_the_microphone() -> None:
    heard = CarVoice()
    spk = PlayedSpeaker(PicoRenderer(), AplayPlayer("null"), car_voice=heard)
    spk.say("Turn left", 1)
    deadline = time.monotonic() + 10
    while spk.stats()["spoken"] < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    spk.close()
    assert spk.stats()["spoken"] == 1 and spk.health().status == "ok"
    assert heard.recent() == ("Turn left",)
    assert heard.busy(tail_s=1.0)  # a 0.6 s prompt, just ended: within the tail


@PICO
@APLAY
def test_make_speaker_voice_is_pico_aloud() -> None:
    spk = make_speaker("voice", device="null")
    assert isinstance(spk, PlayedSpeaker) and spk.engine == "Pico"
    spk.close()


@PICO
@APLAY
def test_a_sound_device_that_is_not_there_is_a_clear_fallback_to_text() -> None:
    out = io.StringIO()
    spk = make_speaker("pico", device="no_such_card", text_stream=out)
    assert isinstance(spk, TextSpeaker)
    assert "no audio output on 'no_such_card'" in (spk.fallback_reason or "")
    spk.say("Turn left", 1, 0.0)
    assert "Turn left" in out.getvalue()


@PICO
@APLAY
def test_aplay_failing_mid_drive_is_detected_and_goes_to_text(tmp_path: Path) -> None:
    """Unlike pyttsx3, the played voice checks aplay's exit status for every prompt."""
    flag = tmp_path / "unplugged"
    wrapper = tmp_path / "aplay"
    wrapper.write_text(f'#!/bin/sh\n[ -e "{flag}" ] && exit 1\nexec aplay "$@"\n')
    wrapper.chmod(0o755)
    out = io.StringIO()
    spk = PlayedSpeaker(PicoRenderer(), AplayPlayer("null", str(wrapper)), text_stream=out)
    flag.touch()
    spk.say("Turn right", 1)
    deadline = time.monotonic() + 10
    while not spk.failed and time.monotonic() < deadline:
        time.sleep(0.01)
    spk.close()
    assert spk.health().status == "text_fallback" and "Turn right" in out.getvalue()


@PICO
def test_guidance_voice_say_writes_the_sentence(tmp_path: Path) -> None:
    out = tmp_path / "s.wav"
    r = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "voice", "say", "Turn left", "--to", str(out)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    pcm, rate = _wav(out)
    assert rate == 16000 and len(pcm) / 2 / rate > 0.3 and "PicoRenderer" in r.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "voice", "say", " ", "--to", str(out)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert bad.returncode == 2 and "nothing to say" in bad.stderr
