"""CAN wheel-speed decoding: frames -> rear-wheel distance increments (SPEC sections 2, 6).

``WheelSpeedDecoder`` is pure: it takes python-can ``Message`` objects (live, simulated or read
from a log) and returns ``WheelOdometry`` increments, integrating the wheel speeds over the time
between frames (trapezoid rule). Bad frames are counted by reason and never raise. cantools is
used here and nowhere else (HOUSE_STYLE: wrap a library at one place). The live driver
(``drivers.can_odometry.CanOdometry``) and the log replay (``replay_log`` there, and
``guidance replay``) feed it.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import can

from drivers._reader import rejection_counters
from drivers.profiles import CHECKSUMS, VehicleProfile, WheelSignals, get_profile, load_dbc
from guidance.core.messages import WheelOdometry

log = logging.getLogger(__name__)

# Sanity limits, unit-named (openpilot locationd style).
MAX_SPEED_MPS = 90.0
"""Above this (324 km/h) a wheel speed is garbage, e.g. GM's 0xFFFF 'invalid' = 2038 km/h."""
MAX_ACCEL_MPS2 = 20.0
"""About 2 g: a wheel speed changing faster than this between frames is a spike."""
SPIKE_MARGIN_MPS = 3.0
"""Allowed step on top of MAX_ACCEL_MPS2 * dt: ABS modules report 0 below a few km/h and then
jump (the Civic 8th-generation log goes from 0 to 7.2 km/h in one 20 ms frame)."""
MAX_CONSECUTIVE_SPIKES = 3
"""After this many spikes in a row the new level is believed (re-anchored, not integrated)."""
MAX_GAP_S = 1.0
"""No integration across a silence longer than this: the speed in between is unknown.

Shorter gaps are bridged with the trapezoid rule (exact at constant acceleration); lossy
loggers drop 0.5-0.7 s at a time (RAV4 log), which must not lose the distance driven."""
FALLBACK_MIN_MPS = 0.5
"""Front wheels are used only when they move at least this fast while both rears read 0."""

REJECT_REASONS = (
    "dlc",
    "checksum",
    "decode",
    "fault",
    "implausible",
    "non_monotonic",
    "gap",
    "spike",
)


@dataclass(frozen=True, slots=True)
class _Axle:
    """Speeds of one axle (m/s, signed) and the frame time they came with."""

    left: float = 0.0
    right: float = 0.0
    t: float | None = None


