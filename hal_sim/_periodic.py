"""One periodic sender thread for the simulated devices (CAN wheels, compass pty)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class PeriodicThread:
    """Calls ``tick`` every ``period_s`` on absolute deadlines until ``stop``.

    A sender that fell more than one period behind (a stalled machine) resumes
    from now instead of bursting to catch up, as a real device would.
    """

    def __init__(self, name: str, period_s: float, tick: Callable[[], None]) -> None:
        self.name = name
        self.period_s = period_s
        self._tick = tick
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def _run(self) -> None:
        deadline = time.monotonic()
        while not self._stop.is_set():
            self._tick()
            deadline += self.period_s
            wait = deadline - time.monotonic()
            if wait < -self.period_s:
                deadline = time.monotonic()
            elif wait > 0 and self._stop.wait(wait):
                break
