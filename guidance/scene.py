"""The roadway scene in the car: which exits the next intersection has, and which one was taken.

No sensor in the design sees intersections (SPEC section 6), so two things stand in for one
(docs/app.md, "Roadway scene"):

* the co-driver types what they see on a keyboard or keypad, one line per event
  (``parse_line``): the exits of the intersection ahead ("l s r", "s r", "l30 r"), or what the
  driver just did ("turned left", "tl");
* ``TurnDetector`` watches the estimated heading and reports each completed turn, so the
  navigator records what the driver actually did even when nobody types it.

``KeyboardScene`` is the ``RoadwayScene`` source: a thread reads lines from stdin (or any text
stream) and hands the parsed events to the app's sink. Exit directions are typed relative to the
car and converted to the filter frame with the estimated heading at the moment the line arrives.
"""

from __future__ import annotations

import logging
import math
import re
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

from guidance.messages import IntersectionScene, TurnCompleted
from guidance.model import wrap_angle

log = logging.getLogger(__name__)

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

_ANGLE_RE = re.compile(r"^([lr])(\d+(?:\.\d+)?)$")
_NUMBER_RE = re.compile(r"^[+-]\d+(?:\.\d+)?$")
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


# --------------------------------------------------------------------------- turn detection


@dataclass(frozen=True, slots=True)
class TurnDetectorConfig:
    min_turn_rad: float = math.radians(45.0)
    """A heading change at least this large is a turn (an exit, not a lane change or a bend)."""
    window_m: float = 40.0
    """The change is measured over at most this much travel (a corner takes 10-25 m)."""
    settle_m: float = 8.0
    """The turn is complete once the heading has been steady over this much travel..."""
    settle_tol_rad: float = math.radians(8.0)
    """...within this tolerance."""


class TurnDetector:
    """Completed turns from the estimated heading against distance travelled (pure, no clock).

    ``update`` takes the estimate after each odometry step. Headings are unwrapped, so a
    U-turn is reported as about +-pi. After a report the window restarts, so one corner gives
    one report.
    """

    def __init__(self, config: TurnDetectorConfig | None = None) -> None:
        self.config = config or TurnDetectorConfig()
        self._samples: deque[tuple[float, float]] = deque()  # (odometer m, unwrapped heading)
        self._last_raw: float | None = None
        self._unwrapped = 0.0
        self.turns = 0

    def reset(self) -> None:
        self._samples.clear()
        self._last_raw = None

    def update(self, t_s: float, heading_rad: float, odometer_m: float) -> TurnCompleted | None:
        if self._last_raw is None:
            self._unwrapped = heading_rad
        else:
            self._unwrapped += wrap_angle(heading_rad - self._last_raw)
        self._last_raw = heading_rad
        cfg = self.config
        s = self._samples
        if s and odometer_m - s[-1][0] < 0.5:  # sample every half metre of travel
            return None
        s.append((odometer_m, self._unwrapped))
        while len(s) > 2 and odometer_m - s[1][0] >= cfg.window_m:
            s.popleft()
        change = self._unwrapped - s[0][1]
        if abs(change) < cfg.min_turn_rad:
            return None
        # Steady over the last settle_m?
        lo = hi = self._unwrapped
        steady_from = None
        for odo, h in reversed(s):
            lo, hi = min(lo, h), max(hi, h)
            if hi - lo > cfg.settle_tol_rad:
                break
            steady_from = odo
        if steady_from is None or odometer_m - steady_from < cfg.settle_m:
            return None
        self.turns += 1
        s.clear()
        s.append((odometer_m, self._unwrapped))
        return TurnCompleted(t_s, change, source="detected")

    def snapshot(self) -> dict[str, object]:
        return {
            "samples": [list(p) for p in self._samples],
            "last_raw": self._last_raw,
            "unwrapped": self._unwrapped,
            "turns": self.turns,
        }

    def restore(self, snap: dict[str, object]) -> None:
        samples = snap.get("samples", [])
        assert isinstance(samples, list)
        self._samples = deque((float(a), float(b)) for a, b in samples)
        last = snap.get("last_raw")
        self._last_raw = None if last is None else float(last)  # type: ignore[arg-type]
        self._unwrapped = float(snap.get("unwrapped", 0.0))  # type: ignore[arg-type]
        self.turns = int(snap.get("turns", 0))  # type: ignore[call-overload]


# --------------------------------------------------------------------------- the source


class KeyboardScene:
    """``RoadwayScene`` from co-driver lines on a text stream (stdin by default).

    A daemon thread reads lines (blocking I/O stays off the event loop, HOUSE_STYLE) and calls
    ``sink`` with an ``IntersectionScene`` or ``TurnCompleted``. ``heading_fn`` gives the
    current estimated heading (rad) for turning relative exits into absolute ones; ``clock``
    stamps the line (the message clock). Unparseable lines are counted, logged and answered on
    ``feedback`` (stderr) so the co-driver can retype them.
    """

    def __init__(
        self,
        heading_fn: Callable[[], float],
        *,
        stream: TextIO | None = None,
        feedback: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        name: str = "keyboard",
    ) -> None:
        self.name = name
        self._heading_fn = heading_fn
        self._stream = stream
        self._feedback = feedback
        self._clock = clock
        self._counts: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def start(self, sink: Callable[[IntersectionScene | TurnCompleted], None]) -> None:
        if self._thread is not None:
            raise RuntimeError(f"{self.name} already started")
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._run, args=(sink,), name=f"{self.name}-reader", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop taking lines. A thread blocked in ``readline`` on a terminal cannot be woken;
        it is a daemon and delivers nothing after this."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=0.2)

    def stats(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def handle_line(
        self, line: str, sink: Callable[[IntersectionScene | TurnCompleted], None]
    ) -> IntersectionScene | TurnCompleted | None:
        """Parse one line and deliver it; returns what was delivered (for tests and replay)."""
        t_s = self._clock()
        with self._lock:
            self._counts["lines"] += 1
        try:
            typed = parse_line(line)
        except SceneParseError as exc:
            with self._lock:
                self._counts["rejected"] += 1
            log.info("%s: %s", self.name, exc)
            out = self._feedback if self._feedback is not None else sys.stderr
            out.write(f"? {exc}\n")
            out.flush()
            return None
        if typed is None:
            return None
        msg = to_scene(typed, t_s, self._heading_fn())
        with self._lock:
            self._counts["intersections" if isinstance(msg, IntersectionScene) else "turns"] += 1
        sink(msg)
        return msg

    def _run(self, sink: Callable[[IntersectionScene | TurnCompleted], None]) -> None:
        stream = self._stream if self._stream is not None else sys.stdin
        while not self._stop.is_set():
            try:
                line = stream.readline()
            except (OSError, ValueError) as exc:  # closed stream
                log.warning("%s: input closed (%s)", self.name, exc)
                return
            if not line:  # end of input: the co-driver's keyboard is gone
                log.info("%s: end of input", self.name)
                return
            if self._stop.is_set():
                return
            try:
                self.handle_line(line, sink)
            except Exception:
                log.exception("%s: the scene sink raised; continuing", self.name)
