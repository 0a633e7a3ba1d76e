"""Intelligibility as a tested figure (issue 39): every prompt the product can say, spoken by the
default voice and transcribed by pocketsphinx's general dictation, has a word error rate of at
most 0.25; espeak-ng, the voice before, fails that bar. benchmarks/voice_intelligibility.py
prints the figures side by side with the sentences lost most."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from guidance.tools.voice_corpus import (
    cabin_noise,
    mix_at_snr,
    normalise,
    number_words,
    prompt_corpus,
    speech_power,
    voice_renderer,
    word_error_rate,
)
from guidance.voice.pico import pico_available
from hal_sim.sim_world import landmark_name

WER_BAR = 0.25
LANDMARKS = [landmark_name(k) for k in range(0, 18 * 13, 13)]


def test_numbers_and_spellings_are_compared_as_the_recogniser_writes_them() -> None:
    assert number_words(150) == "one hundred fifty" and number_words(1000) == "one thousand"
    assert normalise("In 1.5 kilometres, make a U-turn.") == (
        ["in", "one", "point", "five", "kilometers", "make", "a", "u", "turn"]
    )
    assert normalise("one hundred and fifty metres") == ["one", "hundred", "fifty", "meters"]
    assert normalise("bread and butter") == ["bread", "and", "butter"]
    assert word_error_rate([("turn left", "turn left")]) == 0.0
    assert word_error_rate([("turn left now", "turned left")]) == pytest.approx(2 / 3)


def test_the_corpus_holds_every_kind_of_prompt() -> None:
    corpus = prompt_corpus(LANDMARKS)
    text = "\n".join(corpus)
    for must in ("Continue straight", "bear left", "turn sharp right", "U-turn", ", then ",
                 "metres", "kilometres", "feet", "miles", "Passing the", "Position lost",
                 "Position found again near", "Chance of reaching", "Warning:", "arrived",
                 "Change of plan", "Please say that again.", "Wheel speed signal lost",
                 "The last report is cancelled", "feet, turn left, then", "The disk is full",
                 "Remote monitoring is offline", "Prompts are shown as text"):  # fmt: skip
        assert must in text, must
    assert len(corpus) == len(set(corpus)) > 80


def test_cabin_noise_is_mixed_at_the_asked_snr() -> None:
    speech = np.sin(np.arange(16000) / 5.0) * 3000.0
    noise = cabin_noise(16000, seed=1)
    mixed = mix_at_snr(speech, noise, 10.0)
    added = mixed - speech
    assert 10 * np.log10(speech_power(speech) / np.mean(added**2)) == pytest.approx(10.0, abs=0.01)


def _wer(voice: str, sentences: list[str]) -> float:
    from drivers.speech_grammar import Transcriber, resample

    render, listen = voice_renderer(voice), Transcriber()
    pairs = []
    for text in sentences:
        pcm, rate = render(text)
        pairs.append((text, listen(resample(np.frombuffer(pcm, dtype="<i2").astype(float), rate))))
    return word_error_rate(pairs)


@pytest.mark.slow
@pytest.mark.skipif(not pico_available(), reason="py-nanotts (Pico) not installed")
def test_the_default_voice_is_understood_over_every_prompt() -> None:
    wer = _wer("pico:en-US", prompt_corpus(LANDMARKS))
    assert wer <= WER_BAR, f"Pico en-US word error rate {wer:.3f}"


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng missing")
def test_the_bar_is_one_espeak_fails() -> None:
    """Every ninth sentence (13 sentences, 100 words; the figure for all is in the benchmark):
    the bar separates. espeak-ng's rate is 0.91 over every prompt and 0.84 over these (every
    third, 37 sentences, cost three times the CPU for no more power: at a rate near 0.9, 100
    words cannot come out under 0.25)."""
    wer = _wer("espeak:en", prompt_corpus(LANDMARKS)[::9])
    assert wer > WER_BAR, f"espeak-ng word error rate {wer:.3f}"
