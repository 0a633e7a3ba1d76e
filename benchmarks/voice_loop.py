"""The 100 Hz loop's lateness with and without always listening, side by side in one run
(issue 39: "the 100 Hz loop's lateness p99 unchanged with the microphone on").

One asyncio ticker on absolute deadlines (as ``App``'s, with its GIL switch interval) runs for
the whole benchmark. The run is cut into blocks that alternate: **off** (no speech input) and
**on** (``drivers.speech.SpeechInput`` always listening, its recogniser in its worker process,
reading a FIFO that another process fills in real time, as ``arecord`` does in the car, with
the 20 spoken commands and radio-like talk in cabin noise at 20 dB). The machine's load drifts
(two cores shared with other jobs), so the comparison is between neighbouring blocks, and the
first ``SETTLE_S`` of each block (the input starting or stopping) is left out.

Printed: each pair's p99 (off, on), the pooled p50 / p99 / max of each condition (and of the
"on" ticks while an utterance was being decoded), and the criterion. "Unchanged" is judged
against the off blocks' own spread: the on-minus-off p99 difference, pair by pair, has a median
inside the range of differences between consecutive off blocks (what the drift alone does);
beside it, how many pairs had "on" above "off" (a sign test: a consistent small cost shows
there even when the drift hides it).

    .venv/bin/python benchmarks/voice_loop.py [--pairs 6] [--block 10]
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from drivers.speech import SpeechInput, SpeechInputConfig
from drivers.speech_grammar import (
    RATE_HZ,
    WORKER_NICE_LEVELS,
    Heard,
    ProcessRecogniser,
    Segmenter,
    resample,
    to_pcm16,
)
from guidance.app.app import GIL_SWITCH_INTERVAL_S
from guidance.tools.voice_corpus import (
    RADIO_TEXT,
    SPOKEN_COMMANDS,
    cabin_noise,
    mix_at_snr,
    voice_renderer,
)

SETTLE_S = 1.0
"""Left out at the start of each block: the speech input starting (or just stopped)."""

WRITER = """
import sys, time
data = open(sys.argv[1], "rb").read()
out = open(sys.argv[2], "wb")
chunk, t0, k = 960, time.monotonic(), 0
while True:
    a = (k * chunk) % (len(data) - chunk)
    out.write(data[a:a + chunk]); out.flush()
    k += 1
    time.sleep(max(0.0, t0 + k * 0.03 - time.monotonic()))
"""
"""The microphone's stand-in: another process writing 16 kHz samples in real time (30 ms)."""


def _speech(voice: str, text: str) -> np.ndarray:
    pcm, rate = voice_renderer(voice)(text)
    return resample(np.frombuffer(pcm, dtype="<i2").astype(np.float64), rate)


def tape() -> bytes:
    """Commands with pauses, then radio-like talk, in cabin noise at 20 dB (16-bit PCM)."""
    parts = []
    for text, _ in SPOKEN_COMMANDS:
        parts += [_speech("flite:awb", text), np.zeros(RATE_HZ * 2)]
    parts.append(_speech("espeak:en-us", RADIO_TEXT[:700]))
    x = np.concatenate(parts)
    return to_pcm16(mix_at_snr(x, cabin_noise(x.size, 5), 20.0))


class Timed:
    """The recogniser, with when each utterance was being decoded (monotonic s)."""

    def __init__(self, inner: ProcessRecogniser) -> None:
        self.inner = inner
        self.spans: list[tuple[float, float]] = []

    def hear(
        self, samples: np.ndarray, t_s: float = 0.0, *, push_to_talk: bool = False
    ) -> Heard | None:
        t0 = time.monotonic()
        try:
            return self.inner.hear(samples, t_s, push_to_talk=push_to_talk)
        finally:
            self.spans.append((t0, time.monotonic()))


class Microphone:
    """A speech input always listening to a FIFO fed by a writer process (one block)."""

    def __init__(self, raw: Path, fifo: Path, recogniser: Timed, talk: str = "always") -> None:
        self.raw, self.fifo, self.recogniser, self.talk = raw, fifo, recogniser, talk
        self.writer: subprocess.Popen[bytes] | None = None
        self.input: SpeechInput | None = None
        self.utterances = 0

    def on(self) -> None:
        self.writer = subprocess.Popen([sys.executable, "-c", WRITER, str(self.raw),
                                        str(self.fifo)])  # fmt: skip
        self.input = SpeechInput(
            SpeechInputConfig(device=str(self.fifo), talk=self.talk), lambda: 0.0,
            feedback=lambda _t: None, recogniser=self.recogniser,
        )  # fmt: skip
        self.input.start(lambda _m: None)

    def off(self) -> None:
        if self.input is not None:
            self.input.stop()
            self.utterances += self.input.stats().get("utterances", 0)
            self.input = None
        if self.writer is not None:
            self.writer.kill()
            self.writer.wait()
            self.writer = None


