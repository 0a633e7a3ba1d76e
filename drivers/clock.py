"""Device timestamps mapped onto the process's monotonic clock (issue 14, item 1; issue 23, 10).

A CAN adapter stamps frames with the wall clock (SocketCAN's kernel time), which NTP or
timesyncd may step at any moment; the app runs on ``time.monotonic()``. The mapping is
``t = device_t + offset``. A frame is received after it was stamped, so the receive lag
``recv_mono - (device_t + offset)`` has a floor (the adapter's latency, a few ms) and only
grows from there.

Two things make the lag grow, and they look alike frame by frame: the device clock stepped
back, or the reader fell behind (a CAN flood, the GIL held elsewhere: frames queued for tens of
ms, then read in a burst). They differ in the device stamps. Frames are stamped in the order
they are received (the kernel, the adapter, the virtual bus), so reader lag never makes a
stamp go back: the stamps of a late burst carry on from the last one, and the lag goes away
once the reader has caught up. A clock stepped back makes the stamps jump back, and the lag
stays. So:

* a frame *ahead* of its receive time is placed at its receive time (never in the future, so
  the times handed on never go back either); more than ``tolerance_s`` ahead, ``CONFIRM`` such
  frames in a row re-anchor. It is a clock step (counted, reported) when the
  stamps jumped ahead of the receive time elapsed since the last frame; otherwise the anchor
  came from a frame that was itself late (the reader was behind when it was taken), and moving
  it is a silent ``corrections`` (one or two frames stamped an hour ahead move nothing);
* a late frame whose stamp is earlier than the last frame's (by more than ``REORDER_S``): the
  device clock stepped back, confirmed by ``CONFIRM`` late frames in a row (one glitching
  frame moves nothing): re-anchor by the smallest lag among them, within a few frames;
* late frames whose stamps carry on: reader lag, left alone (the frames keep their stamps'
  spacing: no distance is made or lost) unless the lag stays flat (within half the tolerance)
  for ``PERSIST_S`` of receive time and ``WINDOW`` frames: a step back during a silence, or a
  drift: re-anchor by the lag floor. A reader that cannot keep up is late by a lag that moves
  (it falls behind and catches up, by tens of ms at a time), never flat for a second.

Each re-anchoring that is a step is counted and reported with its size. Pure: the caller
passes both times.
"""

from __future__ import annotations

from dataclasses import dataclass

TOLERANCE_S = 0.05
"""Lag changes below this are latency jitter, not a clock step."""
CONFIRM = 3
"""Frames in a row that must agree before a clock step is believed (ahead, or stamped back)."""
CONFIRM_AHEAD = CONFIRM
"""The name the tests of issue 14 use."""
REORDER_S = 0.01
"""Stamps may go back this much without a clock step (frames of several senders interleaved on
a virtual bus); stamps in order of reception never go back at all."""
WINDOW = 20
"""At least this many late frames in a row before a lasting lag re-anchors."""
PERSIST_S = 1.0
"""A lag without a stamp going back must last this long (receive time), flat, to be a step or
drift. Reader lag clears sooner (a 20,000 frames/s flood on an idle 2 cores: late runs of at
most 30 ms, lag at most 65 ms), or moves (the same flood on a loaded machine with a reader
stalled 40-100 ms every 0.3 s: 0.13-0.44 s behind for seconds, never flat)."""


@dataclass(frozen=True, slots=True)
class ClockStep:
    """The device clock moved against the monotonic clock by ``step_s`` (+: forward)."""

    recv_s: float
    step_s: float


class ClockMapper:
    """Maps device (wall-clock) timestamps onto the monotonic clock; see the module doc."""

    def __init__(
        self,
        tolerance_s: float = TOLERANCE_S,
        window: int = WINDOW,
        persist_s: float = PERSIST_S,
    ) -> None:
        self.tolerance_s = tolerance_s
        self.window = window
        self.persist_s = persist_s
        self.offset_s: float | None = None
        self._last: tuple[float, float] = (0.0, 0.0)
        """(receive, device) times of the last frame taken in line with the anchor."""
        self._ahead = 0
        self._ahead_jumped = False
        self._back: list[float] = []
        """Lags of the late frames since a stamp went back (a step back being confirmed)."""
        self._late_since: float | None = None
        self._late_n = 0
        self._late_min = self._late_max = 0.0
        self.clamped = 0
        """Frames stamped in the future that were placed at their receive time instead."""
        self.corrections = 0
        """Re-anchorings that were no clock step: the anchor was taken from a late frame."""
        self.steps: list[ClockStep] = []

    def map(self, recv_mono_s: float, device_s: float) -> tuple[float, ClockStep | None]:
        """The monotonic time of a frame stamped ``device_s`` and received at ``recv_mono_s``,
        and the clock step this frame revealed (None when there was none)."""
        if self.offset_s is None:
            self.offset_s = recv_mono_s - device_s
            self._last = (recv_mono_s, device_s)
            return recv_mono_s, None
        tol = self.tolerance_s
        last_recv, last_device = self._last
        mapped = device_s + self.offset_s
        lag = recv_mono_s - mapped
        if lag < -tol:  # stamped in the future
            if self._ahead == 0:  # did the stamps jump, or was the anchor late?
                self._ahead_jumped = device_s - last_device > recv_mono_s - last_recv + tol
            self._ahead += 1
            if self._ahead < CONFIRM:  # one glitching frame must not move the clock
                self.clamped += 1
                return recv_mono_s, None
            step = self._reanchor(recv_mono_s, -lag, recv_mono_s - device_s, self._ahead_jumped)
            self._last = (recv_mono_s, device_s)
            return recv_mono_s, step
        self._ahead = 0
        step = None
        if lag <= tol:  # on time
            self._back.clear()
            self._late_since = None
        else:
            if self._back or device_s < last_device - REORDER_S:  # the stamps went back
                self._back.append(lag)
                if len(self._back) >= CONFIRM:
                    floor = min(self._back)
                    step = self._reanchor(recv_mono_s, -floor, self.offset_s + floor, True)
            if step is None:
                step = self._lasting_lag(recv_mono_s, lag)
            if step is not None:
                mapped += -step.step_s
        if not self._back:  # a frame stamped back, not confirmed yet, is no reference
            self._last = (recv_mono_s, device_s)
        return min(mapped, recv_mono_s), step  # never in the future, even within tolerance

    def _lasting_lag(self, recv_s: float, lag: float) -> ClockStep | None:
        """A late frame whose stamp carries on: reader lag, unless the lag lasts, and lasts
        flat (see the module)."""
        if (
            self._late_since is None
            or max(self._late_max, lag) - min(self._late_min, lag) > self.tolerance_s / 2
        ):  # a new run: the lag moved by more than jitter (a reader catching up, or not)
            self._late_since, self._late_n = recv_s, 0
            self._late_min = self._late_max = lag
        self._late_n += 1
        self._late_min = min(self._late_min, lag)
        self._late_max = max(self._late_max, lag)
        if self._late_n < self.window or recv_s - self._late_since < self.persist_s:
            return None
        assert self.offset_s is not None
        floor = self._late_min
        return self._reanchor(recv_s, -floor, self.offset_s + floor, True)

    def _reanchor(
        self, recv_s: float, step_s: float, offset_s: float, is_step: bool
    ) -> ClockStep | None:
        self.offset_s = offset_s
        self._ahead = 0
        self._back.clear()
        self._late_since = None
        if not is_step:
            self.corrections += 1
            return None
        step = ClockStep(recv_s, step_s)
        self.steps.append(step)
        return step
