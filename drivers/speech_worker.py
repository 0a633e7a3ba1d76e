"""The speech input's per-sample work, in the process that decodes (issue 39).

``UtteranceStream`` takes the microphone's audio in blocks, with two flags per block that only
the app knows (the car's voice was speaking: deaf; the talk key is held), and answers with the
utterances it heard: in ``always`` mode the voice activity detector (``Segmenter``: the rumble
filter and pocketsphinx's endpointer) cuts them, in ``key`` mode the key does; each one goes
through ``CommandRecogniser.hear``. Every sample-by-sample step is here.

``ProcessListener`` runs one in a worker process (what the car uses), so the app's process only
moves audio blocks: the reader thread writes the 30 ms blocks of 16-bit samples into a pipe as
they came from ``arecord`` (``BATCH_S`` at a time) and picks up the answers when there are
some, never waiting for a decode. pocketsphinx and the detector hold the GIL while they run; in
the app they delayed the 100 Hz loop (docs/voice.md, "Speed"). The worker runs
``WORKER_NICE_LEVELS`` below the app. In the same process (tests, benchmarks, tools) the stream
is used directly.
"""

from __future__ import annotations

import os
import struct
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Protocol

import numpy as np

from drivers.speech_grammar import (
    ACCEPT,
    MIN_COMMAND_S,
    RATE_HZ,
    SAY_AGAIN,
    WAKE_WINDOW_S,
    CommandRecogniser,
    Heard,
    Segmenter,
    to_pcm16,
)

MAX_HELD_S = 8.0
"""Push-to-talk audio beyond this is not kept (a key stuck down must not fill memory)."""
WORKER_NICE_LEVELS = 19
"""The worker process runs this many nice levels below the app (never real-time; capped at
nice 19): it must not delay the 100 Hz loop, and a report waits for it only when both cores
are busy. benchmarks/voice_loop.py, always listening, 6 pairs of 10 s on a 2-core machine at
load 19: the loop's p99 while decoding 16 ms at 19 levels, 79 ms at 5 (docs/voice.md)."""
BATCH_S = 0.24
"""Blocks are sent to the worker this much at a time (each with its own flags): a message per
30 ms block would fill the pipe's socket buffer (counted per message, not per byte) after a
second or two of a busy worker, and the reader would then wait. Batched, the buffer holds about
6 s of audio before the reader waits for the worker (as it waited for every decode before)."""
START_TIMEOUT_S = 60.0
"""The worker loads pocketsphinx's model (a second or two; more on a loaded machine)."""


@dataclass(frozen=True, slots=True)
class Outcome:
    """One utterance cut from the stream: what ``CommandRecogniser.hear`` made of it (None: not
    meant for the car) and when it was decoded (monotonic s, the same clock in every process)."""

    heard: Heard | None
    decode_start: float
    decode_end: float


TALK_MODES = ("key", "wake", "always")
"""``key``: push-to-talk; ``wake``: the voice activity detector cuts utterances and one is a
command only after ``WAKE_WORD`` (in it, or alone just before it); ``always``: every utterance
is tried, the confidence threshold alone keeps talk out."""