def run(pairs: int, block_s: float, mic: Microphone) -> list[tuple[int, float, float]]:
    """(block, deadline, lateness s) of every tick after the first ``SETTLE_S`` of its block."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    samples: list[tuple[int, float, float]] = []
    n_blocks = 2 * pairs
    boundary = [threading.Event() for _ in range(n_blocks)]

    def control() -> None:  # on a thread of its own, as the app's device threads are
        for b in range(n_blocks):
            boundary[b].wait()
            mic.on() if b % 2 else mic.off()
        mic.off()

    ctl = threading.Thread(target=control, daemon=True)
    ctl.start()

    async def tick() -> None:
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        k, block = 0, -1
        while True:
            k += 1
            deadline = t0 + k * 0.01
            await asyncio.sleep(max(0.0, deadline - loop.time()))
            late = loop.time() - deadline
            elapsed = deadline - t0
            b = int(elapsed // block_s)
            if b >= n_blocks:
                return
            if b != block:
                block = b
                boundary[b].set()
            if elapsed - b * block_s >= SETTLE_S:
                samples.append((b, deadline, late))

    asyncio.run(tick())
    ctl.join(10)
    return samples


def p99(x: np.ndarray) -> float:
    return float(np.percentile(x, 99))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--block", type=float, default=10.0, help="seconds per block")
    ap.add_argument("--nice", type=int, default=WORKER_NICE_LEVELS,
                    help="the recogniser process's nice levels below this one")  # fmt: skip
    ap.add_argument("--talk", choices=("always", "key"), default="always",
                    help="key: push-to-talk with the key up (reading only), for comparison")
    args = ap.parse_args()
    recogniser = Timed(ProcessRecogniser(args.nice))
    recogniser.hear(np.zeros(RATE_HZ // 2), push_to_talk=True)  # started and warm
    recogniser.spans.clear()
    Segmenter()  # pocketsphinx imported and its detector built once, as at the car's start
    with tempfile.TemporaryDirectory() as d:
        raw, fifo = Path(d) / "tape.raw", Path(d) / "mic"
        raw.write_bytes(tape())
        os.mkfifo(fifo)
        mic = Microphone(raw, fifo, recogniser, args.talk)
        load0 = os.getloadavg()[0]
        samples = run(args.pairs, args.block, mic)
    recogniser.inner.close()
    by_block: dict[int, np.ndarray] = {}
    for b in range(2 * args.pairs):
        by_block[b] = np.array([s for k, _t, s in samples if k == b]) * 1e3
    print(f"100 Hz loop lateness (ms): {args.pairs} pairs of {args.block:.0f} s blocks, off then "
          f"{args.talk} (recogniser {args.nice} nice levels down); load average "
          f"{load0:.1f} -> {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
          f"{mic.utterances} utterances decoded")  # fmt: skip
    print("  pair   off p99   on p99   on - off")
    diffs = []
    for i in range(args.pairs):
        off, on = p99(by_block[2 * i]), p99(by_block[2 * i + 1])
        diffs.append(on - off)
        print(f"  {i + 1:4}   {off:7.2f}  {on:7.2f}   {on - off:+7.2f}")
    offs = [p99(by_block[2 * i]) for i in range(args.pairs)]
    drift = np.diff(offs)
    for label, parity in (("off", 0), ("on", 1)):
        a = np.concatenate([by_block[b] for b in by_block if b % 2 == parity])
        print(f"  pooled {label:3}  p50 {np.percentile(a, 50):6.2f}  p99 {p99(a):6.2f}  "
              f"max {a.max():7.2f}  (n={a.size})")  # fmt: skip
    spans = recogniser.spans
    busy = np.array([s for k, t, s in samples if k % 2 and any(a <= t <= b for a, b in spans)])
    idle = np.array([s for k, t, s in samples if k % 2 and not any(a <= t <= b for a, b in spans)])
    for label, a in (("decoding", busy * 1e3), ("not", idle * 1e3)):
        if a.size:
            print(f"  on, {label:8} p50 {np.percentile(a, 50):6.2f}  p99 {p99(a):6.2f}  "
                  f"max {a.max():7.2f}  (n={a.size})")  # fmt: skip
    med = float(np.median(diffs))
    lo, hi = (float(drift.min()), float(drift.max())) if drift.size else (0.0, 0.0)
    verdict = "unchanged" if lo <= med <= hi else "CHANGED"
    above = sum(d > 0 for d in diffs)
    sign_p = sum(math.comb(len(diffs), k) for k in range(above, len(diffs) + 1)) / 2 ** len(diffs)
    print(f"  median on - off p99 {med:+.2f} ms; off-to-off drift {lo:+.2f} .. {hi:+.2f} ms: "
          f"{verdict}; on above off in {above} of {len(diffs)} pairs (one-sided sign test "
          f"p = {sign_p:.3f})")  # fmt: skip


if __name__ == "__main__":
    main()
