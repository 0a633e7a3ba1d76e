"""One health record per device (HOUSE_STYLE: every input has a health record).

Every driver answers ``health()`` with a ``guidance.core.messages.Health``: is data arriving
(``alive``), is what arrives usable (``valid``), a one-word ``status``, the age of the last
accepted message, its counters and the last error (``detail``, for the log and the operator).
Never a sentence for the driver: ``warning`` stays empty, and the pipeline words a bad status
once, by input (``guidance.core.speech.SENSOR_WORDS``: one event, one sentence, whoever noticed
it first). docs/reliability.md lists what each fault does to these.

``HealthTracker`` is the bookkeeping behind it, shared by the drivers: the reader thread reports
each unit of data (a wheel-speed frame, an NMEA line, a camera frame) as accepted, rejected or
neutral (someone else's NMEA sentence), connection changes and errors; ``evaluate`` turns that
into a status on the driver's clock and logs each flip once, and the recovery once.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Callable, Mapping

from guidance.core.health import BAD_STATUSES, MAX_REJECTED_FRACTION, VALIDITY_WINDOW, garbled
from guidance.core.messages import Health

log = logging.getLogger(__name__)


class HealthTracker:
    """Arrivals, outcomes and connection state of one input; thread-safe.

    Times are on ``clock`` (the driver's clock: monotonic live, simulated or frame
    time in simulation and replay).
    """

    def __init__(
        self,
        name: str,
        *,
        stale_after_s: float,
        clock: Callable[[], float],
        window: int = VALIDITY_WINDOW,
        max_rejected_fraction: float = MAX_REJECTED_FRACTION,
    ) -> None:
        if not (math.isfinite(stale_after_s) and stale_after_s > 0):
            raise ValueError(f"stale_after_s must be positive, not {stale_after_s!r}")
        self.name = name
        self.stale_after_s = stale_after_s
        self._clock = clock
        self._max_rejected = max_rejected_fraction
        self._lock = threading.Lock()
        self._outcomes: deque[bool] = deque(maxlen=window)
        self._started_t: float | None = None
        self._running = False
        self._connected = True
        self._ended = False
        self._last_data_t: float | None = None
        self._last_good_t: float | None = None
        self._last_error = ""
        self._status = "stopped"
        self.flips = 0
        """Times the status went from good (ok/starting) to bad."""
        self.on_flip: Callable[[Health], None] | None = None
        """Called (on the caller's thread, outside the lock) with the health whenever the
        status changes: the driver's status flips reach the app through its message path."""

    # -- reports from the reader thread ----------------------------------------------------------

    def started(self) -> None:
        with self._lock:
            self._running = True
            self._ended = False
            self._started_t = self._clock()
            self._status = "starting"

    def stopped(self) -> None:
        with self._lock:
            self._running = False
            self._status = "stopped"

    def ended(self) -> None:
        with self._lock:
            self._ended = True

    def connected(self, up: bool, error: str = "") -> None:
        with self._lock:
            self._connected = up
            if error:
                self._last_error = error

    def error(self, text: str) -> None:
        with self._lock:
            self._last_error = text

    def data(self, accepted: bool | None, t: float | None = None) -> None:
        """One unit of data arrived: accepted, rejected, or ``None`` (neutral: not ours)."""
        now = self._clock() if t is None else t
        with self._lock:
            self._last_data_t = now
            if accepted is None:
                return
            self._outcomes.append(accepted)
            if accepted:
                self._last_good_t = now

    # -- evaluation ----------------------------------------------------------------------------

    def evaluate(self, counters: Mapping[str, int] | None = None) -> Health:
        """The health now; logs a flip to a bad status once, and the recovery once."""
        now = self._clock()
        with self._lock:
            alive = self._fresh(self._last_data_t, now)
            rejected = sum(1 for ok in self._outcomes if not ok)
            judged = len(self._outcomes)  # the last VALIDITY_WINDOW units: the fast verdict
            mostly_good = judged > 0 and not garbled(judged, rejected, self._max_rejected)
            valid = self._fresh(self._last_good_t, now) and mostly_good
            if not self._running:
                status = "stopped"
            elif self._ended:
                status = "ended"
            elif not self._connected:
                status = "disconnected"
            elif not alive:
                overdue = self._last_data_t is not None or (
                    self._started_t is not None and now - self._started_t > self.stale_after_s
                )
                status = "silent" if overdue else "starting"
            elif not valid:
                status = "invalid" if self._last_good_t is not None or rejected else "starting"
            else:
                status = "ok"
            previous, self._status = self._status, status
            age = None if self._last_good_t is None else max(0.0, now - self._last_good_t)
            error = self._last_error
        alive = alive and status not in ("disconnected", "stopped")
        if status != previous:
            self._log_flip(previous, status, error)
        health = Health(
            name=self.name,
            status=status,
            alive=alive,
            valid=valid and alive,
            age_s=age,
            counters=dict(counters or {}),
            detail=error,
        )
        if status != previous and self.on_flip is not None:
            try:
                self.on_flip(health)
            except Exception:  # the app's hook must never break the reader
                log.exception("%s: the status hook raised; continuing", self.name)
        return health

    def _fresh(self, t: float | None, now: float) -> bool:
        return t is not None and now - t <= self.stale_after_s

    def _log_flip(self, previous: str, status: str, error: str) -> None:
        bad_before = previous in BAD_STATUSES
        bad_now = status in BAD_STATUSES
        if bad_now and not bad_before:
            self.flips += 1
        if "disconnected" in (previous, status):
            return  # the driver logs losing and finding its device itself
        if bad_now and not bad_before:
            log.warning("%s: %s%s", self.name, status, f" (last error: {error})" if error else "")
        elif bad_now:
            log.warning("%s: now %s (was %s)", self.name, status, previous)
        elif bad_before and status == "ok":
            log.warning("%s: ok again (was %s)", self.name, previous)
