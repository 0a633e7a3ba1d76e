"""Co-driver lines (pure parsing): what the co-driver types about the roadway scene.

No sensor in the design sees intersections (SPEC section 6), so the co-driver types what they
see, one line per event (``parse_line``): the exits of the intersection ahead ("l s r", "s r",
"l30 r"), or what the driver just did ("turned left", "tl"). Exit directions are typed relative
to the car and converted to the filter frame with the estimated heading (``to_scene``). The
reader that delivers the lines is ``drivers.keyboard.KeyboardScene``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from guidance.core.messages import IntersectionScene, TurnCompleted
from guidance.core.model import wrap_angle

# Relative exit directions, radians CCW (left positive), by keyboard token.
EXIT_TOKENS: dict[str, float] = {
    "s": 0.0,
    "f": 0.0,
    "straight": 0.0,
    "ahead": 0.0,
    "l": math.pi / 2,
    "left": math.pi / 2,
    "r": -math.pi / 2,
    "right": -math.pi / 2,
    "bl": math.pi / 4,
    "br": -math.pi / 4,
    "hl": 3 * math.pi / 4,
    "hr": -3 * math.pi / 4,
    "u": math.pi,
    "uturn": math.pi,
}
"""``s``/``f`` straight, ``l``/``r`` left/right (90 deg), ``bl``/``br`` bear (45 deg),
``hl``/``hr`` hard (135 deg), ``u`` U-turn. Keypad digits map like a phone pad seen from
above: 8 straight, 4 left, 6 right, 7/9 bear left/right, 1/3 hard left/right, 2 U-turn."""

KEYPAD_DIGITS: dict[str, str] = {
    "8": "s",
    "4": "l",
    "6": "r",
    "7": "bl",
    "9": "br",
    "1": "hl",
    "3": "hr",
    "2": "u",
}

_ANGLE_RE = re.compile(r"^([lr])([0-9]{1,3}(?:\.[0-9]{1,3})?)$")
_NUMBER_RE = re.compile(r"^[+-][0-9]{1,3}(?:\.[0-9]{1,3})?$")
"""Angles in ASCII digits only (``float`` takes "١٢٠" and "1_20"), at most 3 before the point."""
MAX_LINE_CHARS = 80
"""A report is a few tokens ("bl s r", "+30 -120 u", "turned left"): a longer line is refused
before it is split (an 8 MB line once cost the car 120 MB and a blocked loop)."""
MAX_EXITS = 8
"""At most eight exits at one intersection: eight directions 45 degrees apart (a report of
33,334 "lsr" exits once blocked the loop for 1.5 s)."""
_TURN_PREFIXES = ("turned", "took", "went", "t")


class SceneParseError(ValueError):
    """A keyboard line that is neither a list of exits nor a turn report."""


@dataclass(frozen=True, slots=True)
class ExitsTyped:
    """Exits typed by the co-driver, relative to the car (rad, CCW positive), with labels."""

    relative_rad: tuple[float, ...]
    labels: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class TurnTyped:
    """The co-driver reports the turn just taken (rad, CCW positive)."""

    relative_rad: float
    label: str


def _direction(token: str) -> tuple[float, str]:
    """One exit token -> (relative angle rad, label); raises SceneParseError."""
    tok = KEYPAD_DIGITS.get(token, token)
    if tok in EXIT_TOKENS:
        return EXIT_TOKENS[tok], tok
    m = _ANGLE_RE.match(tok)
    if m:
        deg = float(m.group(2))
        if deg > 180.0:
            raise SceneParseError(f"angle {token!r} is above 180 degrees")
        return math.radians(deg if m.group(1) == "l" else -deg), tok
    if _NUMBER_RE.match(tok):
        deg = float(tok)
        if abs(deg) > 180.0:
            raise SceneParseError(f"angle {token!r} is outside [-180, 180] degrees")
        return math.radians(deg), tok
    raise SceneParseError(
        f"unknown exit {token!r}: use s l r bl br hl hr u, keypad 8 4 6 7 9 1 3 2, "
        "l30/r30, or signed degrees left-positive (+30, -45)"
    )


def parse_line(line: str) -> ExitsTyped | TurnTyped | None:
    """Parse one co-driver line; None for an empty line.

    Exits: tokens separated by spaces or commas, a run of single letters ("lsr"), keypad digits
    ("846": each digit is one key), or signed angles in degrees, left positive ("+30 -90").
    Turn reports: "turned left", "took r", "t l", "tl", "went straight", "t 8".
    """
    if len(line) > MAX_LINE_CHARS:
        raise SceneParseError(f"a line of {len(line)} characters (at most {MAX_LINE_CHARS})")
    text = line.strip().lower().replace(",", " ")
    if not text:
        return None
    words = text.split()
    if words[0] in _TURN_PREFIXES or (
        len(words) == 1 and len(words[0]) >= 2 and words[0][0] == "t" and words[0] != "turned"
    ):
        rest = words[1:] if words[0] in _TURN_PREFIXES else [words[0][1:]]
        if len(rest) != 1:
            raise SceneParseError(
                f"a turn report names one direction, e.g. 'turned left': {line!r}"
            )
        angle, label = _direction(rest[0])
        return TurnTyped(angle, label)
    if len(words) == 1 and words[0] not in EXIT_TOKENS and set(words[0]) <= set("sflru"):
        words = list(words[0])  # "lsr"
    words = [k for w in words for k in (list(w) if w.isdigit() else [w])]  # keypad "846"
    if len(words) > MAX_EXITS:
        raise SceneParseError(f"{len(words)} exits (at most {MAX_EXITS} at one intersection)")
    exits = [_direction(w) for w in words]
    return ExitsTyped(tuple(a for a, _ in exits), tuple(lab for _, lab in exits))


def to_scene(
    typed: ExitsTyped | TurnTyped, t_s: float, heading_rad: float
) -> IntersectionScene | TurnCompleted:
    """Typed event -> message: exits become absolute headings using the estimated heading."""
    if isinstance(typed, TurnTyped):
        return TurnCompleted(t_s, typed.relative_rad, source="co-driver")
    headings = tuple(wrap_angle(heading_rad + a) for a in typed.relative_rad)
    return IntersectionScene(t_s, headings, None, typed.labels)
