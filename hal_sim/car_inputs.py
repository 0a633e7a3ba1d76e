"""The world's events as the car's inputs, written once (issue 37, item 4; docs/layout.md
"Simulated car").

``DeviceWire`` is what the simulated devices put on their wires for one step of the world:
the wheel speeds as CAN frames encoded with the car's DBC (``SimCanWheels.encode``), a gyro
car's yaw rate as its stability control's frame (``yaw_frames``: the profile's yaw-rate signal,
``VehicleProfile.yaw_rate``, in whole steps of the DBC's scale, as ``drivers.can_yaw``
decodes it), the compass heading as an NMEA ``HDG`` sentence (magnetic degrees, with the
drive's declination; garbage in a ``compass_garbage`` window), nothing from CAN in a
``can_silent`` window.
``SimDrive`` sends these on python-can's virtual bus and a pseudo-terminal, where the car's
drivers read them (``CanOdometry``, ``SerialCompass``).

``CarInputs`` is the same wire decoded in-process by the same drivers' pure decoders
(``drivers.can_decode.WheelSpeedDecoder``: the trapezoid rule, the gap bridged up to
``MAX_GAP_S`` and not beyond; ``drivers.can_yaw.YawRateDecoder``, a gyro car's, as
``guidance run``'s CAN driver has it; ``drivers.compass.NmeaCompassParser``), for drives that
feed the pipeline directly (``hal_sim.guided``, ``hal_sim.population``): the inputs the car would
have had, without a bus, a pty or threads.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import can

from drivers.can_decode import WheelSpeedDecoder
from drivers.can_yaw import UNIT_TO_RAD_S, YawRateDecoder
from drivers.compass import NmeaCompassParser
from drivers.profiles import load_dbc
from guidance.core.messages import CompassHeading, WheelOdometry, YawRate
from guidance.core.model import heading_to_compass
from hal_sim.sim_can import SimCanWheels, physical_range
from hal_sim.sim_compass import hdg_body, nmea_sentence

COMPASS_GARBAGE = b"$HCHDG,12x.4,,,,*7Z\r\n"
"""What the compass sends in a ``compass_garbage`` window: a line the parser rejects."""


def in_window(window: tuple[float, float] | None, t: float) -> bool:
    """``t`` within a fault window (start, duration)."""
    return window is not None and window[0] <= t < window[0] + window[1]


class DeviceWire:
    """The simulated devices' side: the bytes the wheels' ECU and the compass send."""

    def __init__(
        self,
        declination_deg: float,
        *,
        profile: str = "gm_global_a",
        can_silent: tuple[float, float] | None = None,
        compass_garbage: tuple[float, float] | None = None,
        wheels: SimCanWheels | None = None,
    ) -> None:
        self.declination_deg = declination_deg
        self.wheels = wheels if wheels is not None else SimCanWheels(profile=profile)
        self.can_silent = can_silent
        self.compass_garbage = compass_garbage
        self._yaw: tuple[Any, str, str | None, float, tuple[float, float]] | None = None

    def can_frames(self, t_s: float, left_mps: float, right_mps: float) -> list[can.Message]:
        """The wheel-speed frames sent at ``t_s`` (stamped), none while CAN is silent."""
        if in_window(self.can_silent, t_s):
            return []
        self.wheels.set_speeds(left_mps, right_mps)
        frames = self.wheels.encode()
        for msg in frames:
            msg.timestamp = t_s
        return frames

    def yaw_frames(self, t_s: float, rate_rad_s: float) -> list[can.Message]:
        """The stability control's yaw-rate frame for a reading of ``rate_rad_s`` at ``t_s``
        (stamped), none while CAN is silent: the profile's signal in its unit, within what its
        bits carry, encoded by the DBC (cantools rounds to the scale's nearest whole step:
        the DBC's quantisation); the message's other signals zero. A profile without a
        yaw-rate signal is refused (``UserError``, as ``drivers.can_yaw`` refuses it)."""
        if in_window(self.can_silent, t_s):
            return []
        spec, name, sign, per_rad, (lo, hi) = self._yaw_encoding()
        values = {s.name: 0.0 for s in spec.signals}
        value = rate_rad_s * per_rad
        if sign is not None:  # a magnitude and its sign bit (Volkswagen's)
            values[sign], value = float(value < 0.0), abs(value)
        values[name] = min(max(value, lo), hi)
        msg = can.Message(arbitration_id=spec.frame_id, data=spec.encode(values, strict=False),
                          is_extended_id=False, timestamp=t_s)  # fmt: skip
        return [msg]

    def _yaw_encoding(self) -> tuple[Any, str, str | None, float, tuple[float, float]]:
        """(the DBC message, the signal's name, its sign bit's, its units per rad/s, its
        physical range)."""
        if self._yaw is None:
            p = self.wheels.profile
            YawRateDecoder(p.name)  # the car's own refusal of a profile without the signal
            assert p.yaw_rate is not None
            spec = load_dbc(p.dbc_file).get_message_by_frame_id(p.yaw_rate.frame_id)
            signal = spec.get_signal_by_name(p.yaw_rate.signal)
            unit = 1.0 / UNIT_TO_RAD_S[p.yaw_rate.unit]
            self._yaw = (spec, p.yaw_rate.signal, p.yaw_rate.sign, unit, physical_range(signal))
        return self._yaw

    def compass_line(self, t_s: float, heading_rad: float) -> tuple[bytes, bool]:
        """The compass's line for a reading of ``heading_rad`` (filter frame) at ``t_s``, and
        whether it is a heading (False: garbage)."""
        if in_window(self.compass_garbage, t_s):
            return COMPASS_GARBAGE, False
        deg = float(heading_to_compass(heading_rad, self.declination_deg))
        return nmea_sentence(hdg_body(deg)), True


class CarInputs:
    """The device wire decoded by the car's own drivers' decoders, in-process."""

    def __init__(self, wire: DeviceWire, *, yaw_rate: bool = False) -> None:
        self.wire = wire
        self.odometry = WheelSpeedDecoder(wire.wheels.profile)
        self.compass = NmeaCompassParser()
        self.yaw = YawRateDecoder(wire.wheels.profile.name) if yaw_rate else None
        """A gyro car's decoder (``[vehicle] yaw_source`` "gyro" or "both")."""

    def wheels(self, t_s: float, left_mps: float, right_mps: float) -> Iterator[WheelOdometry]:
        """The odometry increments the car's decoder makes of this step's frames."""
        for msg in self.wire.can_frames(t_s, left_mps, right_mps):
            out = self.odometry.feed(msg)
            if out is not None:
                yield out

    def yaw_rate(self, t_s: float, rate_rad_s: float) -> Iterator[YawRate]:
        """The yaw rates the car's decoder makes of this step's yaw-rate frame (a gyro car's:
        ``yaw_rate=True``)."""
        if self.yaw is None:
            raise ValueError("CarInputs(yaw_rate=False) decodes no yaw rate")
        for msg in self.wire.yaw_frames(t_s, rate_rad_s):
            out = self.yaw.feed(msg)
            if out is not None:
                yield out

    def heading(self, t_s: float, heading_rad: float) -> CompassHeading | None:
        """The compass reading the car's NMEA parser makes of this step's line (None: the
        line was rejected)."""
        line, _ = self.wire.compass_line(t_s, heading_rad)
        return self.compass.feed_line(line, t_s)
