"""What ``guidance monitor`` knows about each car, and how its terminal view is drawn.

``FleetView`` folds telemetry events into one ``CarView`` per car (pure, no I/O).
``render_table`` returns a rich renderable that picks its layout from the space it is
given: a table when the output is a terminal wide enough for every column without
splitting a number, otherwise one block per car (its numbers packed into whole
``label value unit`` fields, then its health and last prompt) that never splits a value
either, at 80 columns or piped into a file. Headings are shown as compass headings
(degrees clockwise from north); the messages carry them counter-clockwise from east.
Text from the cars (prompts, ids, health names) is shown as plain text: never parsed
as rich markup, terminal control characters removed.
"""

from __future__ import annotations

import itertools
import math
import re
import textwrap
import unicodedata
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rich.cells import cell_len

from guidance.core.angles import heading_to_compass
from guidance.core.plan.chance import shown
from guidance.tools.monitor_check import MAX_NUMBER, message_problem
from guidance.tools.monitor_ids import Publishers

if TYPE_CHECKING:  # rich's renderables load when the live view first draws
    from rich.console import Console, ConsoleOptions, RenderResult
    from rich.table import Table
    from rich.text import Text

TRACK_POINTS = 20_000
"""Points kept per car (40 km of driving at ``TRACK_STEP_M``)."""
TRACK_STEP_M = 2.0
"""A car's track keeps a point when it is this far from the last one kept (the newest position
is always its last point, replaced until it is): a track drawn at city scale shows nothing
finer, and 1,000 cars at 10 Hz would otherwise keep 10,000 points a second."""
ELLIPSE_EVERY_S = 10.0
"""Keep one past ellipse per car this often (car time) for the snapshot."""

HEADING_CONVENTION = "hdg: compass heading, degrees clockwise from north"
KEYS_HELP = "s: snapshot PNG   q: quit"


# -- what the monitor knows about each car ---------------------------------------------------
@dataclass(slots=True)
class CarView:
    vehicle_id: str
    alive: bool = True
    state: Mapping[str, Any] | None = None
    prompt: str = ""
    health: Mapping[str, Any] | None = None
    last_received_s: float | None = None
    messages: int = 0
    bad_messages: int = 0
    """Messages that failed ``monitor_check.message_problem``: counted, never shown."""
    last_bad: str = ""
    """Why the last bad message was bad (one short line)."""
    gaps: int = 0
    """Messages missing from the sequence numbers (dropped by the car or the network)."""
    track: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=TRACK_POINTS))
    track_stamps: deque[int] = field(default_factory=lambda: deque(maxlen=TRACK_POINTS))
    """The fleet's ``generation`` at which each track point was last written (non-decreasing):
    what changed since a reader's last look is the tail stamped after it."""
    track_total: int = 0
    """Points ever appended: the track's last point is point ``track_total - 1`` of the car."""
    ellipses: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    """(x_m, y_m, semi_major_m, semi_minor_m, orientation_rad), one every ELLIPSE_EVERY_S."""
    gone_s: float | None = None
    """Monitor clock when its liveliness token dropped (None while alive)."""
    alarm: str = ""
    """Two publishers behind this id (``monitor_ids``), or ""."""
    publishers: Publishers = field(default_factory=Publishers)
    _last_seq: dict[str, int] = field(default_factory=dict)
    _last_ellipse_t_s: float = -math.inf
    _track_open: bool = False
    """Whether the track's last point is the newest position, not yet ``TRACK_STEP_M`` from
    the one before it (replaced by the next)."""

    def track_since(
        self, generation: int, limit: int | None = None
    ) -> tuple[int, list[tuple[float, float]]] | None:
        """The track points written after ``generation`` and the car's index of the first of
        them (``track_total`` when none); None when there are more than ``limit``. The cost is
        that of the points returned (at most ``limit`` + 1 looked at), not of the track."""
        n = 0
        for stamp in reversed(self.track_stamps):
            if stamp <= generation:
                break
            if limit is not None and n >= limit:
                return None
            n += 1
        tail = list(itertools.islice(reversed(self.track), n))
        tail.reverse()
        return self.track_total - n, tail


