"""Messages that cross package boundaries: frozen, slotted dataclasses, SI units in field names.

Drivers (real or simulated) produce the input messages; the estimator and the
navigator consume them; telemetry, recording and prompts consume the outputs.
Timestamps ``t_s`` are monotonic seconds taken from the message source (CAN
frame time, NMEA line arrival, simulated clock), never read from a clock inside
``guidance``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from enum import IntEnum, StrEnum
from typing import Any


@dataclass(frozen=True, slots=True)
class WheelOdometry:
    """Rear-wheel distance increments since the previous message (metres, signed)."""

    t_s: float
    d_left_m: float
    d_right_m: float


@dataclass(frozen=True, slots=True)
class YawRate:
    """The car's yaw-rate sensor (the stability control's gyro, on CAN): rad/s,
    counter-clockwise positive, as read (bias and scale error included)."""

    t_s: float
    yaw_rate_rad_s: float


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
    relocalised: bool = False
    """The place was found by a search of the whole database, not inside the estimate's
    gate (the car was lost, or started with no position): the pipeline resets the position
    around it instead of updating (an update would be refused by the gate). Its ``sigma_m``
    is then the sighting range plus the place's own sigma (``reset_sigma_m``): the car is
    anywhere the place can be seen from, its first sight often at the edge of that range."""


def reset_sigma_m(sighting_range_m: float, position_sigma_m: float) -> float:
    """1-sigma of a relocalisation's reset: the whole sighting range plus the place's survey
    error, so the 2-sigma ellipse holds every point within the range (a first sight is at its
    edge; ``r / 2``, an ordinary fix's share of the range, would put it on the ellipse)."""
    return sighting_range_m + position_sigma_m


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
    """The estimate: what the first stage of the core (``core/localize``) hands the second
    (``core/plan``), and the state the car publishes. ``covariance`` is the pose block (x, y,
    heading) of the filter's covariance."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    covariance: tuple[tuple[float, float, float], ...]
    ellipse: Ellipse
    lost: bool
    healthy: bool
    odometer_m: float = 0.0
    """Distance driven so far (odometry, and dead reckoning through a CAN gap)."""
    speed_mps: float = 0.0
    """The speed of the last odometry increment (held through a gap)."""
    heading_known: bool = True
    """False until the first heading (a start heading, or the first compass reading)."""
    reckoning: bool = False
    """The distance is being dead-reckoned (odometry overdue): no turn is named for a place on
    the road, nothing is passed straight by distance alone."""


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


@dataclass(frozen=True, slots=True)
class CancelReport:
    """The co-driver withdraws the last intersection report (a mistake): taken back while the
    car has not yet reached it, else answered that there is nothing to cancel."""

    t_s: float
    source: str = "co-driver"


@dataclass(frozen=True, slots=True)
class HeadingFix:
    """A heading measurement already in the filter frame (rad, CCW from east).

    Drivers convert compass degrees with ``guidance.model.compass_to_heading``
    (declination and mounting offset applied there, at the input edge).
    """

    t_s: float
    theta_rad: float


class Priority(IntEnum):
    """Prompt tiers: a higher tier is spoken first and dropped last.

    ``LOST`` is an alias of ``SAFETY``: "position lost" shares the top tier
    with sensor and uncertainty warnings.
    """

    INFO = 0
    GUIDANCE = 1
    SAFETY = 2
    LOST = 2

    @classmethod
    def of(cls, value: int) -> Priority:
        """Clamp a plain int (the Speaker protocol's ``priority``) onto a tier."""
        return cls(min(max(int(value), int(cls.INFO)), int(cls.SAFETY)))


@dataclass(frozen=True, slots=True)
class GoalUpdate:
    """A new goal (local metres): from the operator, a remote monitor, or the field protocol."""

    t_s: float
    x_m: float
    y_m: float
    source: str = "operator"


@dataclass(frozen=True, slots=True)
class Approach:
    """The distance to the intersection the pending decision is for (when it is known: the
    simulator; a future map-free intersection detector). Drives the second announcement."""

    t_s: float
    distance_m: float


class Speech(StrEnum):
    """What the driver is told, as an event (openpilot's event names): its words are made in
    one place, ``guidance.core.speech.SPEECH``, from a ``Say``'s numbers and the units."""

    TURN = "turn"
    LANDMARK = "landmark"
    FOUND = "found"
    UNCERTAIN = "uncertain"
    NEW_DESTINATION = "new_destination"
    ARRIVED = "arrived"
    LOST = "lost"
    POSITION_UNKNOWN = "position_unknown"
    WAITING_FOR_HEADING = "waiting_for_heading"
    SENSOR = "sensor"
    COMPASS_UNUSABLE = "compass_unusable"
    CHANCE = "chance"
    DIFFERENT_EXIT = "different_exit"
    NO_CO_DRIVER_INPUT = "no_co_driver_input"
    READ_BACK = "read_back"
    SAY_AGAIN = "say_again"
    REPORT_CANCELLED = "report_cancelled"
    CANNOT_CANCEL = "cannot_cancel"
    COMPONENT = "component"


@dataclass(frozen=True, slots=True)
class Say:
    """One thing to tell the driver: its kind and its numbers, no words (those are
    ``guidance.core.speech.words(say, units)``). Fields a kind does not use keep their defaults."""

    speech: Speech
    turn_rad: float = 0.0
    """TURN: the manoeuvre (CCW positive = left)."""
    distance_m: float | None = None
    """TURN: to the intersection (None: "at the next intersection"); UNCERTAIN: the major axis."""
    then_turn_rad: float | None = None
    then_gap_m: float | None = None
    """TURN: the turn after it and the distance between the two ("..., then turn right")."""
    band_rad: float = 0.0
    """TURN: +- the approach heading's uncertainty: the manoeuvre is named only as truly as it
    is known (``speech.manoeuvre_within``)."""
    exit_heading_rad: float = 0.0
    """TURN: the exit road's heading, for "take the road towards the north-east"."""
    changed: bool = False
    """TURN: a new instruction for an intersection already announced ("Change of plan: ...")."""
    again: bool = False
    """TURN: the same words for another intersection right after ("... again"); FOUND: found
    *again* (False: the first place of a car that started anywhere)."""
    name: str = ""
    """LANDMARK, FOUND: the place's name (an id-like name is not read out)."""
    input: str = ""
    status: str = ""
    """SENSOR: the input ("odometry", "compass", "camera", "scene") and its bad status
    ("silent", "invalid", "disconnected"); COMPASS_UNUSABLE: ``status`` is the judge's reason;
    COMPONENT: the component ("voice", "telemetry", "recorder") and its bad status."""
    chance: float = 0.0
    """CHANCE: of reaching the destination, 0-1."""
    remote: bool = False
    """NEW_DESTINATION: set by a remote monitor."""
    searching: bool = False
    """LOST: the car looks for a known place again."""
    line: str = ""
    """READ_BACK: the co-driver line heard ("l s r", "t l", "repeat")."""


@dataclass(frozen=True, slots=True)
class Prompt:
    """Something to tell the driver: the words (made once, by ``guidance.core.speech``) and
    what they say as data (``say``: its kind and numbers)."""

    t_s: float
    text: str
    priority: int
    kind: str
    """"turn", "landmark", "found", "uncertain", "arrived", "lost", "sensor", "chance", "info"
    (``speech.KIND``: the published category)."""
    say: Say | None = None


def _finite(value: float | None) -> float | None:
    """A JSON-safe number: non-finite values become None (strict JSON has no NaN)."""
    return value if value is None or math.isfinite(value) else None


@dataclass(frozen=True, slots=True)
class Target:
    """Where the navigator is heading (SPEC 3): the goal, or a landmark by its id."""

    x_m: float
    y_m: float
    kind: str = "goal"
    """"goal" or "landmark"."""
    id: int | None = None


@dataclass(frozen=True, slots=True)
class Health:
    """The one health record (SPEC section 6; openpilot's alive/valid), for an input and for a
    component alike: a driver's ``health()``, the pipeline's view of an input
    (``Pipeline.statuses()``), telemetry's, the recorder's and the speaker's. The health
    message carries ``as_dict`` of each (docs/reliability.md lists what each fault sets)."""

    name: str
    status: str
    """One word. Drivers and inputs: "starting", "ok", "silent", "disconnected", "invalid",
    "ended", "stopped"; components add their own ("up", "down", "disk_full", "failed",
    "recording", "text_fallback"...)."""
    alive: bool
    """Data (or the component's work) is arriving."""
    valid: bool
    """What arrives is usable."""
    age_s: float | None = None
    """Seconds since the last accepted message; None before the first (or not applicable)."""
    detail: str = ""
    """Why it is not ok, or the last error, in words."""
    warning: str = ""
    """What to tell the driver (or the operator) while it is not ok; empty otherwise."""
    counters: Mapping[str, int] = field(default_factory=dict)
    info: Mapping[str, str] = field(default_factory=dict)
    """Facts in words, e.g. the recorder's current file or telemetry's mode."""
    rate_hz: float | None = None
    """Measured message rate (inputs)."""
    expected_rate_hz: float | None = None
    """The rate the input should have; None for event-driven inputs and components."""

    @property
    def ok(self) -> bool:
        return self.alive and self.valid

    def as_dict(self) -> dict[str, Any]:
        """The record as plain JSON-safe values (non-finite numbers become None)."""
        return {
            "name": self.name,
            "status": self.status,
            "alive": self.alive,
            "valid": self.valid,
            "ok": self.ok,
            "age_s": _finite(self.age_s),
            "rate_hz": _finite(self.rate_hz),
            "expected_rate_hz": _finite(self.expected_rate_hz),
            "detail": self.detail,
            "warning": self.warning,
            "counters": {str(k): int(v) for k, v in self.counters.items()},
            "info": {str(k): str(v) for k, v in self.info.items()},
        }


@dataclass(frozen=True, slots=True)
class DeviceStatus:
    """A driver's status flip, delivered through the ordinary message path (rare): what only
    the driver knows (its device disconnected) and the sentence it wants said."""

    t_s: float
    input: str
    """The app's input it feeds: "odometry", "compass", "camera", "scene"."""
    health: Health


@dataclass(frozen=True, slots=True)
class HealthChange:
    """An input whose alive/valid flags flipped (``Outputs.health``)."""

    t_s: float
    status: Health


@dataclass(frozen=True, slots=True)
class ExitTaken:
    """How a pending decision was resolved: which exit the driver actually took."""

    t_s: float
    decision: Decision
    exit_index: int
    followed: bool
    source: str


# -- the navigator's values (guidance.core.plan.navigator makes them) -----------------------------
class Method(StrEnum):
    STRAIGHT_TO_GOAL = "straight_to_goal"
    LANDMARK_TO_LANDMARK = "landmark_to_landmark"
    HYBRID = "hybrid"

    @property
    def code(self) -> int:
        from guidance.core import law  # the compiled law's order (loads numba on first use)

        return law.METHOD_NAMES.index(self.value)


@dataclass(frozen=True, slots=True)
class Landmark:
    id: int
    x_m: float
    y_m: float
    name: str = ""


@dataclass(frozen=True, slots=True)
class ExitOption:
    index: int
    heading_rad: float
    turn_rad: float
    """Turn relative to the current heading, CCW positive (left)."""
    angle_cost_rad: float
    penalty_rad: float
    cost_rad: float


@dataclass(frozen=True, slots=True)
class Decision:
    t_s: float
    exit_index: int
    exit_heading_rad: float
    turn_rad: float
    options: tuple[ExitOption, ...]
    target_x_m: float
    target_y_m: float
    target_kind: str
    """"goal" or "landmark"."""
    target_id: int | None
    intersection_id: int
    revisit: bool
    mode: str
    reason: str

    def with_exit(self, o: ExitOption) -> Decision:
        """This decision with the exit ``o`` chosen (a change the margin did not allow)."""
        return replace(self, exit_index=o.index, exit_heading_rad=o.heading_rad,
                       turn_rad=o.turn_rad)  # fmt: skip


# -- raw device units (the drivers' raw-input hook; the recorder's /can and /nmea) -------------
@dataclass(frozen=True, slots=True)
class RawCanFrame:
    """One CAN frame as the driver read it, before decoding."""

    t_s: float
    arbitration_id: int
    data: bytes
    is_extended_id: bool = False
    is_error_frame: bool = False
    channel: str = ""


@dataclass(frozen=True, slots=True)
class RawNmeaLine:
    """One NMEA line as the driver read it (bytes as they came), before parsing."""

    t_s: float
    line: bytes | str
    port: str = ""


RawRecord = RawCanFrame | RawNmeaLine
RawSink = Callable[[RawRecord], None]
"""The drivers' raw-input hook (``ThreadedSource.set_raw_sink``): every unit read, typed."""