class UtteranceStream:
    """Blocks of 16 kHz audio in, ``Outcome``s out (see the module docstring). Not
    thread-safe: one per stream."""

    def __init__(self, recogniser: CommandRecogniser, talk: str) -> None:
        if talk not in TALK_MODES:
            raise ValueError(f"talk must be one of {', '.join(TALK_MODES)}, not {talk!r}")
        self.recogniser = recogniser
        self.talk = talk
        self.reset()

    def reset(self) -> None:
        """A new stream: its first sample is at 0 s."""
        self._segmenter = Segmenter() if self.talk != "key" else None
        self._ptt: list[np.ndarray] = []
        self._audio_s = 0.0
        self._armed_until = -1.0
        """``wake``: the wake word was said alone; an utterance starting before this is heard."""

    def _hear(self, samples: np.ndarray, t_s: float, push_to_talk: bool | None = None) -> Outcome:
        t0 = time.monotonic()
        ptt = self.talk == "key" if push_to_talk is None else push_to_talk
        heard = self.recogniser.hear(samples, t_s, push_to_talk=ptt)
        return Outcome(heard, t0, time.monotonic())

    def _utterance(self, t_s: float, samples: np.ndarray) -> Outcome:
        """One utterance the detector cut: tried (``always``), or heard as a held key's when it
        follows the wake word (``wake``: the rest of it, or the next one)."""
        if self.talk == "always":
            return self._hear(samples, t_s)
        t0 = time.monotonic()
        if t_s <= self._armed_until:
            self._armed_until = -1.0
            return self._hear(samples, t_s, push_to_talk=True)
        end = self.recogniser.wake_end(samples)
        if end is None:
            return Outcome(None, t0, time.monotonic())
        if samples.size - end >= MIN_COMMAND_S * RATE_HZ:
            rest = self._hear(samples[end:], t_s + end / RATE_HZ, push_to_talk=True)
            if rest.heard is not None and rest.heard.line:
                return rest
        # the wake word alone (or with no complete phrase after it): the command may follow
        self._armed_until = t_s + samples.size / RATE_HZ + WAKE_WINDOW_S
        return Outcome(None, t0, time.monotonic())

    def feed(
        self, samples: np.ndarray, *, deaf: bool = False, talking: bool = False
    ) -> list[Outcome]:
        """One block, in order. ``deaf``: the car's voice covered it (what was being said is
        dropped); ``talking``: the talk key was down (push-to-talk)."""
        x = samples.astype(np.float64)
        self._audio_s += x.size / RATE_HZ
        if deaf:
            self._ptt = []  # the car talked over it: nothing of it is a report
            if self._segmenter is not None:
                self._segmenter = Segmenter()
            self._armed_until = -1.0
            return []
        if self._segmenter is not None:
            return [self._utterance(t, u) for t, u in self._segmenter.feed(x)]
        if talking:
            if sum(h.size for h in self._ptt) < MAX_HELD_S * RATE_HZ:
                self._ptt.append(x)
            return []
        return self._release()

    def _release(self) -> list[Outcome]:
        if not self._ptt:
            return []
        utterance = np.concatenate(self._ptt)
        self._ptt = []
        return [self._hear(utterance, self._audio_s - utterance.size / RATE_HZ)]

    def flush(self) -> list[Outcome]:
        """The audio ended: the utterance in progress is heard (a WAV that ends mid-phrase)."""
        if self._segmenter is not None:
            return [self._utterance(t, u) for t, u in self._segmenter.flush()]
        return self._release()

    def close(self) -> None:
        """Nothing to release in this process."""


class Listener(Protocol):
    """``UtteranceStream`` (in this process) or ``ProcessListener`` (the car)."""

    def reset(self) -> None: ...
    def feed(
        self, samples: np.ndarray, *, deaf: bool = False, talking: bool = False
    ) -> list[Outcome]: ...
    def flush(self) -> list[Outcome]: ...
    def close(self) -> None: ...


# ------------------------------------------------------------------------- the worker process

_AUDIO, _RESET, _FLUSH = b"a", b"r", b"f"
_HEAD = struct.Struct("<cH")  # kind, number of blocks
_BLOCK = struct.Struct("<BI")  # per block: flags (1: deaf, 2: talking), samples; then the PCM


def lower_priority(nice_levels: int = WORKER_NICE_LEVELS) -> None:
    """This process: never real-time, ``nice_levels`` below its parent (at most nice 19)."""
    if os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK in (os.SCHED_RR, os.SCHED_FIFO):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.setpriority(os.PRIO_PROCESS, 0, min(19, os.getpriority(os.PRIO_PROCESS, 0)
                                           + nice_levels))  # fmt: skip