class FleetView:
    """Folds telemetry events into one ``CarView`` per car."""

    def __init__(self) -> None:
        self.cars: dict[str, CarView] = {}
        self.gone: dict[str, CarView] = {}
        self.messages = 0
        self.bad_messages = 0
        self.generation = 0
        """Counts the track points written (``CarView.track_stamps``)."""
        self.alarm_changes: list[str] = []
        """Cars whose alarm came or went since the last ``take_alarm_changes``."""

    def take_alarm_changes(self) -> list[str]:
        changes, self.alarm_changes = self.alarm_changes, []
        return changes

    def apply(self, event: Any) -> bool:
        """Fold one ``TelemetryEvent`` in; False when it told nothing new (a repeated
        late-join reply) or its message is bad (``monitor_check``: against the message
        schemas and limits; counted per car, never folded in or shown)."""
        vid = event.vehicle_id
        if event.kind == "gone":
            car = self.cars.pop(vid, None)
            if car is not None:
                car.alive = False
                car.gone_s = event.received_s
                self.gone[vid] = car
            return True
        car = self.cars.get(vid)
        if car is None:
            car = self.gone.pop(vid, None) or CarView(vid)
            car.alive, car.gone_s = True, None
            self.cars[vid] = car
        if event.kind == "alive" or event.message is None:
            return True
        msg = event.message
        why = message_problem(event.kind, msg)
        if why is not None:
            self.bad_messages += 1
            car.bad_messages += 1
            car.last_bad = f"{plain(event.kind)}: {plain(why)}"
            return False
        if not event.late_join:
            self._publishers(car, event)
        seq = msg.get("seq")
        if isinstance(seq, int):
            last = car._last_seq.get(event.kind)
            if event.late_join and last is not None:
                return False  # live (or queried) messages already arrived; this one is older
            if last is not None and seq > last + 1:
                car.gaps += seq - last - 1
            if last is None or seq > last or seq == 1:
                car._last_seq[event.kind] = seq
        self.messages += 1
        car.messages += 1
        car.last_received_s = event.received_s
        if event.kind == "state":
            self._apply_state(car, msg)
        elif event.kind == "prompt":
            car.prompt = str(msg.get("text", ""))
        elif event.kind == "health":
            car.health = msg
        return True

    def _publishers(self, car: CarView, event: Any) -> None:
        """Two publishers behind one id (``monitor_ids``): the alarm shown on the car; its
        coming and going recorded in ``alarm_changes``."""
        source = getattr(event, "source", "")
        alarm = car.publishers.see(event.kind, event.message, source, event.received_s)
        if bool(alarm) != bool(car.alarm):
            self.alarm_changes.append(car.vehicle_id)
        car.alarm = alarm

    def _apply_state(self, car: CarView, msg: Mapping[str, Any]) -> None:
        car.state = msg
        x, y = msg.get("x_m"), msg.get("y_m")
        if not (isinstance(x, int | float) and isinstance(y, int | float)):
            return
        self._track_point(car, float(x), float(y))
        t_s = msg.get("t_s")
        ell = msg.get("ellipse") or {}
        if isinstance(t_s, int | float) and t_s - car._last_ellipse_t_s >= ELLIPSE_EVERY_S:
            axes = [ell.get(k) for k in ("semi_major_m", "semi_minor_m", "orientation_rad")]
            nums = [float(v) for v in axes if isinstance(v, int | float)]
            if len(nums) == 3:
                car.ellipses.append((float(x), float(y), nums[0], nums[1], nums[2]))
                car._last_ellipse_t_s = float(t_s)

    def _track_point(self, car: CarView, x: float, y: float) -> None:
        self.generation += 1
        track, stamps = car.track, car.track_stamps
        anchor = len(track) - 1 - car._track_open  # the last point kept for good
        if anchor >= 0:
            ax, ay = track[anchor]
            far = math.hypot(x - ax, y - ay) >= TRACK_STEP_M
            if car._track_open:
                track[-1], stamps[-1] = (x, y), self.generation
                car._track_open = not far
                return
            if not far:
                car._track_open = True
        track.append((x, y))
        stamps.append(self.generation)
        car.track_total += 1


