"""Per-vehicle CAN profiles: which DBC, which wheel-speed messages and signals, tyre data.

cantools is the only thing that knows the bit layout (from the DBC); a profile only names the
messages and signals, says how to read direction and fault fields, and carries the vehicle data
the estimator needs (rear track width). Adding a car is adding one entry to ``PROFILES``.

Wheel speeds on these buses are linear speeds the ABS module computes from its own rolling
circumference, so distance needs no tyre radius; ``speed_scale`` corrects them when a calibration
drive shows a bias (worn or non-standard tyres). ``tyre_radius_m`` is carried for documentation
and to convert to wheel turns when a profile reports rotation instead of speed.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cantools

from guidance.errors import UserError

DBC_DIR = Path(__file__).resolve().parent / "dbc"
KPH_TO_MPS = 1.0 / 3.6


@dataclass(frozen=True, slots=True)
class WheelSignals:
    """Where one axle's wheel speeds live: a message and its left/right signals."""

    frame_id: int
    left: str
    right: str
    left_direction: str | None = None
    right_direction: str | None = None
    left_fault: str | None = None
    right_fault: str | None = None


@dataclass(frozen=True, slots=True)
class VehicleProfile:
    """Everything the wheel-speed decoder needs to know about one kind of car."""

    name: str
    vehicle: str
    dbc_file: str
    rear: WheelSignals
    front: WheelSignals
    track_width_m: float
    """Rear track width (the differential-odometry baseline, SPEC section 2)."""
    tyre_radius_m: float
    speed_resolution_kph: float
    """One count of the wheel-speed signal (quantisation of every speed sample)."""
    message_period_s: float
    """Nominal period of the rear wheel-speed message on the bus."""
    unit_to_mps: float = KPH_TO_MPS
    signed_speeds: bool = False
    """True when the speed signal itself is signed (Toyota's offset encoding)."""
    reverse_values: frozenset[int] = frozenset()
    """Direction-field values meaning 'rolling backwards'."""
    fault_direction_values: frozenset[int] = frozenset()
    """Direction-field values meaning 'sensor fault': the frame is rejected."""
    checksum: str | None = None
    """Name of the frame checksum to verify (a key of ``CHECKSUMS``), or None."""
    allow_front_fallback: bool = True
    """Use the front wheels when the rears read exactly zero while the fronts move."""
    speed_scale: float = 1.0

    @property
    def dbc_path(self) -> Path:
        return DBC_DIR / self.dbc_file

    @property
    def speed_resolution_mps(self) -> float:
        return self.speed_resolution_kph * KPH_TO_MPS

    @property
    def distance_quantum_m(self) -> float:
        """Distance resolution of one increment at the nominal message rate."""
        return self.speed_resolution_mps * self.message_period_s

    @property
    def frame_ids(self) -> tuple[int, ...]:
        return tuple(sorted({self.rear.frame_id, self.front.frame_id}))


def honda_checksum(frame_id: int, data: bytes) -> int:
    """Honda's 4-bit frame checksum (opendbc ``honda_checksum``), stored in the last nibble.

    Sum of the id's nibbles and every data nibble except the checksum nibble itself,
    subtracted from 8, modulo 16 (plus 3 for extended ids).
    """
    s = 0
    addr = frame_id
    while addr:
        s += addr & 0xF
        addr >>= 4
    last = len(data) - 1
    for i, byte in enumerate(data):
        x = byte >> 4 if i == last else byte
        s += (x & 0xF) + (x >> 4)
    s = 8 - s
    if frame_id > 0x7FF:
        s += 3
    return s & 0xF


def _honda_frame_ok(frame_id: int, data: bytes) -> bool:
    return bool(data) and (data[-1] & 0xF) == honda_checksum(frame_id, data)


CHECKSUMS: dict[str, Callable[[int, bytes], bool]] = {"honda": _honda_frame_ok}


