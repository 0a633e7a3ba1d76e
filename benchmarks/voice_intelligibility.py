"""The voice's intelligibility as a figure (issue 39): every prompt the product can say, rendered
by each voice and transcribed by pocketsphinx's general English dictation (no knowledge of the
car's sentences); the word error rate over the set, side by side, and the sentences each voice
loses most words in.

    .venv/bin/python benchmarks/voice_intelligibility.py [--voices pico:en-US,espeak:en]
        [--worst 8]

The default voice is ``pico:en-US`` (what ``[voice] voice = "en"`` speaks); the bar is a word
error rate of at most 0.25 (tests/guidance/tools/test_voice_corpus.py holds it).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.speech_grammar import Transcriber, resample
from guidance.tools.voice_corpus import edit_distance, normalise, prompt_corpus, voice_renderer
from hal_sim.sim_world import landmark_name

LANDMARKS = [landmark_name(k) for k in range(0, 18 * 13, 13)]
"""18 of the simulated city's names: every kind of place, and most streets."""


def transcribe_all(voice: str, sentences: list[str]) -> list[tuple[str, str, float]]:
    """(sentence, what the recogniser heard, seconds of audio) for each sentence."""
    render = voice_renderer(voice)
    listen = Transcriber()
    out = []
    for text in sentences:
        pcm, rate = render(text)
        x = resample(np.frombuffer(pcm, dtype="<i2").astype(np.float64), rate)
        out.append((text, listen(x), x.size / 16000))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--voices", default="pico:en-US,pico:en-GB,espeak:en,espeak:en-us")
    ap.add_argument("--worst", type=int, default=8, help="sentences to list per voice")
    args = ap.parse_args()
    sentences = prompt_corpus(LANDMARKS)
    print(f"{len(sentences)} sentences; recogniser: pocketsphinx en-us dictation\n")
    rows = []
    for voice in args.voices.split(","):
        t0 = time.perf_counter()
        heard = transcribe_all(voice, sentences)
        edits = [edit_distance(normalise(s), normalise(h)) for s, h, _ in heard]
        words = sum(len(normalise(s)) for s, _, _ in heard)
        wer = sum(edits) / words
        rows.append((voice, wer, sum(a for *_, a in heard), time.perf_counter() - t0))
        worst = sorted(zip(edits, heard, strict=True), key=lambda e: -e[0] / max(1, len(e[1][0])))
        print(f"{voice}: word error rate {wer:.3f} ({sum(edits)} / {words} words)")
        for e, (s, h, _) in worst[: args.worst]:
            print(f"    {e:2d}  {s!r} -> {h!r}")
        print()
    print(f"{'voice':16} {'WER':>6} {'audio s':>8} {'wall s':>7}")
    for voice, wer, audio, wall in rows:
        print(f"{voice:16} {wer:6.3f} {audio:8.1f} {wall:7.1f}")


if __name__ == "__main__":
    main()
