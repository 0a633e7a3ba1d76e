"""What the car's own voice is saying, for the speech input (issue 39).

The co-driver's microphone hears the car's loudspeaker. The speech input is deaf while the car
speaks and for a tail after, and refuses a heard phrase that matches what the car just said;
both need to know what the car said and when. A live speaker reports each prompt it plays
(``started``/``finished``); the speech input asks ``busy`` and ``recent``. There is one
loudspeaker per car, so the process has one ``CAR_VOICE`` that both use by default (a test
makes its own). Times are on the wall-clock monotonic clock: the microphone's.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

RECENT_KEPT = 16


class CarVoice:
    """The car's voice: busy now (or within a tail of the end), and what it said lately."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._busy_until = -float("inf")
        self._speaking = 0
        self._said: deque[tuple[float, str]] = deque(maxlen=RECENT_KEPT)

    def started(self, text: str, duration_s: float) -> None:
        """A prompt of ``duration_s`` starts playing now."""
        now = self._clock()
        with self._lock:
            self._speaking += 1
            self._busy_until = max(self._busy_until, now + max(0.0, duration_s))
            self._said.append((now, text))

    def finished(self) -> None:
        """The prompt started last has stopped playing (at the earliest, now)."""
        now = self._clock()
        with self._lock:
            self._speaking = max(0, self._speaking - 1)
            self._busy_until = max(self._busy_until, now)

    def busy(self, tail_s: float = 0.0, at_s: float | None = None) -> bool:
        """Speaking at ``at_s`` (default now), or stopped less than ``tail_s`` before it."""
        t = self._clock() if at_s is None else at_s
        with self._lock:
            return self._speaking > 0 or t <= self._busy_until + tail_s

    def recent(self, within_s: float = 30.0) -> tuple[str, ...]:
        """What the car said over the last ``within_s`` seconds, oldest first."""
        t = self._clock()
        with self._lock:
            return tuple(text for when, text in self._said if t - when <= within_s)


CAR_VOICE = CarVoice()
"""The process's car voice: live speakers report to it, the speech input listens to it."""