# -- row values ------------------------------------------------------------------------------
_ANSI = re.compile(r"\x1b(\[[0-?]*[ -/]*[@-~]|\][^\x07\x1b]*(\x07|\x1b\\)?|[@-Z\\-_])")
_SPACES = re.compile(r"[\t\n\r\v\f\x85\u2028\u2029]+")


def plain(value: object) -> str:
    """Text from a car made safe for a terminal: escape sequences and control/format
    characters removed, line breaks and tabs turned into spaces."""
    text = _SPACES.sub(" ", _ANSI.sub("", str(value)))
    return "".join(ch for ch in text if unicodedata.category(ch)[0] != "C")


def compass_deg(heading_rad: float) -> float:
    """Heading counter-clockwise from east (rad) as a compass heading: degrees clockwise
    from north in [0, 360)."""
    deg = float(heading_to_compass(heading_rad, 0.0))
    return 0.0 if deg >= 359.5 else deg  # shown rounded: 359.7 reads as 0, not 360


def _num(value: object) -> float | None:
    if isinstance(value, float) and math.isfinite(value) and abs(value) <= MAX_NUMBER:
        return value
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) <= MAX_NUMBER:
        return float(value)
    return None


def _mapping(value: object) -> Mapping[str, Any]:
    """A JSON object as a mapping; anything else (a component's free-form health) as empty."""
    return value if isinstance(value, Mapping) else {}


def bad_summary(car: CarView) -> str:
    """ "" or e.g. "2 bad messages (state: ellipse: [] is not of type 'object')"."""
    if not car.bad_messages:
        return ""
    n = car.bad_messages
    return f"{n} bad message{'s' if n > 1 else ''} ({car.last_bad})"


def _fmt(value: object, spec: str = ".1f", unit: str = "") -> str:
    num = _num(value)
    return "-" if num is None else f"{num:{spec}}{unit}"


def health_problems(health: Mapping[str, Any] | None) -> str:
    """ "ok", or the inputs that are down or invalid, e.g. "compass down, camera invalid"."""
    if health is None:
        return "-"
    problems = []
    for name, h in sorted(_mapping(health.get("inputs")).items()):
        h = _mapping(h)
        if not h.get("alive", False):
            problems.append(f"{plain(name)} down")
        elif not h.get("valid", False):
            problems.append(f"{plain(name)} invalid")
    return ", ".join(problems) if problems else "ok"


DROPPED_REASONS = {
    "superseded": "replaced by a newer one before it was sent",
    "fifo_full": "pushed out of a full queue",
    "session_down": "made while the car had no zenoh session",
    "put_error": "refused by zenoh",
    "encode_error": "could not be encoded",
}
DROPPED_HELP = "dropped: messages the car made but did not send"


def dropped(health: Mapping[str, Any] | None) -> tuple[int, dict[str, int]]:
    """The car's own count of telemetry messages it did not send, and by reason (its health
    message's ``components.telemetry.counters``: ``dropped`` and ``dropped_<reason>``)."""
    counters = _mapping(_mapping(_mapping(_mapping(health).get("components")).get("telemetry"))
                        .get("counters"))  # fmt: skip
    total = int(_num(counters.get("dropped")) or 0)
    reasons = {
        plain(k.removeprefix("dropped_")): int(n)
        for k, v in counters.items()
        if isinstance(k, str) and k.startswith("dropped_") and (n := _num(v))
    }
    return total, dict(sorted(reasons.items()))


