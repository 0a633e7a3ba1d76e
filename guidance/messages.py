"""Messages that cross package boundaries: frozen, slotted dataclasses, SI units in field names.

Drivers (real or simulated) produce the input messages; the estimator and the
navigator consume them; telemetry, recording and prompts consume the outputs.
Timestamps ``t_s`` are monotonic seconds taken from the message source (CAN
frame time, NMEA line arrival, simulated clock), never read from a clock inside
``guidance``.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class WheelOdometry:
    """Rear-wheel distance increments since the previous message (metres, signed)."""

    t_s: float
    d_left_m: float
    d_right_m: float


@dataclass(frozen=True, slots=True)
class CompassHeading:
    """A compass reading as it comes off the wire: degrees clockwise from north.

    ``is_true`` is False for magnetic headings (HDG/HDM), which need the
    declination added at the input edge; True for HDT.
    """

    t_s: float
    heading_deg: float
    is_true: bool = False


@dataclass(frozen=True, slots=True)
class LandmarkFix:
    """A confirmed camera match: the landmark's known position measures the car's position."""

    t_s: float
    landmark_id: int
    x_m: float
    y_m: float
    sigma_m: float


@dataclass(frozen=True, slots=True)
class IntersectionScene:
    """An intersection the car is at (or approaching): the exits it offers.

    ``exit_headings_rad`` are the headings (local frame, CCW from east) the car
    will have after taking each exit. ``distance_m`` is the distance to it when
    known (simulation), else None.
    """

    t_s: float
    exit_headings_rad: tuple[float, ...]
    distance_m: float | None = None
    labels: tuple[str, ...] = field(default=())


@dataclass(frozen=True, slots=True)
class Ellipse:
    """The 2-sigma position ellipse: semi-axes (m), orientation (rad from x) and full major axis."""

    semi_major_m: float
    semi_minor_m: float
    orientation_rad: float
    major_axis_m: float


@dataclass(frozen=True, slots=True)
class EstimateState:
    """The estimator's published state."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    covariance: tuple[tuple[float, float, float], ...]
    ellipse: Ellipse
    lost: bool
    healthy: bool


@dataclass(frozen=True, slots=True, eq=False)
class CameraFrame:
    """One camera image (BGR or grey ``numpy`` array) with its capture time."""

    t_s: float
    image: object  # numpy.ndarray; kept as object so this module needs no numpy import
    source: str = ""


@dataclass(frozen=True, slots=True)
class TurnCompleted:
    """The driver took an exit: reported by the co-driver or detected from the heading change."""

    t_s: float
    heading_change_rad: float
    source: str = "detected"
