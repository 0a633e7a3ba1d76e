"""Per-vehicle CAN profiles: which DBC, which wheel-speed messages and signals, tyre data.

cantools is the only thing that knows the bit layout (from the DBC); a profile only names the
messages and signals, says how to read direction and fault fields, and carries the vehicle data
the estimator needs (rear track width). Adding a car is adding one entry to ``PROFILES``.

The DBCs are opendbc's (``drivers.opendbc_dbc``): one profile per DBC that an opendbc car
platform uses for its powertrain bus, grouped by make (``_family``); the message and signal
names are those opendbc's own car code reads (``opendbc/car/<brand>/carstate.py``). Most ABS
modules send linear speeds computed from their own rolling circumference, so distance needs no
tyre radius; Ford (rad/s) and Chrysler (rpm) send wheel rotation, converted with the profile's
nominal ``tyre_radius_m``. ``speed_scale`` corrects either when a calibration drive shows a
bias (worn or non-standard tyres).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers import opendbc_dbc
from guidance.errors import UserError

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
class YawRateSignal:
    """Where the stability control's yaw rate is (``drivers.can_yaw`` decodes it for a gyro
    car), counter-clockwise positive once decoded."""

    frame_id: int
    message: str
    signal: str
    unit: str
    sign: str | None = None
    """A separate sign bit of the same message (Volkswagen's): set, the unsigned magnitude
    is negative, as openpilot reads it (``yawRate = magnitude x (1, -1)[bit]``)."""


@dataclass(frozen=True, slots=True)
class VehicleProfile:
    """Everything the wheel-speed decoder needs to know about one kind of car."""

    name: str
    vehicle: str
    dbc_file: str
    """The opendbc DBC (``drivers.opendbc_dbc``), by its name there."""
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
    brand: str = ""
    """opendbc's name of the make (its ``opendbc.car.<brand>`` package)."""
    yaw_rate: YawRateSignal | None = None

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


def _axle(frame_id: int, left: str, right: str, **kw: Any) -> WheelSignals:
    return WheelSignals(frame_id=frame_id, left=left, right=right, **kw)


def _family(
    brand: str,
    members: dict[str, tuple[str, float, str]],
    *,
    rear: WheelSignals | dict[str, WheelSignals],
    front: WheelSignals | dict[str, WheelSignals],
    resolution_kph: float,
    period_s: float,
    tyre_radius_m: float,
    yaw: dict[str, YawRateSignal] | YawRateSignal | None = None,
    **kw: Any,
) -> dict[str, VehicleProfile]:
    """One brand's ABS module as opendbc describes it, for each of its DBCs: ``members`` maps
    a profile name to (opendbc DBC, rear track of the reference car in m, the reference car).
    ``rear``, ``front`` and ``yaw`` may differ per DBC (a dict keyed by profile name)."""

    def pick(v: Any, name: str) -> Any:
        return v.get(name) if isinstance(v, dict) else v

    return {
        name: VehicleProfile(
            name=name,
            brand=brand,
            vehicle=vehicle,
            dbc_file=dbc,
            rear=pick(rear, name),
            front=pick(front, name),
            track_width_m=track,
            tyre_radius_m=tyre_radius_m,
            speed_resolution_kph=resolution_kph,
            message_period_s=period_s,
            yaw_rate=pick(yaw, name),
            **kw,
        )
        for name, (dbc, track, vehicle) in members.items()
    }


_KPH_PER_RPM_AT = 2.0 * 3.141592653589793 * 60.0 / 1000.0
"""km/h per rpm of a wheel of 1 m radius (rpm x 2 pi r / 60 m/s = rpm x 0.377 r km/h)."""

PROFILES: dict[str, VehicleProfile] = {
    # Toyota / Lexus: WHEEL_SPEEDS 0xAA, all four wheels; the -67.67 km/h offset signs them
    # (reverse is negative). Yaw rate: KINEMATICS 0x24 YAW_RATE (deg/s).
    **_family(
        "toyota",
        {
            "toyota": ("toyota_nodsu_pt_generated", 1.62, "Toyota TSS2 (checked on a 2019 RAV4)"),
            "toyota_new_mc_pt": (
                "toyota_new_mc_pt_generated",
                1.55,
                "Toyota Corolla / RAV4 2017-18",
            ),
            "toyota_tnga_k_pt": (
                "toyota_tnga_k_pt_generated",
                1.62,
                "Toyota TNGA-K (Highlander, RAV4 hybrid)",
            ),
            "toyota_secoc_pt": (
                "toyota_secoc_pt_generated",
                1.62,
                "Toyota SecOC (RAV4 Prime, Yaris)",
            ),
        },
        rear=_axle(0xAA, "WHEEL_SPEED_RL", "WHEEL_SPEED_RR"),
        front=_axle(0xAA, "WHEEL_SPEED_FL", "WHEEL_SPEED_FR"),
        resolution_kph=0.01,
        period_s=0.0125,
        tyre_radius_m=0.362,
        signed_speeds=True,
        yaw=YawRateSignal(0x24, "KINEMATICS", "YAW_RATE", "deg/s"),
    ),
    # Honda / Acura: WHEEL_SPEEDS 0x1D0 with Honda's 4-bit checksum; no yaw rate in the DBCs.
    **_family(
        "honda",
        {
            "honda_civic": (
                "honda_civic_touring_2016_can_generated",
                1.56,
                "Honda Civic 2016 Touring (also the 2019 Type R, 8th generation)",
            ),
            "honda_civic_hatchback_ex_2017_can": (
                "honda_civic_hatchback_ex_2017_can_generated",
                1.57,
                "Honda Accord, Civic Bosch, CR-V 5G",
            ),
            "honda_bosch_radarless": (
                "honda_bosch_radarless_generated",
                1.57,
                "Honda Civic 2022, HR-V 3G",
            ),
            "honda_common_canfd": (
                "honda_common_canfd_generated",
                1.60,
                "Honda Accord 11G, CR-V 6G, Pilot 4G",
            ),
            "honda_crv_touring_2016_can": (
                "honda_crv_touring_2016_can_generated",
                1.58,
                "Honda CR-V 2016",
            ),
            "honda_insight_ex_2019_can": (
                "honda_insight_ex_2019_can_generated",
                1.57,
                "Honda Insight 2019",
            ),
            "honda_odyssey_exl_2018": (
                "honda_odyssey_exl_2018_generated",
                1.72,
                "Honda Odyssey 2018",
            ),
            "honda_odyssey_twn_2018": (
                "honda_odyssey_twn_2018_generated",
                1.72,
                "Honda Odyssey (Taiwan) 2018",
            ),
            "honda_e_advance_2020_can": (
                "honda_e_advance_2020_can_generated",
                1.51,
                "Honda e Advance 2020",
            ),
            "acura_ilx_2016_can": (
                "acura_ilx_2016_can_generated",
                1.53,
                "Acura ILX, Honda Fit, HR-V",
            ),
            "acura_rdx_2018_can": ("acura_rdx_2018_can_generated", 1.61, "Acura RDX 2018"),
            "acura_rdx_2020_can": (
                "acura_rdx_2020_can_generated",
                1.65,
                "Acura RDX 2020, Honda e, N-Box",
            ),
        },
        rear=_axle(0x1D0, "WHEEL_SPEED_RL", "WHEEL_SPEED_RR"),
        front=_axle(0x1D0, "WHEEL_SPEED_FL", "WHEEL_SPEED_FR"),
        resolution_kph=0.01,
        period_s=0.02,
        tyre_radius_m=0.32,
        checksum="honda",
    ),
    # GM Global A: EBCMWheelSpdRear 0x34A with 3-bit directions, front 0x348; yaw rate
    # EBCMVehicleDynamic 0x1E9 YawRate (deg/s).
    **_family(
        "gm",
        {
            "gm_global_a": (
                "gm_global_a_powertrain_generated",
                1.72,
                "GM Global A powertrain bus; reference car 2007 Chevrolet Tahoe (GMT900)",
            )
        },
        rear=_axle(
            0x34A,
            "RLWheelSpd",
            "RRWheelSpd",
            left_direction="RLWheelDir",
            right_direction="RRWheelDir",
        ),
        front=_axle(0x348, "FLWheelSpd", "FRWheelSpd"),
        # P265/70R17: 17 in rim / 2 + 0.70 * 265 mm sidewall = 0.401 m; 20 Hz (Camaro log).
        resolution_kph=0.0311,
        period_s=0.05,
        tyre_radius_m=0.401,
        # VAL_ 842 RLWheelDir: 0 Stationary, 1 Forward, 2 Reverse, 3 Unsupported, 4 Fault.
        reverse_values=frozenset({2}),
        fault_direction_values=frozenset({4}),
        # Two yaw rates in the frame: YawRate (12 bits signed x 0.625: +-1,280 deg/s,
        # declared in [0, 1] without a unit) and YawRate2 (12 bits signed x 0.0625 "grad/s":
        # +-128 deg/s). An ESC yaw-rate sensor measures +-100-300 deg/s to a few hundredths
        # (docs/estimation.md, "The car's gyro"): YawRate2 is that sensor; not checked on a
        # GM drive (the shared Camaro log stands still).
        yaw=YawRateSignal(0x1E9, "EBCMVehicleDynamic", "YawRate2", "deg/s"),
    ),
    # Hyundai / Kia / Genesis: WHL_SPD11 0x386 (CAN), WHEEL_SPEEDS 0xA0 (CAN FD, 24 bytes);
    # yaw rate ESP12 0x220 YAW_RATE, ESC_02_10ms 0xE5 ESC_YawRtVal (deg/s).
    **_family(
        "hyundai",
        {
            "hyundai_kia_generic": (
                "hyundai_kia_generic",
                1.60,
                "Hyundai / Kia / Genesis on CAN (Sonata, Elantra, Tucson, Niro...)",
            ),
            "hyundai_canfd": (
                "hyundai_canfd_generated",
                1.64,
                "Hyundai / Kia / Genesis on CAN FD (Ioniq 5, EV6...)",
            ),
        },
        rear={
            "hyundai_kia_generic": _axle(0x386, "WHL_SPD_RL", "WHL_SPD_RR"),
            "hyundai_canfd": _axle(0xA0, "WHL_SpdRLVal", "WHL_SpdRRVal"),
        },
        front={
            "hyundai_kia_generic": _axle(0x386, "WHL_SPD_FL", "WHL_SPD_FR"),
            "hyundai_canfd": _axle(0xA0, "WHL_SpdFLVal", "WHL_SpdFRVal"),
        },
        resolution_kph=0.03125,
        period_s=0.02,
        tyre_radius_m=0.34,
        yaw={
            "hyundai_kia_generic": YawRateSignal(0x220, "ESP12", "YAW_RATE", "deg/s"),
            "hyundai_canfd": YawRateSignal(0xE5, "ESC_02_10ms", "ESC_YawRtVal", "deg/s"),
        },
    ),
    # Subaru: Wheel_Speeds 0x13A (global platform, 0.057 km/h) or 0xD4 (pre-global, 0.0592).
    **_family(
        "subaru",
        {
            "subaru_global_2017": (
                "subaru_global_2017_generated",
                1.55,
                "Subaru global platform (Impreza, Outback, Ascent...)",
            ),
            "subaru_global_2020_hybrid": (
                "subaru_global_2020_hybrid_generated",
                1.55,
                "Subaru Crosstrek / Forester hybrid",
            ),
        },
        rear=_axle(0x13A, "RL", "RR"),
        front=_axle(0x13A, "FL", "FR"),
        resolution_kph=0.057,
        period_s=0.02,
        tyre_radius_m=0.33,
    ),
    **_family(
        "subaru",
        {
            "subaru_forester_2017": (
                "subaru_forester_2017_generated",
                1.55,
                "Subaru Forester (pre-global)",
            ),
            "subaru_outback_2015": (
                "subaru_outback_2015_generated",
                1.55,
                "Subaru Legacy / Outback 2015 (pre-global)",
            ),
            "subaru_outback_2019": (
                "subaru_outback_2019_generated",
                1.55,
                "Subaru Outback 2018-19 (pre-global)",
            ),
        },
        rear=_axle(0xD4, "RL", "RR"),
        front=_axle(0xD4, "FL", "FR"),
        resolution_kph=0.0592,
        period_s=0.02,
        tyre_radius_m=0.34,
    ),
    # Nissan: WHEEL_SPEEDS_REAR 0x285; front 0x29A (X-Trail, Rogue, Altima) or 0x284 (Leaf).
    **_family(
        "nissan",
        {
            "nissan_x_trail_2017": (
                "nissan_x_trail_2017_generated",
                1.58,
                "Nissan X-Trail / Rogue / Altima",
            ),
            "nissan_leaf_2018": ("nissan_leaf_2018_generated", 1.55, "Nissan Leaf 2018"),
        },
        rear=_axle(0x285, "WHEEL_SPEED_RL", "WHEEL_SPEED_RR"),
        front={
            "nissan_x_trail_2017": _axle(0x29A, "WHEEL_SPEED_FL", "WHEEL_SPEED_FR"),
            "nissan_leaf_2018": _axle(0x284, "WHEEL_SPEED_FL", "WHEEL_SPEED_FR"),
        },
        resolution_kph=0.005,
        period_s=0.02,
        tyre_radius_m=0.34,
    ),
    # Mazda: WHEEL_SPEEDS 0x215, offset -100 km/h (reverse is negative, as Toyota's).
    **_family(
        "mazda",
        {"mazda_2017": ("mazda_2017", 1.59, "Mazda 3 / 6 / CX-5 / CX-9 2017-")},
        rear=_axle(0x215, "RL", "RR"),
        front=_axle(0x215, "FL", "FR"),
        resolution_kph=0.01,
        period_s=0.02,
        tyre_radius_m=0.35,
        signed_speeds=True,
    ),
    # Ford / Lincoln: WheelSpeed 0x217 in rad/s of the wheel (distance needs the tyre
    # radius: set speed_scale from a calibration drive); yaw rate Yaw_Data_FD1 0x91
    # VehYaw_W_Actl (rad/s).
    **_family(
        "ford",
        {
            "ford_lincoln_base_pt": (
                "ford_lincoln_base_pt",
                1.63,
                "Ford / Lincoln CAN (Escape, Explorer, Bronco Sport, F-150...)",
            )
        },
        rear=_axle(0x217, "WhlRl_W_Meas", "WhlRr_W_Meas"),
        front=_axle(0x217, "WhlFl_W_Meas", "WhlFr_W_Meas"),
        resolution_kph=0.01 * 0.36 * 3.6,
        period_s=0.01,
        tyre_radius_m=0.36,
        unit_to_mps=0.36,  # rad/s x tyre radius (m)
        yaw=YawRateSignal(0x91, "Yaw_Data_FD1", "VehYaw_W_Actl", "rad/s"),
    ),
    # Volkswagen group: MQB ESP_19 0xB2, MLB ESP_03 0x103, PQ Bremse_3 0x4A0 (HL/HR rear,
    # VL/VR front); yaw rate ESP_02 0x101 ESP_Gierrate (MQB, MLB), Bremse_5 0x4A8 (PQ), deg/s
    # unsigned with a separate sign bit (ESP_VZ_Gierrate, BR5_Vorzeichen; set: negative).
    **_family(
        "volkswagen",
        {"vw_mqb": ("vw_mqb", 1.51, "VW MQB (Golf 7, Passat B8, Tiguan, Audi A3, Skoda, Seat...)")},
        rear=_axle(0xB2, "ESP_HL_Radgeschw_02", "ESP_HR_Radgeschw_02"),
        front=_axle(0xB2, "ESP_VL_Radgeschw_02", "ESP_VR_Radgeschw_02"),
        resolution_kph=0.0075,
        period_s=0.01,
        tyre_radius_m=0.32,
        yaw=YawRateSignal(0x101, "ESP_02", "ESP_Gierrate", "deg/s", sign="ESP_VZ_Gierrate"),
    ),
    **_family(
        "volkswagen",
        {"vw_mlb": ("vw_mlb", 1.61, "VW MLB (Audi Q5 mk1, Porsche Macan)")},
        rear=_axle(0x103, "ESP_HL_Radgeschw", "ESP_HR_Radgeschw"),
        front=_axle(0x103, "ESP_VL_Radgeschw", "ESP_VR_Radgeschw"),
        resolution_kph=0.1,
        period_s=0.02,
        tyre_radius_m=0.35,
        yaw=YawRateSignal(0x101, "ESP_02", "ESP_Gierrate", "deg/s", sign="ESP_VZ_Gierrate"),
    ),
    **_family(
        "volkswagen",
        {"vw_pq": ("vw_pq", 1.55, "VW PQ (Jetta 6, Passat NMS, Caddy 3, Sharan 2)")},
        rear=_axle(0x4A0, "Radgeschw__HL_4_1", "Radgeschw__HR_4_1"),
        front=_axle(0x4A0, "Radgeschw__VL_4_1", "Radgeschw__VR_4_1"),
        resolution_kph=0.01,
        period_s=0.01,
        tyre_radius_m=0.32,
        yaw=YawRateSignal(0x4A8, "Bremse_5", "BR5_Giergeschw", "deg/s", sign="BR5_Vorzeichen"),
    ),
    # Chrysler / Jeep / Ram: ESP_6 (0x158, Ram 1500 0x8B) in wheel rpm (x 0.5); distance
    # needs the tyre radius (speed_scale from a calibration drive). Yaw rate ESP_4 0x89
    # Yaw_Rate on the Ram 1500 only.
    **_family(
        "chrysler",
        {
            "chrysler_pacifica_2017_hybrid": (
                "chrysler_pacifica_2017_hybrid_generated",
                1.73,
                "Chrysler Pacifica 2017-",
            ),
            "chrysler_ram_hd": ("chrysler_ram_hd_generated", 1.73, "Ram HD 5th generation"),
        },
        rear=_axle(0x158, "WHEEL_SPEED_RL", "WHEEL_SPEED_RR"),
        front=_axle(0x158, "WHEEL_SPEED_FL", "WHEEL_SPEED_FR"),
        resolution_kph=0.5 * _KPH_PER_RPM_AT * 0.37,
        period_s=0.02,
        tyre_radius_m=0.37,
        unit_to_mps=_KPH_PER_RPM_AT * 0.37 / 3.6,  # rpm x 2 pi r / 60
    ),
    **_family(
        "chrysler",
        {"chrysler_ram_dt": ("chrysler_ram_dt_generated", 1.73, "Ram 1500 5th generation")},
        rear=_axle(0x8B, "WHEEL_SPEED_RL", "WHEEL_SPEED_RR"),
        front=_axle(0x8B, "WHEEL_SPEED_FL", "WHEEL_SPEED_FR"),
        resolution_kph=0.5 * _KPH_PER_RPM_AT * 0.40,
        period_s=0.02,
        tyre_radius_m=0.40,
        unit_to_mps=_KPH_PER_RPM_AT * 0.40 / 3.6,
        yaw=YawRateSignal(0x89, "ESP_4", "Yaw_Rate", "deg/s"),
    ),
    # Tesla Model 3 / Y / X: ESP_wheelSpeeds 0x175 on the "party" bus (km/h x 0.04).
    **_family(
        "tesla",
        {"tesla_model3_party": ("tesla_model3_party", 1.58, "Tesla Model 3 / Y / X (party bus)")},
        rear=_axle(0x175, "ESP_wheelSpeedReL", "ESP_wheelSpeedReR"),
        front=_axle(0x175, "ESP_wheelSpeedFrL", "ESP_wheelSpeedFrR"),
        resolution_kph=0.04,
        period_s=0.01,
        tyre_radius_m=0.35,
    ),
}
"""Every profile: one per opendbc DBC that an opendbc car platform uses for its powertrain
bus and whose wheel speeds this decoder reads (``guidance profiles`` lists them with the
platforms). The Toyota, Honda Civic and GM Global A profiles keep their earlier names."""


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


def load_dbc(dbc_file: str) -> Any:
    """The profile's DBC loaded by cantools, from opendbc (``drivers.opendbc_dbc``)."""
    return opendbc_dbc.load_dbc(dbc_file)
