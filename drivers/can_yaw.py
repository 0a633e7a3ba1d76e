"""The stability control's yaw rate from CAN frames (issue 38): the signal the vehicle profile
names (``VehicleProfile.yaw_rate``, from opendbc), decoded with the profile's DBC into the
estimator's ``YawRate`` (rad/s, counter-clockwise positive).

The sign: the profiles' signals read counter-clockwise (left turn) positive as opendbc
documents them (Volkswagen's magnitude with its sign bit, ``YawRateSignal.sign``, as openpilot
reads it); checked on the shared Toyota RAV4 log, whose ``KINEMATICS.YAW_RATE``
follows the truth's yaw rate (correlation +0.85 over 1 s means on a straight drive). Frames
that do not decode, or whose rate is beyond ``MAX_RATE_RAD_S``, are counted and dropped.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import can

from drivers.profiles import get_profile, load_dbc
from guidance.core.messages import YawRate
from guidance.errors import UserError

UNIT_TO_RAD_S = {"deg/s": math.pi / 180.0, "rad/s": 1.0}
MAX_RATE_RAD_S = 5.0
"""About 290 deg/s, beyond the measuring range of ESC yaw-rate sensors (100-300 deg/s): a
damaged frame (the estimator refuses the same, ``guidance.core.localize.gyro``)."""


class YawRateDecoder:
    """CAN frames in, ``YawRate`` out for the profile's yaw-rate frame; everything else
    ignored."""

    def __init__(self, profile: str) -> None:
        p = get_profile(profile)
        if p.yaw_rate is None:
            raise UserError(f"vehicle profile {profile!r} names no yaw-rate signal: "
                            '[vehicle] yaw_source = "gyro" needs one')  # fmt: skip
        self.signal = p.yaw_rate
        if self.signal.unit not in UNIT_TO_RAD_S:
            raise UserError(f"yaw-rate unit {self.signal.unit!r} of profile {profile!r}")
        self._to_rad = UNIT_TO_RAD_S[self.signal.unit]
        self._message: Any = load_dbc(p.dbc_file).get_message_by_frame_id(self.signal.frame_id)
        self.rejected: Counter[str] = Counter()
        self.frames = 0
        """Frames of the yaw-rate id read (decoded or refused): the gyro's health counts."""

    def feed(self, msg: can.Message) -> YawRate | None:
        if msg.arbitration_id != self.signal.frame_id or msg.is_extended_id:
            return None
        self.frames += 1
        if msg.is_error_frame or msg.is_remote_frame or len(msg.data) != self._message.length:
            self.rejected["dlc"] += 1
            return None
        try:
            value = self._message.decode(bytes(msg.data), decode_choices=False)
            rate = float(value[self.signal.signal]) * self._to_rad
            if self.signal.sign is not None and int(value[self.signal.sign]):
                rate = -rate
        except Exception:  # cantools raises several types on odd payloads
            self.rejected["decode"] += 1
            return None
        t = float(msg.timestamp)
        if not (math.isfinite(rate) and math.isfinite(t)) or abs(rate) > MAX_RATE_RAD_S:
            self.rejected["implausible"] += 1
            return None
        return YawRate(t, rate)
