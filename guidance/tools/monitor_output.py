"""``guidance monitor --json``'s output, written on a thread of its own (issue 41, the stall).

The monitor used to write its JSON lines on the thread that takes messages from zenoh. A
program that reads the monitor's stdout late or in bursts (``subprocess.communicate`` after a
run, a pipeline stage that is busy) fills the pipe (64 KiB on Linux: 2.6 s of five cars'
states): the monitor then sat in ``write`` and took nothing from zenoh, whose per-kind rings
kept only each car's newest states, so when the reader came back every car's states from the
whole blocked stretch were gone but the last two: "prints each car's states for 1-3 s, then
nothing until it exits". A car published by the project shows the same with enough output;
one car at 10 Hz fills 64 KiB in about 13 s, which is why a short single-car run never did.

Now the reader only hands lines to ``LineWriter`` and goes back to zenoh; the writer thread
blocks on the pipe instead. Its queue is bounded in bytes (``OUTPUT_BUFFER_BYTES``): past
that the reader waits for the writer (the old behaviour, each car's states conflated to its
newest by the client's rings), said once on stderr.
"""

from __future__ import annotations

import sys
import threading
from collections import deque
from collections.abc import Callable
from typing import TextIO

OUTPUT_BUFFER_BYTES = 256 * 2**20
"""Output held for a reader of stdout that is behind: a state line is about 560 bytes, so
this is 7 minutes of 100 cars at 10 Hz (a script reading a run's output at its end) or 45 s
of 1,000 cars, in a process that already holds every car's track."""


def _stderr_line(text: str) -> None:
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


class LineWriter:
    """Writes text handed to ``put`` to ``out`` in order, on its own thread, one write and
    flush per batch waiting. ``put`` returns at once unless ``limit_bytes`` are waiting;
    ``close`` writes what is left and ends the thread. When the reader of ``out`` has gone
    (``BrokenPipeError``, e.g. piped into ``head``) ``broken`` is set and the rest dropped."""

    def __init__(
        self,
        out: TextIO,
        *,
        limit_bytes: int = OUTPUT_BUFFER_BYTES,
        warn: Callable[[str], None] = _stderr_line,
    ) -> None:
        self._out = out
        self._limit = limit_bytes
        self._warn = warn
        self._chunks: deque[str] = deque()
        self._queued = 0
        self._done = False
        self._warned = False
        self.broken = False
        self.error: OSError | None = None
        """What ended the writing early (a broken pipe, a full disk), if anything did."""
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="monitor-output", daemon=True)
        self._thread.start()

    def put(self, text: str) -> None:
        """Queue ``text`` (whole lines); waits only while ``limit_bytes`` are queued."""
        with self._cond:
            while self._queued >= self._limit and not self.broken:
                if not self._warned:
                    self._warned = True
                    self._warn(
                        f"guidance monitor: {self._queued / 2**20:.0f} MiB of output waiting "
                        "for whoever reads stdout; taking messages only as fast as it reads "
                        "(each car's states in between are dropped for its newest)"
                    )
                self._cond.wait(0.25)
            if self.broken:
                return
            self._chunks.append(text)
            self._queued += len(text)
            self._cond.notify_all()

    def queued_bytes(self) -> int:
        with self._cond:
            return self._queued

    def close(self) -> None:
        """Write everything queued, then end the thread (waits as long as stdout's reader
        takes, as a write would have)."""
        with self._cond:
            self._done = True
            self._cond.notify_all()
        self._thread.join()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._chunks and not self._done:
                    self._cond.wait()
                if not self._chunks:
                    return
                batch = "".join(self._chunks)
                self._chunks.clear()
            try:
                self._out.write(batch)
                self._out.flush()
            except OSError as exc:  # BrokenPipeError included: nobody reads any more
                with self._cond:
                    self.broken = True
                    self.error = exc
                    self._chunks.clear()
                    self._queued = 0
                    self._cond.notify_all()
                return
            with self._cond:
                self._queued -= len(batch)
                self._cond.notify_all()
