"""Speed of the voice and of the speech input (issue 39), printed side by side:

* prompt render time: every prompt of ``prompt_corpus`` rendered and level-normalised as the
  car does it (Pico, the default; espeak-ng's command line beside), p50 / p90 / max
  (target: p90 <= 50 ms);
* recognition cost: CPU seconds per second of audio on one core (target <= 0.10): push-to-talk
  commands in cabin noise, always listening and the wake word's mode on radio-like talk.

The 100 Hz loop's lateness with the microphone off and on is benchmarks/voice_loop.py's.

    .venv/bin/python benchmarks/voice_speed.py
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from drivers.speech_grammar import RATE_HZ, CommandRecogniser, resample
from drivers.speech_worker import UtteranceStream
from guidance.tools.voice_corpus import (
    RADIO_TEXT,
    SPOKEN_COMMANDS,
    cabin_noise,
    mix_at_snr,
    prompt_corpus,
    voice_renderer,
)
from guidance.voice import make_renderer
from guidance.voice.level import normalise_level
from hal_sim.sim_world import landmark_name


def render_times(engine: str) -> tuple[np.ndarray, np.ndarray]:
    """(wall, CPU) seconds to render and level each prompt: on a busy machine the wall time
    includes waiting for a core, the CPU time is the work."""
    render = make_renderer(engine)  # type: ignore[arg-type]
    wall, cpu = [], []
    for text in prompt_corpus([landmark_name(k) for k in range(0, 234, 13)]):
        t0, c0 = time.perf_counter(), time.process_time()
        pcm, _ = render(text)
        normalise_level(pcm)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return np.array(wall), np.array(cpu)


def _speech(voice: str, text: str) -> np.ndarray:
    pcm, rate = voice_renderer(voice)(text)
    return resample(np.frombuffer(pcm, dtype="<i2").astype(np.float64), rate)


def recognition_cost() -> tuple[float, float, float]:
    """(push-to-talk commands, always listening on talk, the wake word's mode on talk): CPU s
    per audio s, in this process (the voice activity detector included in the last two)."""
    rec = CommandRecogniser()
    cpu = audio = 0.0
    for i, (text, _) in enumerate(SPOKEN_COMMANDS):
        x = np.concatenate([np.zeros(4800), _speech("flite:slt", text), np.zeros(4800)])
        x = mix_at_snr(x, cabin_noise(x.size, i), 10.0)
        t0 = time.process_time()
        rec.hear(x, push_to_talk=True)
        cpu += time.process_time() - t0
        audio += x.size / RATE_HZ
    talk = np.concatenate([_speech("espeak:en-us", RADIO_TEXT[:600]), np.zeros(RATE_HZ)])
    talk = mix_at_snr(talk, cabin_noise(talk.size, 99), 20.0)
    t0 = time.process_time()
    rec.recognise(talk)
    always = (time.process_time() - t0) / (talk.size / RATE_HZ)
    stream = UtteranceStream(rec, "wake")
    t0 = time.process_time()
    stream.feed(talk)
    stream.flush()
    return cpu / audio, always, (time.process_time() - t0) / (talk.size / RATE_HZ)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.parse_args()
    print("Prompt render + level (ms over every prompt)")
    print(f"  load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    for engine in ("pico", "espeak"):
        wall, cpu = (t * 1e3 for t in render_times(engine))
        print(f"  {engine:7} wall p50 {np.percentile(wall, 50):5.1f}  p90 "
              f"{np.percentile(wall, 90):5.1f}  max {wall.max():5.1f};  CPU p90 "
              f"{np.percentile(cpu, 90):5.1f}  (n={wall.size})")  # fmt: skip
    ptt, always, wake = recognition_cost()
    print(f"\nRecognition, CPU s per audio s on one core: push-to-talk {ptt:.3f}, "
          f"always listening on talk {always:.3f}, the wake word's mode on talk "
          f"{wake:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
