"""Every sentence the driver hears, in one table (openpilot's ``events.py``): ``SPEECH``.

What happens is data: a ``Say`` (``guidance.core.messages``) names the event (``Speech``) and
carries its numbers (a turn's angle and distance, a landmark's name, an input and its status,
a chance). ``words(say, units)`` is the only place they become English, with ``[navigation]
units`` applied here and nowhere else; the pipeline, the operator screen and the speech input
all speak through it, and drivers report a status, never a sentence (tests/test_layers.py).
One event has one sentence whoever noticed it first (an odometry dropout seen by the CAN
driver or by the pipeline's clock is "Wheel speed signal lost. ...").

Speaking them is ``guidance.voice``'s job. Distances are rounded the way turn-by-turn voices
round them (coarser as they grow), in metric or imperial. ``guidance.tools.voice_corpus`` says
every entry of the table (the intelligibility figure, docs/voice.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from enum import StrEnum

from guidance.core.messages import Say, Speech

METRES_PER_FOOT = 0.3048
METRES_PER_MILE = 1609.344

THEN_MAX_GAP_M = 150.0
"""Two turns closer than this are announced together ("..., then ...")."""


class Units(StrEnum):
    METRIC = "metric"
    IMPERIAL = "imperial"


def _round_to(value: float, step: float) -> float:
    return max(step, math.floor(value / step + 0.5) * step)


def _plural(n: float, one: str, many: str) -> str:
    return one if n == 1 else many


def format_distance(distance_m: float, units: Units = Units.METRIC) -> str:
    """Round a distance for speech: '50 metres', '250 metres', '1.5 kilometres', '500 feet'."""
    if not math.isfinite(distance_m) or distance_m < 0:
        raise ValueError(f"distance must be finite and non-negative, got {distance_m}")
    if units is Units.METRIC:
        if distance_m < 100:
            v = _round_to(distance_m, 10)
            return f"{v:.0f} {_plural(v, 'metre', 'metres')}"
        if distance_m < 975:
            v = _round_to(distance_m, 50)
            return f"{v:.0f} metres"
        km = distance_m / 1000.0
        if km < 9.95:
            v = round(km, 1)
            text = f"{v:.0f}" if v == int(v) else f"{v:.1f}"
            return f"{text} {_plural(v, 'kilometre', 'kilometres')}"
        v = float(round(km))
        return f"{v:.0f} kilometres"
    feet = distance_m / METRES_PER_FOOT
    if feet < 1000:
        v = _round_to(feet, 50)
        return f"{v:.0f} feet"
    miles = distance_m / METRES_PER_MILE
    if miles < 9.95:
        v = max(0.2, round(miles, 1))
        text = f"{v:.0f}" if v == int(v) else f"{v:.1f}"
        return f"{text} {_plural(v, 'mile', 'miles')}"
    v = float(round(miles))
    return f"{v:.0f} miles"


STRAIGHT_DEG, BEAR_DEG, TURN_DEG, SHARP_DEG = 20.0, 60.0, 135.0, 170.0
"""A turn's name changes at these angles (either side): straight below the first, then bear,
turn, sharp, and a U-turn from the last."""


def manoeuvre(turn_rad: float) -> str:
    """Name a turn by its angle (CCW positive = left)."""
    deg = math.degrees(turn_rad)
    a = abs(deg)
    side = "left" if deg > 0 else "right"
    if a < STRAIGHT_DEG:
        return "continue straight"
    if a < BEAR_DEG:
        return f"bear {side}"
    if a < TURN_DEG:
        return f"turn {side}"
    if a < SHARP_DEG:
        return f"turn sharp {side}"
    return "make a U-turn"


BEARINGS = ("north", "north-east", "east", "south-east", "south", "south-west", "west",
            "north-west")  # fmt: skip
"""The eight directions a road is named by when not even its side is known (45 degrees each)."""


def bearing_word(heading_rad: float) -> str:
    """A heading (CCW from east) as the nearest of ``BEARINGS`` (clockwise from north)."""
    bearing = (90.0 - math.degrees(heading_rad)) % 360.0
    return BEARINGS[int((bearing + 22.5) // 45.0) % 8]


def manoeuvre_within(turn_rad: float, band_rad: float, exit_heading_rad: float) -> str:
    """What can be said truly of a turn known to within +-``band_rad`` (the approach heading's
    uncertainty): its name (``manoeuvre``) when every turn in the band has that name; else
    its side ("go left", "go right") when every turn in the band is a left (or a right) turn
    short of a U-turn; else the direction of the road to take ("take the road towards the
    north-east", from ``exit_heading_rad``, which the scene gives without the car's heading
    error)."""
    name = manoeuvre(turn_rad)
    deg, band = math.degrees(turn_rad), math.degrees(max(0.0, band_rad))
    lo, hi = deg - band, deg + band
    bounds = (STRAIGHT_DEG, BEAR_DEG, TURN_DEG, SHARP_DEG)
    # the name changes going up through +c (at c) and through -c (just above it)
    if not any(lo < c <= hi or lo <= -c < hi for c in bounds):
        return name
    if lo >= STRAIGHT_DEG and hi < SHARP_DEG:
        return "go left"
    if lo > -SHARP_DEG and hi <= -STRAIGHT_DEG:
        return "go right"
    return f"take the road towards the {bearing_word(exit_heading_rad)}"


def turn_prompt(
    turn_rad: float,
    distance_m: float | None = None,
    units: Units = Units.METRIC,
    then_turn_rad: float | None = None,
    then_gap_m: float | None = None,
    *,
    action: str | None = None,
) -> str:
    """'At the next intersection, turn left', 'In 200 metres, turn right', 'Continue straight'.

    A second turn closer than ``THEN_MAX_GAP_M`` after the first is appended
    ('..., then turn right'). ``action``: the words for the turn when they are not its plain
    name (``manoeuvre_within``).
    """
    action = manoeuvre(turn_rad) if action is None else action
    if action == "continue straight" and distance_m is None:
        text = "Continue straight"
    elif distance_m is None:
        text = f"At the next intersection, {action}"
    else:
        text = f"In {format_distance(distance_m, units)}, {action}"
    if (
        then_turn_rad is not None
        and then_gap_m is not None
        and then_gap_m <= THEN_MAX_GAP_M
        and manoeuvre(then_turn_rad) != "continue straight"
    ):
        text += f", then {manoeuvre(then_turn_rad)}"
    return text


def _turn(p: Say, units: Units) -> str:
    """A turn instruction; a change said as one ("Change of plan: in 120 metres, turn
    right"), never silently; "again" for another intersection with the same words right after."""
    action = manoeuvre_within(p.turn_rad, p.band_rad, p.exit_heading_rad)
    text = turn_prompt(p.turn_rad, p.distance_m, units, p.then_turn_rad, p.then_gap_m,
                       action=action)  # fmt: skip
    if p.changed:
        text = f"Change of plan: {text[:1].lower()}{text[1:]}"
    return text + " again" if p.again else text


def _looks_like_an_id(name: str) -> bool:
    """'57', 'landmark 57', 'sim-00057', 'lm_57': numbering, not a name a driver can use."""
    words = name.replace("-", " ").replace("_", " ").split()
    return (
        any(ch.isdigit() for ch in words[-1])
        and len(words) <= 2
        and not any(
            w.isalpha() and len(w) > 2 and w.lower() not in ("landmark", "sim", "lm", "mark")
            for w in words
        )
    )


def _place(name: str) -> str:
    """A place's name as it may be said: "" for none, or for a bare number or internal id."""
    spoken = name.strip()
    return "" if not spoken or _looks_like_an_id(spoken) else spoken


def _landmark(p: Say, units: Units) -> str:
    """A landmark fix, said by the place's name ("Passing the town hall: position confirmed")."""
    place = _place(p.name)
    if not place:
        return "Landmark passed: position confirmed"
    return f"Passing {place}: position confirmed"


def _found(p: Say, units: Units) -> str:
    """A relocalisation: the place the whole-database search found, by its name (``again``
    False: the first place of a car that started anywhere)."""
    place = _place(p.name)
    found = "Position found again" if p.again else "Position found"
    return f"{found} near {place}" if place else f"{found} at a known landmark"


def _lost(p: Say, units: Units) -> str:
    """Said once when the position is lost; a car that looks for itself again says so."""
    if p.searching:
        return "Position lost. Guidance is unreliable; looking for a known place"
    return "Position lost. Guidance is unreliable; stop when safe"


SENSOR_WORDS: dict[str, dict[str, str]] = {
    "odometry": {
        "silent": "Wheel speed signal lost. Position is getting less certain.",
        "invalid": "Wheel speed data is unreliable. Position is getting less certain.",
        "disconnected": "Wheel speed bus disconnected. Position is getting less certain.",
    },
    "compass": {
        "silent": "Compass silent. Heading is getting less certain.",
        "invalid": "Compass data is unreliable. Heading is getting less certain.",
        "disconnected": "Compass disconnected. Heading is getting less certain.",
    },
    "camera": {
        "silent": "Camera stopped. Landmarks cannot be recognised.",
        "invalid": "Camera images are failing. Landmarks cannot be recognised.",
        "disconnected": "Camera lost. Landmarks cannot be recognised.",
    },
    "scene": {
        "silent": "Co-driver input silent. Intersections cannot be reported.",
        "invalid": "Co-driver input is failing. Intersections cannot be reported.",
        "disconnected": "Co-driver input lost. Intersections cannot be reported.",
    },
}
"""An input gone bad (docs/reliability.md), one sentence per input and status, whoever noticed
it: its driver (``DeviceStatus``) or the pipeline's health monitor."""

_PROBLEM = {"silent": "is silent", "invalid": "sends bad data", "disconnected": "is disconnected"}


def _sensor(p: Say, units: Units) -> str:
    words = SENSOR_WORDS.get(p.input, {}).get(p.status)
    if words is not None:
        return words
    return f"Warning: {p.input} {_PROBLEM.get(p.status, p.status)}"  # an input not listed


COMPONENT_WORDS: dict[str, dict[str, str]] = {
    "voice": {"text_fallback": "Voice prompts failed. Prompts are shown as text."},
    "telemetry": {"down": "Remote monitoring is offline."},
    "recorder": {
        "disk_full": "The disk is full: recording has stopped.",
        "failed": "The disk failed: recording has stopped.",
    },
}
"""A component of the car's own gone bad (its ``Health.warning``, docs/reliability.md), one
sentence per component and status: the voice's is shown, since it cannot be spoken; telemetry's
and the recorder's are for the operator (the car drives on without them)."""


def _component(p: Say, units: Units) -> str:
    words = COMPONENT_WORDS.get(p.input, {}).get(p.status)
    if words is not None:
        return words
    return f"Warning: {p.input or 'a component'} is {p.status or 'failing'}"  # one not listed


def _compass_unusable(p: Say, units: Units) -> str:
    """The compass readings cannot be used (``CompassJudge.reason``: uncalibrated,
    interference or gated)."""
    if p.status == "interference":
        return "Compass unusable: magnetic interference. Steering by wheel odometry."
    return "Compass unusable: calibrate it."


def _chance(p: Say, units: Units) -> str:
    """Rounded to 10 % above 10 %, so a number is not read as precise."""
    if p.chance < 0.1:
        return "Chance of reaching the destination is now below 10 percent."
    return (
        f"Chance of reaching the destination is now about {round(p.chance * 10) * 10:.0f} percent."
    )


_EXIT_WORDS = {"l": "left", "r": "right", "s": "straight", "bl": "bear left", "br": "bear right",
               "hl": "hard left", "hr": "hard right", "u": "U-turn"}  # fmt: skip


def _read_back(p: Say, units: Units) -> str:
    """What the car says back of a co-driver line: "l s r" -> "Left, straight, right.";
    "t l" -> "Turned left."; "repeat" -> "Repeat."."""
    tokens = p.line.split()
    if tokens and tokens[0] == "t":
        return f"Turned {', '.join(_EXIT_WORDS.get(t, t) for t in tokens[1:])}."
    words = ", ".join(_EXIT_WORDS.get(t, t) for t in tokens)
    return f"{words[:1].upper()}{words[1:]}."


SPEECH: dict[Speech, Callable[[Say, Units], str]] = {
    Speech.TURN: _turn,
    Speech.LANDMARK: _landmark,
    Speech.FOUND: _found,
    Speech.UNCERTAIN: lambda p, u: (
        f"Position uncertain, within {format_distance(p.distance_m or 0.0, u)}"
    ),
    Speech.NEW_DESTINATION: lambda p, u: (
        "New destination set remotely" if p.remote else "New destination set"
    ),
    Speech.ARRIVED: lambda p, u: "You have arrived at your destination",
    Speech.LOST: _lost,
    Speech.POSITION_UNKNOWN: lambda p, u: "Position unknown. Drive on; looking for a known place",
    Speech.WAITING_FOR_HEADING: lambda p, u: (
        "Waiting for a heading: no turn advice yet. Drive on, or give the start heading."
    ),
    Speech.SENSOR: _sensor,
    Speech.COMPASS_UNUSABLE: _compass_unusable,
    Speech.CHANCE: _chance,
    Speech.DIFFERENT_EXIT: lambda p, u: "Different exit taken. Guidance continues from here.",
    Speech.NO_CO_DRIVER_INPUT: lambda p, u: (
        "Warning: no co-driver input. Intersections cannot be reported."
    ),
    Speech.READ_BACK: _read_back,
    Speech.SAY_AGAIN: lambda p, u: "Please say that again.",
    Speech.REPORT_CANCELLED: lambda p, u: "The last report is cancelled.",
    Speech.CANNOT_CANCEL: lambda p, u: "Nothing to cancel.",
    Speech.COMPONENT: _component,
}
"""Every sentence the product says: an event's words from its numbers and the units."""

KIND: dict[Speech, str] = {
    Speech.TURN: "turn", Speech.LANDMARK: "landmark", Speech.FOUND: "found",
    Speech.UNCERTAIN: "uncertain", Speech.ARRIVED: "arrived", Speech.LOST: "lost",
    Speech.POSITION_UNKNOWN: "lost",
    Speech.SENSOR: "sensor", Speech.COMPASS_UNUSABLE: "sensor", Speech.CHANCE: "chance",
    Speech.NO_CO_DRIVER_INPUT: "sensor", Speech.COMPONENT: "sensor",
}  # fmt: skip
"""The published prompt's category (``Prompt.kind``); every other event is "info"."""


def words(say: Say, units: Units = Units.METRIC) -> str:
    """The sentence for ``say`` in ``units`` (the one place words are made)."""
    return SPEECH[say.speech](say, units)


def kind(say: Say) -> str:
    """The published category of ``say`` (``Prompt.kind``)."""
    return KIND.get(say.speech, "info")