def dropped_text(health: Mapping[str, Any] | None) -> str:
    """ "" or what the dropped messages were, e.g. "31 telemetry messages not sent by the car:
    30 replaced by a newer one before it was sent, 1 made while the car had no zenoh
    session"."""
    total, reasons = dropped(health)
    if not total:
        return ""
    parts = [f"{n} {DROPPED_REASONS.get(r, r)}" for r, n in reasons.items()]
    text = f"{total} telemetry message{'s' if total > 1 else ''} not sent by the car"
    return f"{text}: {', '.join(parts)}" if parts else text


def health_summary(health: Mapping[str, Any] | None) -> str:
    """ "ok", or the inputs that are down or invalid, e.g. "compass down, camera invalid";
    with "(N dropped)" when the car's telemetry dropped messages (``DROPPED_HELP``)."""
    text = health_problems(health)
    drops = dropped(health)[0]
    return f"{text} ({drops} dropped)" if drops else text


def gone_summary(car: CarView, now_s: float) -> str:
    """What a gone car's health cell says: when its liveliness token dropped (its process
    ended or its link went) and that the position shown is its last."""
    ago = "" if car.gone_s is None else f" {_fmt(max(0.0, now_s - car.gone_s), '.0f')} s ago"
    where = " (last position)" if car.state else " (no position received)"
    return f"GONE{ago}: liveliness token dropped{where}"


def _heading(state: Mapping[str, Any]) -> float | None:
    rad = _num(state.get("heading_rad"))
    if rad is None and (deg := _num(state.get("heading_deg"))) is not None:
        rad = math.radians(deg)
    return None if rad is None else compass_deg(rad)


def car_row(car: CarView, now_s: float) -> dict[str, str]:
    """One car's values as display strings (what both layouts show, and what tests check)."""
    s = car.state or {}
    target = s.get("target") or {}
    x, y = _num(s.get("x_m")), _num(s.get("y_m"))
    tx, ty = _num(target.get("x_m")), _num(target.get("y_m"))
    dist = None
    if None not in (x, y, tx, ty):
        dist = math.hypot(tx - x, ty - y)  # type: ignore[operator]
    age = None if car.last_received_s is None else now_s - car.last_received_s
    health = ", ".join(t for t in (health_summary(car.health), bad_summary(car)) if t)
    if not car.alive:
        health = gone_summary(car, now_s)
    if car.alarm:
        health = f"{car.alarm}; {health}"
    return {
        "car": plain(car.vehicle_id),
        "x_m": _fmt(x),
        "y_m": _fmt(y),
        "compass_deg": _fmt(_heading(s), ".0f"),
        "major_axis_m": _fmt((s.get("ellipse") or {}).get("major_axis_m"))
        + (" LOST" if s.get("lost") else ""),
        "chance": shown(_num(s.get("chance"))),
        "target": (
            f"{plain(target.get('kind', '?'))} ({_fmt(tx, '.0f')}, {_fmt(ty, '.0f')})"
            if target
            else "-"
        ),
        "distance_m": _fmt(dist, ".0f"),
        "prompt": plain(car.prompt) or "-",
        "health": health,
        "age_s": _fmt(age, ".1f"),
    }


# -- layouts ---------------------------------------------------------------------------------
_COLUMNS = (
    # key, header, may wrap between words
    ("car", "car", False),
    ("x_m", "x m", False),
    ("y_m", "y m", False),
    ("compass_deg", "hdg °", False),
    ("major_axis_m", "major axis m", False),
    ("chance", "chance", False),
    ("target", "target", False),
    ("distance_m", "to target m", False),
    ("age_s", "age s", False),
    ("health", "health", True),
    ("prompt", "last prompt", True),
)
_MIN_WRAP_WIDTH = {"health": 12, "prompt": 24}
"""Narrowest a wrapping column may get before the table gives way to the per-car layout."""


def _words_width(text: str) -> int:
    return max((cell_len(w) for w in text.split()), default=0)


