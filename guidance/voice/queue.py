"""The prompt queue: bounded, priority tiers, de-duplication, staleness on the
message clock (SPEC section 6, docs/voice.md).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

from guidance.core.messages import Priority

Clock = Callable[[], float]
"""Returns the current time on the message clock (monotonic seconds)."""


DEFAULT_MAX_AGE_S: Mapping[Priority, float] = {
    Priority.SAFETY: 15.0,  # a warning or "lost" is still true a while later
    Priority.GUIDANCE: 5.0,  # 70 m at 50 km/h: a turn prompt older than this misleads
    Priority.INFO: 10.0,
}
"""How old (message-clock seconds since ``t_s``) a prompt may be when it starts."""

DEFAULT_QUEUE_SIZE = 8
DEFAULT_RATE_WPM = 170
"""Speech rate: a little slower than espeak-ng's 175 wpm, for a driver in traffic."""


# --------------------------------------------------------------------------- queue


@dataclass(frozen=True, slots=True)
class QueuedPrompt:
    """One pending prompt. ``seq`` is the arrival order (FIFO within a tier)."""

    text: str
    priority: Priority
    t_s: float
    max_age_s: float
    seq: int

    @property
    def deadline_s(self) -> float:
        """The last message-clock time at which speaking it may start."""
        return self.t_s + self.max_age_s

    def is_stale(self, now_s: float) -> bool:
        return now_s > self.deadline_s


QUEUE_COUNTERS = (
    "queued",
    "popped",
    "deduplicated",
    "dropped_stale",
    "dropped_overflow",
    "discarded",
)


class PromptQueue:
    """Bounded, thread-safe priority FIFO of driver prompts.

    * Order: highest ``Priority`` first, then arrival order.
    * De-duplication: a prompt whose text is already pending refreshes that
      entry (higher priority, later deadline) and keeps its place.
    * Staleness: a prompt that would start after ``t_s + max_age_s`` is dropped
      (on ``put`` and when popped), measured on ``clock``: the message clock.
    * Full: the lowest-priority, oldest prompt is dropped, possibly the new one.

    Every drop is counted in ``stats()``. ``now_s`` arguments override the
    clock (the WAV recorder runs on a virtual speaking clock).
    """

    def __init__(
        self,
        maxsize: int = DEFAULT_QUEUE_SIZE,
        clock: Clock = time.monotonic,
        max_age_s: Mapping[Priority, float] | None = None,
    ) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be at least 1, got {maxsize}")
        self.maxsize = maxsize
        self._clock = clock
        self._max_age_s = dict(DEFAULT_MAX_AGE_S if max_age_s is None else max_age_s)
        self._cond = threading.Condition()
        self._items: list[QueuedPrompt] = []
        self._seq = 0
        self._closed = False
        self._counts = dict.fromkeys(QUEUE_COUNTERS, 0)

    def put(
        self,
        text: str,
        priority: int = Priority.GUIDANCE,
        t_s: float | None = None,
        max_age_s: float | None = None,
        *,
        now_s: float | None = None,
    ) -> bool:
        """Queue a prompt; False when it was dropped (stale, overflow, empty, closed)."""
        text = " ".join(text.split())
        tier = Priority.of(priority)
        with self._cond:
            now = self._clock() if now_s is None else now_s
            t = now if t_s is None else t_s
            age = (
                self._max_age_s.get(tier, DEFAULT_MAX_AGE_S[tier])
                if max_age_s is None
                else max_age_s
            )
            if not (math.isfinite(t) and math.isfinite(age) and age >= 0):
                raise ValueError(
                    f"prompt time and age must be finite, age >= 0: t_s={t}, max_age_s={age}"
                )
            if not text:
                return False
            if self._closed:
                self._counts["discarded"] += 1
                return False
            self._drop_stale(now)
            new = QueuedPrompt(text, tier, t, age, self._seq)
            self._seq += 1
            if new.is_stale(now):
                self._counts["dropped_stale"] += 1
                return False
            for i, old in enumerate(self._items):
                if old.text == text:
                    later = new if new.deadline_s > old.deadline_s else old
                    self._items[i] = replace(
                        old,
                        priority=max(old.priority, tier),
                        t_s=later.t_s,
                        max_age_s=later.max_age_s,
                    )
                    self._counts["deduplicated"] += 1
                    self._cond.notify()
                    return True
            self._items.append(new)
            if len(self._items) > self.maxsize:
                victim = min(self._items, key=lambda p: (p.priority, p.seq))
                self._items.remove(victim)
                self._counts["dropped_overflow"] += 1
                if victim is new:
                    return False
            self._counts["queued"] += 1
            self._cond.notify()
            return True

    def pop(self, now_s: float | None = None) -> QueuedPrompt | None:
        """The next prompt to speak now, or None; stale prompts are dropped first."""
        with self._cond:
            return self._pop_locked(self._clock() if now_s is None else now_s)

    def get(self, timeout_s: float | None = None) -> QueuedPrompt | None:
        """Block (wall-clock ``timeout_s``) until a fresh prompt is ready; None once closed."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while True:
                prompt = self._pop_locked(self._clock())
                if prompt is not None or self._closed:
                    return prompt
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)

    def take_all(self) -> list[QueuedPrompt]:
        """Remove and return every pending prompt in speaking order (for a failover)."""
        with self._cond:
            items = sorted(self._items, key=lambda p: (-p.priority, p.seq))
            self._items.clear()
            return items

    def clear(self) -> int:
        """Discard every pending prompt; returns how many (counted as discarded)."""
        with self._cond:
            n = len(self._items)
            self._items.clear()
            self._counts["discarded"] += n
            return n

    def close(self) -> None:
        """Refuse new prompts and wake ``get``; pending prompts can still be popped."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

    def stats(self) -> dict[str, int]:
        with self._cond:
            return dict(self._counts)

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def _drop_stale(self, now_s: float) -> None:
        fresh = [p for p in self._items if not p.is_stale(now_s)]
        self._counts["dropped_stale"] += len(self._items) - len(fresh)
        self._items[:] = fresh

    def _pop_locked(self, now_s: float) -> QueuedPrompt | None:
        self._drop_stale(now_s)
        if not self._items:
            return None
        best = max(self._items, key=lambda p: (p.priority, -p.seq))
        self._items.remove(best)
        self._counts["popped"] += 1
        return best
