"""The simulator's lockstep: the world waits until the app has processed what it was sent, and
the app's time-driven work runs at the world's steps.

``LockstepSink`` wraps ``App.sink``; the simulated drive starts the sources with it
(``app.wrap_source_sink(LockstepSink)``, the hook ``App`` offers). It counts what it hands over
and, behind each message on the loop, what has been processed, and wakes its waiters then:
``wait_until`` re-checks its predicate right after the app's state changed, and ``drained``
returns once everything handed over so far is processed. ``LockstepClock`` is the world's clock
as the app's message clock, a ``guidance.app.ports.SteppedClock``: the app hands it
``App.tick``, and the drive runs that after each world step (``tick``), not the wall-clock
ticker. A drive is then reproducible for a seed however fast the machine is. ``App`` itself
knows nothing of the simulation (it keeps only its backlog figure, the drivers' back-pressure,
and asks a clock whether it is stepped).
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from guidance.app.app import App, Message
    from guidance.core.messages import CameraFrame

POLL_S = 0.05
"""A predicate on something other than the app's messages (a pty opened) is polled this often."""


async def recognise_now(app: App, frame: CameraFrame) -> None:
    """A frame of the simulated camera, seen now and matched at once (in lockstep), not through
    the app's frame ring: the camera noted alive as the ring's reader notes it, then
    ``App.recognise``; the frame is not recorded."""
    app.pipeline.camera_seen(frame.t_s)
    await app.recognise(frame)


class LockstepClock:
    """The simulated world's time (``now``) as the app's message clock, stepped by the drive: a
    ``SteppedClock``, so the app's ticker leaves the time-driven work to ``tick``."""

    def __init__(self, now: Callable[[], float]) -> None:
        self._now = now
        self._tick: Callable[[float], object] | None = None

    def __call__(self) -> float:
        return self._now()

    def set_tick(self, tick: Callable[[float], object] | None) -> None:
        self._tick = tick

    def tick(self) -> bool:
        """The app's time-driven work at the world's time now (after a step); False when no app
        is running on this clock."""
        if self._tick is None:
            return False
        self._tick(self._now())
        return True


class LockstepSink:
    """A sink around ``sink`` (the app's) that counts submitted and processed messages."""

    def __init__(self, sink: Callable[[Message], None]) -> None:
        self._sink = sink
        self._loop = asyncio.get_running_loop()
        self._lock = threading.Lock()
        self._waiters: list[asyncio.Future[None]] = []
        self.submitted = 0
        """Messages handed to the app (from any thread)."""
        self.processed = 0
        """Of those, the ones the loop has processed."""

    def __call__(self, msg: Message) -> None:
        """The sources' sink (any thread): the app's sink, then a mark behind the message (the
        loop runs its callbacks in order, so the mark runs once the message is processed)."""
        self._sink(msg)
        with self._lock:
            self.submitted += 1
        self._loop.call_soon_threadsafe(self._processed_one)

    def _processed_one(self) -> None:
        self.processed += 1
        waiters, self._waiters = self._waiters, []
        for fut in waiters:
            if not fut.done():
                fut.set_result(None)

    async def wait_until(self, predicate: Callable[[], bool], timeout_s: float = 2.0) -> bool:
        """Wait until ``predicate()`` holds (re-checked after each processed message); False
        after ``timeout_s``."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while not predicate():
            remaining = deadline - loop.time()
            if remaining <= 0:
                return False
            fut: asyncio.Future[None] = loop.create_future()
            self._waiters.append(fut)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(fut, min(remaining, POLL_S))
        return True

    async def drained(self, timeout_s: float = 2.0) -> bool:
        """Wait until every message handed over so far has been processed."""
        with self._lock:
            target = self.submitted
        return await self.wait_until(lambda: self.processed >= target, timeout_s)