def _serve(
    conn: Connection, talk: str, nice_levels: int, accept: float, say_again: float
) -> None:
    """The worker: audio blocks in, ("heard" | "flushed", outcomes) out, until the pipe closes."""
    try:  # the model loads at the app's priority (at its start), then the worker steps down
        stream = UtteranceStream(CommandRecogniser(accept, say_again), talk)
        stream.recogniser.wake_end(np.zeros(RATE_HZ // 10))  # the wake word's search too
        lower_priority(nice_levels)
    except Exception as exc:  # reported to the app, which says so
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", []))
    while True:
        try:
            msg = conn.recv_bytes()
        except (EOFError, OSError):
            return
        kind, n = _HEAD.unpack_from(msg)
        if kind == _AUDIO:
            out = []
            pos = _HEAD.size + n * _BLOCK.size
            for k in range(n):
                flags, size = _BLOCK.unpack_from(msg, _HEAD.size + k * _BLOCK.size)
                x = np.frombuffer(msg, dtype="<i2", count=size, offset=pos)
                pos += 2 * size
                out += stream.feed(x, deaf=bool(flags & 1), talking=bool(flags & 2))
            if out:
                conn.send(("heard", out))
        elif kind == _FLUSH:
            conn.send(("flushed", stream.flush()))
        elif kind == _RESET:
            stream.reset()


class ProcessListener:
    """An ``UtteranceStream`` in a worker process (see the module docstring): ``feed`` writes the
    block into the pipe and returns what the worker has answered so far, without waiting."""

    def __init__(
        self,
        talk: str,
        nice_levels: int = WORKER_NICE_LEVELS,
        accept: float = ACCEPT,
        say_again: float = SAY_AGAIN,
    ) -> None:
        from multiprocessing import get_context

        ctx = get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(target=_serve, name="speech-recogniser", daemon=True,
                                    args=(child, talk, nice_levels, accept, say_again))  # fmt: skip
        self._process.start()
        child.close()
        self._blocks: list[tuple[int, bytes]] = []
        self._pending = 0
        if not self._conn.poll(START_TIMEOUT_S):
            self.close()
            raise OSError(f"the recogniser process did not start within {START_TIMEOUT_S:.0f} s")
        kind, detail = self._receive()
        if kind != "ready":
            self.close()
            raise OSError(f"the recogniser process cannot start: {detail}")

    @property
    def pid(self) -> int | None:
        return self._process.pid

    def _receive(self) -> tuple[str, list[Outcome]]:
        try:
            kind, out = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise OSError(f"the recogniser process stopped ({exc or 'pipe closed'})") from None
        return kind, out

    def _send(self, kind: bytes) -> None:
        blocks = self._blocks if kind == _AUDIO else []
        head = _HEAD.pack(kind, len(blocks))
        head += b"".join(_BLOCK.pack(flags, len(pcm) // 2) for flags, pcm in blocks)
        self._blocks, self._pending = [], 0
        try:
            self._conn.send_bytes(head + b"".join(pcm for _, pcm in blocks))
        except (BrokenPipeError, ConnectionError) as exc:
            raise OSError(f"the recogniser process stopped ({exc})") from None

    def _answers(self) -> list[Outcome]:
        out: list[Outcome] = []
        while self._conn.poll(0):
            out += self._receive()[1]
        return out

    def reset(self) -> None:
        self._blocks, self._pending = [], 0  # what was not sent is of the stream before
        self._send(_RESET)

    def feed(
        self, samples: np.ndarray, *, deaf: bool = False, talking: bool = False
    ) -> list[Outcome]:
        pcm = samples.tobytes() if samples.dtype == np.dtype("<i2") else to_pcm16(samples)
        self._blocks.append((int(deaf) | 2 * int(talking), pcm))
        self._pending += samples.size
        if self._pending >= BATCH_S * RATE_HZ:
            self._send(_AUDIO)
        return self._answers()

    def flush(self, timeout_s: float = 60.0) -> list[Outcome]:
        """Everything the worker still has, the utterance in progress included (waits)."""
        if self._blocks:
            self._send(_AUDIO)
        self._send(_FLUSH)
        out: list[Outcome] = []
        deadline = time.monotonic() + timeout_s
        while True:
            if not self._conn.poll(max(0.0, deadline - time.monotonic())):
                raise OSError(f"the recogniser process did not answer within {timeout_s:.0f} s")
            kind, got = self._receive()
            out += got
            if kind == "flushed":
                return out

    def close(self) -> None:
        self._conn.close()
        self._process.join(5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