def _column_widths(rows: list[dict[str, str]]) -> dict[str, int]:
    """Each column's width so that no value is split: a no-wrap column at its widest cell or
    header (rich does not wrap a no-wrap column's header either), a wrapping column at its
    minimum (``_MIN_WRAP_WIDTH``, or less when nothing in it is that wide, and never below its
    longest word). The table is built with these minimums, so the estimate is rich's own."""
    widths = {}
    for key, header, wraps in _COLUMNS:
        cells = [r[key] for r in rows]
        if wraps:
            natural = max([cell_len(c) for c in cells] + [cell_len(header)])
            widths[key] = max(
                min(natural, _MIN_WRAP_WIDTH[key]), _words_width(header), *map(_words_width, cells)
            )
        else:
            widths[key] = max([cell_len(c) for c in cells] + [cell_len(header)])
    return widths


def _table_width(rows: list[dict[str, str]]) -> int:
    """Width the table needs (``_column_widths`` plus one space each side and the borders)."""
    return 1 + sum(w + 3 for w in _column_widths(rows).values())


def _pack(fields: list[str], width: int, indent: str) -> list[str]:
    """Greedily pack whole fields into lines of at most ``width`` cells (a field longer
    than a line gets a line of its own)."""
    lines: list[str] = []
    line = ""
    for f in fields:
        candidate = f if not line else f"{line}  {f}"
        if line and cell_len(candidate) > width:
            lines.append(line)
            line = f"{indent}{f}"
        else:
            line = candidate
    if line:
        lines.append(line)
    return lines


def _unit(label: str, value: str, unit: str) -> str:
    return f"{label} -" if value == "-" else f"{label} {value}{unit}"


def car_lines(row: dict[str, str], width: int) -> list[str]:
    """The per-car layout: the numbers as whole fields, then health and the last prompt."""
    indent = "    "
    lost = row["major_axis_m"].endswith(" LOST")
    axis = row["major_axis_m"].removesuffix(" LOST")
    fields = [
        row["car"],
        _unit("x", row["x_m"], " m"),
        _unit("y", row["y_m"], " m"),
        _unit("hdg", row["compass_deg"], "°"),
        _unit("axis", axis, " m") + (" LOST" if lost else ""),
    ]
    if row["chance"] != "-":
        fields.append(f"chance {row['chance']}")
    if row["target"] != "-":
        fields.append(f"to {row['target']}: " + _unit("", row["distance_m"], " m").strip())
    fields += [_unit("age", row["age_s"], " s"), f"health: {row['health']}"]
    lines = _pack(fields, width, indent)
    if row["prompt"] != "-":
        lines += textwrap.wrap(
            f'prompt: "{row["prompt"]}"',
            width=max(20, width),
            initial_indent=indent,
            subsequent_indent=indent + "  ",
            break_long_words=False,
            break_on_hyphens=False,
        )
    return lines


