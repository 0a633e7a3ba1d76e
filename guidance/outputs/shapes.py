"""The shape of each output message, written once: a ``TypedDict`` per message (and per nested
object), which the encoders (``guidance.outputs.messages``) return and from which the JSON
Schemas are generated (``guidance.outputs.schemas``), as ``guidance.core.codec.schema`` does for
the inputs from their dataclasses. What a type cannot say (a description, a range) is
``Annotated[..., doc(...)]`` beside it.

Keys are required only where the schema requires them (the envelope's ``schema``,
``vehicle_id``, ``seq`` and ``t_s``, a state's origin's latitude and longitude): the others are
declared ``total=False``, although the encoders always write them (a reader of an older
message may lack one).

No ``from __future__ import annotations`` here: ``TypedDict`` reads ``NotRequired`` from the
evaluated hints.
"""

from typing import Annotated, Any, NotRequired, TypedDict

from guidance.core.codec import doc

NUM = float | None
"""A JSON number, or null where the value was not finite (strict JSON has no NaN)."""


def _together(a: str, b: str) -> list[dict[str, Any]]:
    """Rules that make ``a`` a number only with ``b`` a number, and ``b`` only with ``a``:
    a point is drawn from both or neither (``lat_deg`` without ``lon_deg``, or with
    ``lon_deg: null``, cannot be drawn; the web page and the monitor's check agree on it)."""

    def number(k: str) -> dict[str, Any]:
        return {"required": [k], "properties": {k: {"type": "number"}}}

    return [{"if": number(a), "then": number(b)}, {"if": number(b), "then": number(a)}]


POINT_RULES = [*_together("x_m", "y_m"), *_together("lat_deg", "lon_deg")]
"""Every point of a state (the car, its target, its goal): coordinates in pairs."""
LAT = Annotated[float | None, doc(description="WGS-84 latitude, degrees (null: no origin)")]
LON = Annotated[float | None, doc(description="WGS-84 longitude, degrees (null: no origin)")]


class Envelope(TypedDict):
    """Every message's first fields."""

    schema: Annotated[str, doc(description="name/version, e.g. guidance.state/1")]
    vehicle_id: str
    seq: Annotated[int, doc(description="per vehicle and kind; gaps are drops")]
    t_s: Annotated[float | None, doc(description="car monotonic clock, s")]
    wall_time_unix_s: NotRequired[Annotated[float | None, doc(description="for logs only, s")]]


class TargetShape(TypedDict, total=False):
    x_m: NUM
    y_m: NUM
    kind: Annotated[str, doc(enum=["goal", "landmark"])]
    id: int | None


class GeoTargetShape(TargetShape, total=False):
    lat_deg: LAT
    lon_deg: LON


class PointShape(TypedDict, total=False):
    x_m: NUM
    y_m: NUM
    lat_deg: LAT
    lon_deg: LON


class OriginShape(TypedDict):
    lat_deg: Annotated[float, doc(minimum=-90, maximum=90)]
    lon_deg: Annotated[float, doc(minimum=-180, maximum=180)]


class EllipseShape(TypedDict, total=False):
    semi_major_m: NUM
    semi_minor_m: NUM
    orientation_rad: NUM
    major_axis_m: NUM


class StateMessage(Envelope, total=False):
    x_m: NUM
    y_m: NUM
    lat_deg: LAT
    lon_deg: LON
    origin: Annotated[
        OriginShape | None,
        doc(description="the local frame's origin (x east, y north metres), WGS-84"),
    ]
    heading_rad: NUM
    heading_deg: NUM
    heading_deg_true: Annotated[
        float | None,
        doc(description="compass heading: degrees clockwise from true north, [0, 360)"),
    ]
    covariance: Annotated[list[list[NUM]], doc(description="3x3 over (x_m, y_m, heading_rad)")]
    ellipse: EllipseShape
    speed_mps: NUM
    target: Annotated[GeoTargetShape | None, doc(allOf=POINT_RULES)]
    goal: Annotated[PointShape | None, doc(allOf=POINT_RULES)]
    method: str | None
    mode: str | None
    chance: Annotated[
        float | None,
        doc(
            minimum=0,
            maximum=1,
            description="chance of reaching the goal from here (the study engine's table, "
            "guidance.core.plan.chance); null: not computed",
        ),
    ]
    lost: bool
    healthy: bool


class OptionShape(TypedDict, total=False):
    index: int
    heading_rad: NUM
    turn_rad: NUM
    angle_cost_rad: NUM
    penalty_rad: NUM
    cost_rad: NUM


class DecisionMessage(Envelope, total=False):
    exit_index: int
    exit_heading_rad: NUM
    turn_rad: NUM
    turn_deg: NUM
    options: list[OptionShape]
    target: TargetShape | None
    intersection_id: int
    revisit: bool
    mode: str
    reason: str


class PromptMessage(Envelope, total=False):
    text: str
    kind: str
    priority: int


class MatchShape(TypedDict, total=False):
    landmark_id: int
    x_m: NUM
    y_m: NUM
    sigma_m: NUM
    score: NUM
    name: str


class RejectionShape(TypedDict, total=False):
    landmark_id: int | None
    reason: str
    detail: str


class LandmarkMessage(Envelope, total=False):
    gated: int | None
    matches: list[MatchShape]
    rejections: list[RejectionShape]


class HealthShape(TypedDict, total=False):
    """``guidance.core.messages.Health.as_dict()``."""

    name: str
    status: str
    alive: bool
    valid: bool
    ok: bool
    age_s: NUM
    rate_hz: NUM
    expected_rate_hz: NUM
    detail: str
    warning: str
    counters: dict[str, int]
    info: dict[str, str]


HEALTH_RECORD = Annotated[
    HealthShape,
    doc(
        description="guidance.core.messages.Health.as_dict(): one record for inputs and "
        "components"
    ),
]


class HealthMessage(Envelope, total=False):
    ok: bool
    inputs: dict[str, HEALTH_RECORD]
    components: Annotated[
        dict[str, Any],
        doc(
            description="by name: a Health record (telemetry, recorder, voice) or a "
            "free-form object (estimator, loop)"
        ),
    ]


class TurnMessage(Envelope, total=False):
    heading_change_rad: float | None
    heading_change_deg: float | None
    source: str


class ExitMessage(Envelope, total=False):
    intersection_id: int
    decision_t_s: float | None
    advised_exit: int
    taken_exit: int
    followed: bool
    source: str


MESSAGE_SHAPES: dict[str, type] = {
    "state": StateMessage,
    "decision": DecisionMessage,
    "prompt": PromptMessage,
    "landmark": LandmarkMessage,
    "health": HealthMessage,
    "turn": TurnMessage,
    "exit": ExitMessage,
}
"""Each output kind's message (the kinds are listed once, in ``guidance.outputs.kinds``)."""
