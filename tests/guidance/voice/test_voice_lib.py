"""Speech without the Debian package: espeak-ng's library from the espeakng-loader wheel.

Each check runs in a child process: the wheel's libespeak-ng and the system's (which pyttsx3
loads in tests/guidance/voice/test_voice.py) share a soname, and two copies initialised in one
process crash it. In the car only one is ever loaded: the library is the fallback when the espeak-ng
command, and with it the system library, is missing.
"""

from __future__ import annotations

import json
import subprocess
import sys
import wave
from pathlib import Path

import numpy as np
import pytest

from guidance.voice import libespeak

pytestmark = pytest.mark.skipif(
    not libespeak.available(), reason="espeakng-loader wheel not installed (x86-64 Linux only)"
)


def _child(code: str, tmp_path: Path, env_path: str | None = None) -> dict[str, object]:
    import os

    env = dict(os.environ)
    if env_path is not None:
        env["PATH"] = env_path
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env,
        cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    return dict(json.loads(r.stdout.splitlines()[-1]))


def _rms(pcm: bytes) -> float:
    a = np.frombuffer(pcm, dtype=np.int16).astype(float)
    return float(np.sqrt(np.mean(a * a))) if a.size else 0.0


def _wav(path: Path) -> bytes:
    with wave.open(str(path), "rb") as w:
        assert w.getnchannels() == 1 and w.getsampwidth() == 2
        return w.readframes(w.getnframes())


def test_the_library_renders_speech(tmp_path: Path) -> None:
    out = _child(
        "import json; from guidance.voice.libespeak import LibEspeakRenderer\n"
        "pcm, rate = LibEspeakRenderer()('In 150 metres, turn left')\n"
        "open('pcm.raw', 'wb').write(pcm); print(json.dumps({'rate': rate}))",
        tmp_path,
    )
    rate = int(out["rate"])  # type: ignore[call-overload]
    pcm = (tmp_path / "pcm.raw").read_bytes()
    assert rate > 8000
    assert 1.0 < len(pcm) / 2 / rate < 5.0  # a short sentence
    assert _rms(pcm) > 500.0  # speech, not silence


def test_without_the_command_line_the_wav_still_holds_speech(tmp_path: Path) -> None:
    """A machine without /usr/bin/espeak-ng (nothing on PATH): the wheel's library is used."""
    out = _child(
        "import json\n"
        "from guidance.voice import libespeak\n"
        "from guidance.voice.wav import EspeakNgRenderer, WavSpeaker, default_renderer\n"
        "try:\n    EspeakNgRenderer(); cli = True\nexcept Exception:\n    cli = False\n"
        "r = default_renderer()\n"
        "spk = WavSpeaker('prompts.wav', renderer=r)\n"
        "spk.say('Turn right', 1, 0.0); spk.say('You have arrived', 1, 5.0)\n"
        "spk.close(drain=True)\n"
        "print(json.dumps({'cli': cli, 'lib': isinstance(r, libespeak.LibEspeakRenderer)}))",
        tmp_path,
        env_path=str(tmp_path / "empty"),
    )
    assert out == {"cli": False, "lib": True}
    assert _rms(_wav(tmp_path / "prompts.wav")) > 200.0


def test_voice_rate_and_volume_come_from_the_config(tmp_path: Path) -> None:
    """[voice] voice, rate_wpm and volume reach the WAV: slower speech is longer, a lower
    volume is quieter."""
    _child(
        "import json\n"
        "from guidance.app.build import build_speaker\n"
        "for rate, vol in ((170, 1.0), (120, 1.0), (170, 0.25)):\n"
        "    s = build_speaker('wav', f'r{rate}v{vol}.wav', lambda: 0.0, voice='en',\n"
        "                      rate_wpm=rate, volume=vol)\n"
        "    s.say('In 150 metres, turn left', 1, 0.0); s.close(drain=True)\n"
        "print(json.dumps({}))",
        tmp_path,
    )
    normal = _wav(tmp_path / "r170v1.0.wav")
    slow = _wav(tmp_path / "r120v1.0.wav")
    quiet = _wav(tmp_path / "r170v0.25.wav")
    assert len(slow) > 1.2 * len(normal)  # 120 wpm is slower than 170
    assert _rms(quiet) < 0.4 * _rms(normal)  # a quarter of the volume
