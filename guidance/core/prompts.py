"""Driver phrases: pure functions from decisions and events to short spoken text.

Speaking them is ``guidance.voice``'s job. Distances are rounded the way
turn-by-turn voices round them (coarser as they grow), in metric or imperial.
"""

from __future__ import annotations

import math
from enum import StrEnum

from guidance.core.plan.navigator import Decision

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


def decision_prompt(
    decision: Decision, distance_m: float | None = None, units: Units = Units.METRIC
) -> str:
    """The phrase for a navigator decision."""
    return turn_prompt(decision.turn_rad, distance_m, units)


def changed(text: str) -> str:
    """A new instruction for an intersection already announced: said as a change, never
    silently ("Change of plan: in 120 metres, turn right")."""
    return f"Change of plan: {text[:1].lower()}{text[1:]}"


def landmark_confirmed(name: str = "") -> str:
    """A landmark fix, said by the place's name ("Passing the town hall: position confirmed");
    a bare number or an internal id is never read out."""
    spoken = name.strip()
    if not spoken or _looks_like_an_id(spoken):
        return "Landmark passed: position confirmed"
    return f"Passing {spoken}: position confirmed"


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


def position_uncertain(major_axis_m: float, units: Units = Units.METRIC) -> str:
    return f"Position uncertain, within {format_distance(major_axis_m, units)}"


def new_destination(remote: bool) -> str:
    """A new goal was set (by the operator, or by a remote monitor)."""
    return "New destination set remotely" if remote else "New destination set"


def arrived() -> str:
    return "You have arrived at your destination"


def lost(searching: bool = False) -> str:
    """Said once when the position is lost; a car that looks for itself again says so."""
    if searching:
        return "Position lost. Guidance is unreliable; looking for a known place"
    return "Position lost. Guidance is unreliable; stop when safe"


def position_found(name: str = "", again: bool = True) -> str:
    """A relocalisation: the place the whole-database search found, by its name (``again``
    False: the first place of a car that started anywhere)."""
    spoken = name.strip()
    found = "Position found again" if again else "Position found"
    if not spoken or _looks_like_an_id(spoken):
        return f"{found} at a known landmark"
    return f"{found} near {spoken}"


def position_unknown() -> str:
    """Said once at the start of a car that starts anywhere (``[start]`` gives no position)."""
    return "Position unknown. Drive on; looking for a known place"


def sensor_warning(sensor: str, problem: str) -> str:
    return f"Warning: {sensor} {problem}"


def compass_unusable(reason: str) -> str:
    """The compass readings cannot be used (``CompassJudge.reason``: uncalibrated,
    interference or gated)."""
    if reason == "interference":
        return "Compass unusable: magnetic interference. Steering by wheel odometry."
    return "Compass unusable: calibrate it."


def waiting_for_heading() -> str:
    """No compass reading yet and no start heading: no turn advice until there is one."""
    return "Waiting for a heading: no turn advice yet. Drive on, or give the start heading."
