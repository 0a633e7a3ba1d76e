"""The world's events as the car's inputs, written once (issue 37, item 4; docs/layout.md
"Simulated car").

``DeviceWire`` is what the simulated devices put on their wires for one step of the world:
the wheel speeds as CAN frames encoded with the car's DBC (``SimCanWheels.encode``), the
compass heading as an NMEA ``HDG`` sentence (magnetic degrees, with the drive's declination;
garbage in a ``compass_garbage`` window), nothing from CAN in a ``can_silent`` window.
``SimDrive`` sends these on python-can's virtual bus and a pseudo-terminal, where the car's
drivers read them (``CanOdometry``, ``SerialCompass``).

``CarInputs`` is the same wire decoded in-process by the same drivers' pure decoders
(``drivers.can_decode.WheelSpeedDecoder``: the trapezoid rule, the gap bridged up to
``MAX_GAP_S`` and not beyond; ``drivers.compass.NmeaCompassParser``), for drives that feed the
pipeline directly (``hal_sim.guided``, ``hal_sim.population``): the inputs the car would
have had, without a bus, a pty or threads.
"""

from __future__ import annotations

from collections.abc import Iterator

import can

from drivers.can_decode import WheelSpeedDecoder
from drivers.compass import NmeaCompassParser
from guidance.core.messages import CompassHeading, WheelOdometry
from guidance.core.model import heading_to_compass
from hal_sim.sim_can import SimCanWheels
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

    def can_frames(self, t_s: float, left_mps: float, right_mps: float) -> list[can.Message]:
        """The wheel-speed frames sent at ``t_s`` (stamped), none while CAN is silent."""
        if in_window(self.can_silent, t_s):
            return []
        self.wheels.set_speeds(left_mps, right_mps)
        frames = self.wheels.encode()
        for msg in frames:
            msg.timestamp = t_s
        return frames

    def compass_line(self, t_s: float, heading_rad: float) -> tuple[bytes, bool]:
        """The compass's line for a reading of ``heading_rad`` (filter frame) at ``t_s``, and
        whether it is a heading (False: garbage)."""
        if in_window(self.compass_garbage, t_s):
            return COMPASS_GARBAGE, False
        deg = float(heading_to_compass(heading_rad, self.declination_deg))
        return nmea_sentence(hdg_body(deg)), True


class CarInputs:
    """The device wire decoded by the car's own drivers' decoders, in-process."""

    def __init__(self, wire: DeviceWire) -> None:
        self.wire = wire
        self.odometry = WheelSpeedDecoder(wire.wheels.profile)
        self.compass = NmeaCompassParser()

    def wheels(self, t_s: float, left_mps: float, right_mps: float) -> Iterator[WheelOdometry]:
        """The odometry increments the car's decoder makes of this step's frames."""
        for msg in self.wire.can_frames(t_s, left_mps, right_mps):
            out = self.odometry.feed(msg)
            if out is not None:
                yield out

    def heading(self, t_s: float, heading_rad: float) -> CompassHeading | None:
        """The compass reading the car's NMEA parser makes of this step's line (None: the
        line was rejected)."""
        line, _ = self.wire.compass_line(t_s, heading_rad)
        return self.compass.feed_line(line, t_s)

