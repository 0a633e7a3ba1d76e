"""Device timestamps mapped onto the process's monotonic clock (issue 14, item 1).

A CAN adapter stamps frames with the wall clock (SocketCAN's kernel time), which NTP or
timesyncd may step at any moment; the app runs on ``time.monotonic()``. The mapping is
``t = device_t + offset``. A frame is received after it was stamped, so the receive lag
``recv_mono - (device_t + offset)`` has a floor (the adapter's latency, a few ms) and only
grows from there. The offset follows that floor:

* a frame *ahead* of its receive time: placed at its receive time (never in the future);
  ``CONFIRM_AHEAD`` such frames in a row mean the device clock stepped forward: re-anchor
  (one or two frames stamped an hour ahead by an adapter glitch move nothing);
* the smallest lag of the last ``window`` frames above ``tolerance_s``: the device clock
  stepped back (or drifted): re-anchor by that much, within ``window`` frames (a fraction of a
  second at CAN rates), never frozen, however small the step.

Each re-anchoring is counted and reported as a clock step with its size. Pure: the caller
passes both times.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

TOLERANCE_S = 0.05
"""Lag changes below this are latency jitter, not a clock step."""
CONFIRM_AHEAD = 3
"""Frames in a row stamped in the future before the device clock is taken to have stepped."""
WINDOW = 20
"""Frames over which the lag floor is measured (0.25 s of an 80 Hz wheel-speed message)."""


@dataclass(frozen=True, slots=True)
class ClockStep:
    """The device clock moved against the monotonic clock by ``step_s`` (+: forward)."""

    recv_s: float
    step_s: float


class ClockMapper:
    """Maps device (wall-clock) timestamps onto the monotonic clock; see the module doc."""

    def __init__(self, tolerance_s: float = TOLERANCE_S, window: int = WINDOW) -> None:
        self.tolerance_s = tolerance_s
        self.offset_s: float | None = None
        self._lags: deque[float] = deque(maxlen=window)
        self._ahead = 0
        self.clamped = 0
        """Frames stamped in the future that were placed at their receive time instead."""
        self.steps: list[ClockStep] = []

    def map(self, recv_mono_s: float, device_s: float) -> tuple[float, ClockStep | None]:
        """The monotonic time of a frame stamped ``device_s`` and received at ``recv_mono_s``,
        and the clock step this frame revealed (None when there was none)."""
        if self.offset_s is None:
            self.offset_s = recv_mono_s - device_s
            return recv_mono_s, None
        step = None
        mapped = device_s + self.offset_s
        if mapped > recv_mono_s + self.tolerance_s:  # stamped in the future
            self._ahead += 1
            if self._ahead < CONFIRM_AHEAD:  # one glitching frame must not move the clock
                self.clamped += 1
                return recv_mono_s, None
            step = self._reanchor(recv_mono_s, mapped - recv_mono_s, recv_mono_s - device_s)
            mapped = recv_mono_s
        self._ahead = 0
        self._lags.append(recv_mono_s - mapped)
        floor = min(self._lags)
        if len(self._lags) == self._lags.maxlen and floor > self.tolerance_s:
            # every recent frame arrived late by at least this much: the clock went back
            step = self._reanchor(recv_mono_s, -floor, self.offset_s + floor)
            mapped += floor
        return mapped, step

    def _reanchor(self, recv_s: float, step_s: float, offset_s: float) -> ClockStep:
        self.offset_s = offset_s
        self._lags.clear()
        step = ClockStep(recv_s, step_s)
        self.steps.append(step)
        return step