class WheelSpeedDecoder:
    """Decode wheel-speed frames of one vehicle profile and integrate them into distances.

    ``feed`` returns a ``WheelOdometry`` for every rear wheel-speed frame that closes a valid
    interval; ``None`` for anything else (other ids, the first frame, rejected frames). The
    output time is the frame's timestamp (the live driver maps wall-clock stamps onto the
    monotonic clock before feeding: ``drivers.clock.ClockMapper``).
    """

    def __init__(
        self,
        profile: VehicleProfile | str,
        *,
        max_gap_s: float = MAX_GAP_S,
        max_speed_mps: float = MAX_SPEED_MPS,
        max_accel_mps2: float = MAX_ACCEL_MPS2,
    ) -> None:
        self.profile = get_profile(profile) if isinstance(profile, str) else profile
        self.max_gap_s = max_gap_s
        self.max_speed_mps = max_speed_mps
        self.max_accel_mps2 = max_accel_mps2
        db = load_dbc(self.profile.dbc_file)
        p = self.profile
        self._rear_msg = db.get_message_by_frame_id(p.rear.frame_id)
        self._front_msg = db.get_message_by_frame_id(p.front.frame_id)
        self._shared = p.rear.frame_id == p.front.frame_id
        self._checksum = CHECKSUMS[p.checksum] if p.checksum else None
        self._scale = p.unit_to_mps * p.speed_scale
        self._prev_t: float | None = None
        self._prev_used: tuple[float, float] = (0.0, 0.0)
        self._front_latest = _Axle()
        self._spikes_in_row = 0

        self.frames = 0
        self.ignored = 0
        self.decoded = 0
        self.emitted = 0
        self.front_fallback = 0
        self.fallback_active = False
        self.rejected_by_reason: Counter[str] = Counter()
        self.left_m = 0.0
        self.right_m = 0.0
        self.distance_m = 0.0
        """Path length: sum of |mean of the two wheels| over the increments."""
        self.integrated_s = 0.0
        self.gap_s = 0.0
        self.max_speed_seen_mps = 0.0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.last_outcome = "none"
        """What the last ``feed`` did: "ignored" (not a wheel-speed frame), "ok" (decoded and
        usable: integrated or an anchor), or the reason it was rejected."""

    # -- counters ------------------------------------------------------------------------------

    @property
    def rejected(self) -> int:
        return sum(self.rejected_by_reason.values())

    @property
    def duration_s(self) -> float:
        if self.t_first is None or self.t_last is None:
            return 0.0
        return self.t_last - self.t_first

    def stats(self) -> dict[str, int]:
        out = {
            "frames": self.frames,
            "ignored": self.ignored,
            "decoded": self.decoded,
            "emitted": self.emitted,
            "rejected": self.rejected,
            "front_fallback": self.front_fallback,
        }
        out.update(rejection_counters(self.rejected_by_reason, REJECT_REASONS))
        return out

    def _reject(self, reason: str) -> None:
        self.rejected_by_reason[reason] += 1
        self.last_outcome = reason

    # -- decoding ------------------------------------------------------------------------------

    def feed(self, msg: can.Message) -> WheelOdometry | None:
        """Take one frame; return a distance increment when it closes a valid interval."""
        self.frames += 1
        self.last_outcome = "ok"
        t = float(msg.timestamp)
        if math.isfinite(t):
            self.t_first = t if self.t_first is None else min(self.t_first, t)
            self.t_last = t if self.t_last is None else max(self.t_last, t)
        fid = msg.arbitration_id
        p = self.profile
        if (
            msg.is_error_frame
            or msg.is_remote_frame
            or msg.is_extended_id
            or (fid != p.rear.frame_id and fid != p.front.frame_id)
        ):
            self.ignored += 1
            self.last_outcome = "ignored"
            return None
        is_rear = fid == p.rear.frame_id
        spec = self._rear_msg if is_rear else self._front_msg
        data = bytes(msg.data)
        if len(data) != spec.length:
            self._reject("dlc")
            return None
        if self._checksum is not None and not self._checksum(fid, data):
            self._reject("checksum")
            return None
        try:
            values = spec.decode(data, decode_choices=False)
        except Exception:  # cantools raises several types on odd payloads; all mean "bad frame"
            self._reject("decode")
            return None
        self.decoded += 1
        if not math.isfinite(t):
            self._reject("non_monotonic")
            return None

        if not is_rear:  # a separate front message (GM): remember it for the fallback
            front = self._wheel_pair(values, p.front)
            if front is not None:
                self._front_latest = _Axle(front[0], front[1], t)
            return None

        rear = self._wheel_pair(values, p.rear)
        if rear is None:
            return None
        if self._shared:  # the fronts only matter when both rears read zero (the fallback)
            stopped = rear == (0.0, 0.0) and self.profile.allow_front_fallback
            front = self._wheel_pair(values, p.front, count=False) if stopped else None
        else:
            latest = self._front_latest
            fresh = latest.t is not None and abs(t - latest.t) <= self.max_gap_s
            front = (latest.left, latest.right) if fresh else None
        return self._integrate(t, rear, front)

    def _wheel_pair(
        self, values: Mapping[str, Any], sig: WheelSignals, count: bool = True
    ) -> tuple[float, float] | None:
        """Signed speeds (m/s) of one axle, or None (counted) when faulted or implausible."""
        try:
            left = float(values[sig.left]) * self._scale
            right = float(values[sig.right]) * self._scale
            faulted = any(
                name is not None and int(values[name]) != 0
                for name in (sig.left_fault, sig.right_fault)
            )
            for name, side in ((sig.left_direction, 0), (sig.right_direction, 1)):
                if name is None:
                    continue
                direction = int(values[name])
                faulted = faulted or direction in self.profile.fault_direction_values
                if direction in self.profile.reverse_values:
                    if side == 0:
                        left = -abs(left)
                    else:
                        right = -abs(right)
        except (KeyError, TypeError, ValueError):
            if count:
                self._reject("decode")
            return None
        if faulted:
            if count:
                self._reject("fault")
            return None
        if not (
            math.isfinite(left)
            and math.isfinite(right)
            and abs(left) <= self.max_speed_mps
            and abs(right) <= self.max_speed_mps
        ):
            if count:
                self._reject("implausible")
            return None
        return left, right

    def _integrate(
        self, t: float, rear: tuple[float, float], front: tuple[float, float] | None
    ) -> WheelOdometry | None:
        """Close the interval since the last accepted rear frame (trapezoid rule).

        The interval starts from the speeds used last time (rear or front), so switching to or
        from the front-wheel fallback keeps the car's speed continuous.
        """
        use_front = (
            front is not None
            and self.profile.allow_front_fallback
            and rear[0] == 0.0
            and rear[1] == 0.0
            and 0.5 * (abs(front[0]) + abs(front[1])) >= FALLBACK_MIN_MPS
        )
        now = front if use_front and front is not None else rear
        prev_t = self._prev_t
        if prev_t is None:  # first frame: an anchor, nothing to integrate yet
            self._anchor(t, now)
            return None
        dt = t - prev_t
        if dt <= 0.0:
            self._reject("non_monotonic")
            if -dt > self.max_gap_s:  # the clock stepped back: start again from here
                self._anchor(t, now)
            return None
        if dt > self.max_gap_s:
            self._reject("gap")
            self.gap_s += dt
            self._anchor(t, now)
            return None
        prev = self._prev_used
        allowed = self.max_accel_mps2 * dt + SPIKE_MARGIN_MPS
        if abs(now[0] - prev[0]) > allowed or abs(now[1] - prev[1]) > allowed:
            self._reject("spike")
            self._spikes_in_row += 1
            if self._spikes_in_row > MAX_CONSECUTIVE_SPIKES:
                self._anchor(t, now)  # a real change after all: believe it from now on
            return None

        d_left = 0.5 * (prev[0] + now[0]) * dt
        d_right = 0.5 * (prev[1] + now[1]) * dt
        self._set_fallback(use_front, t)
        self._anchor(t, now)
        self.emitted += 1
        self.left_m += d_left
        self.right_m += d_right
        self.distance_m += abs(0.5 * (d_left + d_right))
        self.integrated_s += dt
        self.max_speed_seen_mps = max(self.max_speed_seen_mps, abs(0.5 * (now[0] + now[1])))
        return WheelOdometry(t_s=t, d_left_m=d_left, d_right_m=d_right)

    def _anchor(self, t: float, used: tuple[float, float]) -> None:
        self._spikes_in_row = 0
        self._prev_t = t
        self._prev_used = used

    def _set_fallback(self, active: bool, t: float) -> None:
        if active:
            self.front_fallback += 1
        if active != self.fallback_active:
            self.fallback_active = active
            if active:
                log.warning(
                    "rear wheel speeds read 0 while the fronts move (t=%.3f): using the front "
                    "wheels for odometry",
                    t,
                )
            else:
                log.warning("front-wheel fallback ended (t=%.3f): using the rear wheels", t)