PROFILES: dict[str, VehicleProfile] = {
    "gm_global_a": VehicleProfile(
        name="gm_global_a",
        vehicle="GM Global A powertrain bus; reference car 2007 Chevrolet Tahoe (GMT900)",
        dbc_file="gm_global_a_powertrain_generated.dbc",
        rear=WheelSignals(
            frame_id=0x34A,
            left="RLWheelSpd",
            right="RRWheelSpd",
            left_direction="RLWheelDir",
            right_direction="RRWheelDir",
        ),
        front=WheelSignals(frame_id=0x348, left="FLWheelSpd", right="FRWheelSpd"),
        track_width_m=1.72,
        # P265/70R17: 17 in rim / 2 + 0.70 * 265 mm sidewall = 0.401 m.
        tyre_radius_m=0.401,
        speed_resolution_kph=0.0311,
        # 20 Hz, measured on the Camaro log (0x348 / 0x34A every 50.0 ms).
        message_period_s=0.05,
        # VAL_ 842 RLWheelDir: 0 Stationary, 1 Forward, 2 Reverse, 3 Unsupported, 4 Fault.
        reverse_values=frozenset({2}),
        fault_direction_values=frozenset({4}),
    ),
    "toyota": VehicleProfile(
        name="toyota",
        vehicle="Toyota TSS2 powertrain bus (checked on a 2019 RAV4)",
        dbc_file="toyota_nodsu_pt_generated.dbc",
        rear=WheelSignals(
            frame_id=0xAA,
            left="WHEEL_SPEED_RL",
            right="WHEEL_SPEED_RR",
            left_fault="WHEEL_SPEED_RL_FAULT",
            right_fault="WHEEL_SPEED_RR_FAULT",
        ),
        front=WheelSignals(
            frame_id=0xAA,
            left="WHEEL_SPEED_FL",
            right="WHEEL_SPEED_FR",
            left_fault="WHEEL_SPEED_FL_FAULT",
            right_fault="WHEEL_SPEED_FR_FAULT",
        ),
        # 2019 RAV4 (XA50) rear tread 1,620 mm; 225/65R17 tyres.
        track_width_m=1.62,
        tyre_radius_m=0.362,
        speed_resolution_kph=0.01,
        message_period_s=0.0125,
        # The DBC offset (-67.67 km/h) makes raw values below 6767 negative: reverse.
        signed_speeds=True,
    ),
    "honda_civic": VehicleProfile(
        name="honda_civic",
        vehicle="Honda Civic (2016 Touring DBC; also decodes the 2019 Type R and 8th generation)",
        dbc_file="honda_civic_touring_2016_can_generated.dbc",
        rear=WheelSignals(frame_id=0x1D0, left="WHEEL_SPEED_RL", right="WHEEL_SPEED_RR"),
        front=WheelSignals(frame_id=0x1D0, left="WHEEL_SPEED_FL", right="WHEEL_SPEED_FR"),
        # 10th-generation Civic rear track 1.56-1.58 m (8th generation 1.53 m); 0.32 m tyres.
        track_width_m=1.56,
        tyre_radius_m=0.32,
        speed_resolution_kph=0.01,
        # 50 Hz, measured on the Civic 8th-generation log (every 20.0 ms).
        message_period_s=0.02,
        checksum="honda",
    ),
}


def profile_names() -> tuple[str, ...]:
    return tuple(sorted(PROFILES))


def get_profile(name: str) -> VehicleProfile:
    """The named profile; an unknown name is a ``UserError`` listing the known ones."""
    try:
        return PROFILES[name]
    except KeyError:
        raise UserError(
            f"unknown vehicle profile {name!r}; known profiles: {', '.join(profile_names())}"
        ) from None


@functools.cache
def load_dbc(dbc_file: str) -> Any:
    """Load (once) a DBC shipped in ``drivers/dbc``; non-strict, as the Toyota file needs."""
    return cantools.database.load_file(str(DBC_DIR / dbc_file), strict=False)