@dataclass(slots=True)
class FleetRender:
    """The fleet as the monitor shows it; lays itself out for the width it is given."""

    rows: list[dict[str, str]]
    title: str
    caption: str
    cars: int = -1
    """Cars known (-1: as many as rows); those beyond what fits are counted, not shown."""

    def _more(self, shown: int) -> str:
        n = max(self.cars, len(self.rows)) - shown
        return f"{n} more car{'s' if n > 1 else ''} not shown (a taller terminal, --json or --web)"

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        width = options.max_width
        height = options.height or options.max_height
        if options.is_terminal and self.rows and _table_width(self.rows) <= width:
            from rich.segment import Segment

            fit = max(1, height - 8)  # title 2, header 3, borders 2, caption 1
            if len(self.rows) > fit or self.cars > len(self.rows):
                fit = max(1, fit - 1)
                shown = FleetRender(self.rows[:fit], self.title,
                                    f"{self._more(fit)}   {self.caption}")  # fmt: skip
                yield from shown.__rich_console__(console, options)
                return
            table = self._table()
            # rich's own layout decides, rendered uncropped: the console would cut a table
            # wider than the screen at its right edge (its widths can exceed the estimate)
            lines = Segment.split_lines(console.render(table, options.update(width=width)))
            if all(Segment.get_line_length(line) <= width for line in lines):
                yield table
                return
        yield from self._lines(width, height if options.is_terminal else None)

    def _table(self) -> Table:
        from rich.table import Table
        from rich.text import Text

        table = Table(
            title=Text(f"{self.title}\n{HEADING_CONVENTION}"),
            caption=Text(self.caption),
            expand=False,
        )
        widths = _column_widths(self.rows)
        for key, header, wraps in _COLUMNS:
            table.add_column(
                header,
                no_wrap=not wraps,
                overflow="fold",
                justify="right" if key.endswith(("_m", "_s", "_deg")) else "left",
                min_width=widths[key] if wraps else None,
            )
        for row in self.rows:
            table.add_row(*(Text(row[k]) for k, _, _ in _COLUMNS), style=_style(row))
        return table

    def _lines(self, width: int, height: int | None) -> Iterator[Text]:
        """One block per car; with ``height`` (a terminal's), as many as fit and a count."""
        from rich.text import Text

        yield Text(self.title, style="bold")
        header = textwrap.wrap(f"{HEADING_CONVENTION}   {self.caption}", width=max(20, width),
                               subsequent_indent="    ", break_long_words=False)  # fmt: skip
        yield Text("\n".join(header), style="dim")
        if not self.rows:
            yield Text("(no car seen yet)")
        room = None if height is None else height - 1 - len(header)
        for i, row in enumerate(self.rows):
            block = car_lines(row, width)
            if room is not None and len(block) > room - 1:  # a line kept for the count
                yield Text(self._more(i), style="dim")
                return
            if room is not None:
                room -= len(block)
            yield Text("\n".join(block), style=_style(row) or "")
        if self.cars > len(self.rows):
            yield Text(self._more(len(self.rows)), style="dim")


def _style(row: dict[str, str]) -> str | None:
    if row["health"].startswith("GONE"):
        return "bold yellow"  # readable on dark and light backgrounds, unlike dim grey
    return "red" if row["major_axis_m"].endswith("LOST") else None


SHOWN_AT_MOST = 200
"""Cars laid out per draw at most (no terminal is taller): a table of 1,000 took 2 s to draw,
and the live view folds no message while it draws."""


def _needs_a_look(car: CarView) -> bool:
    s, health = car.state or {}, car.health or {}
    return bool(s.get("lost")) or health.get("ok") is False or car.bad_messages > 0


def render_table(view: FleetView, now_s: float, title: str, status: str = "") -> FleetRender:
    """The live view of every car seen: the live ones sorted by id, then the gone ones (a car
    whose liveliness token dropped stays, marked GONE, with its last position). When more cars
    than fit are known, those that need a look come first (gone, lost, health not ok, bad
    messages), and the view says how many are not shown."""
    live = [view.cars[vid] for vid in sorted(view.cars)]
    gone = [view.gone[vid] for vid in sorted(view.gone, key=lambda v: -(view.gone[v].gone_s or 0))]
    cars = live + gone
    if len(cars) > SHOWN_AT_MOST:
        look = [_needs_a_look(c) for c in live]
        first = [c for c, needs in zip(live, look, strict=True) if needs]
        rest = [c for c, needs in zip(live, look, strict=True) if not needs]
        cars = (gone + first + rest)[:SHOWN_AT_MOST]
    rows = [car_row(car, now_s) for car in cars]
    if view.bad_messages:
        bad = f"{view.bad_messages} bad message{'s' if view.bad_messages > 1 else ''} left out"
        status = f"{status}   {bad}" if status else bad
    if any(dropped(c.health)[0] for c in (*view.cars.values(), *view.gone.values())):
        status = f"{status}   {DROPPED_HELP}" if status else DROPPED_HELP
    caption = f"{status}   ({KEYS_HELP})" if status else KEYS_HELP
    return FleetRender(rows, plain(title), caption, len(view.cars) + len(view.gone))
