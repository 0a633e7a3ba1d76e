"""What the operator screen shows (pure: no I/O, no clock, no terminal).

``OperatorView`` folds what ``guidance run`` learns (the pipeline's inputs and outputs handed to
``App.listeners``, the inputs' health, the co-driver's key acknowledgements) into the screen's
content, and ``rows`` lays it out as labelled lines of plain text with a style name each
("ok", "warn", "bad" or ""). ``guidance.app.screen`` draws them: a rich live view on a
terminal, plain lines in the journal. Wall-clock times are passed in (``wall_s``), so a test
can fold a drive and read the screen it gives.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from guidance.core.angles import heading_to_compass
from guidance.core.messages import (
    Approach,
    EstimateState,
    ExitTaken,
    Health,
    IntersectionScene,
    Target,
)
from guidance.core.plan.chance import shown
from guidance.core.speech import manoeuvre

KEYS_LINE = (
    "keypad: 8 straight  4 left  6 right  7/9 bear  1/3 hard  2 U-turn  | Enter ends a line"
    "  | 0+key: turn taken (0 4 = turned left)  | . clear  + help  * repeat  / mute"
)
"""The key map in one line (drivers/evdev_keys.py; the terminal takes the same as text)."""

PROMPTS_SHOWN = 5
KEYS_SHOWN = 5
EVENTS_KEPT = 200


@dataclass(frozen=True, slots=True)
class ScreenEvent:
    """One line of the screen's history: a prompt, a key acknowledgement, a health flip..."""

    seq: int
    wall_s: float
    kind: str
    """"prompt", "key" (a line acknowledged, answered, help), "typing" (one key), "exit",
    "health", "log", "info"."""
    text: str
    style: str = ""


def compass_deg(heading_rad: float) -> float:
    """Filter heading (rad, CCW from east) -> compass heading (deg clockwise from north),
    rounded to 0.1 deg so that it never shows as 360."""
    return round(float(heading_to_compass(heading_rad, 0.0)), 1) % 360.0


def compass_point(deg: float) -> str:
    """The nearest of the 8 compass points: 92 -> "E"."""
    return ("N", "NE", "E", "SE", "S", "SW", "W", "NW")[int((deg % 360.0) / 45.0 + 0.5) % 8]


def clock_text(wall_s: float) -> str:
    """Local wall-clock time of day, HH:MM:SS."""
    return time.strftime("%H:%M:%S", time.localtime(wall_s))


def distance_text(distance_m: float) -> str:
    if distance_m < 1000.0:
        return f"{distance_m:.0f} m"
    return f"{distance_m / 1000.0:.1f} km"


def uncertainty_text(major_axis_m: float, lost: bool, lost_major_axis_m: float) -> str:
    """The 2-sigma major axis and what it means for the operator: "good to about R m" is its
    half (the 2-sigma semi-major axis, the farthest the true position is likely to be),
    rounded to 1 m below 10 m, 5 m below 100 m, 10 m above; never 0 and never more than the
    axis (a 4 m axis once read "about 5 m")."""
    radius = major_axis_m / 2.0
    step = 1.0 if radius < 10.0 else 5.0 if radius < 100.0 else 10.0
    about = max(1.0, round(radius / step) * step)
    axis = f"2-sigma major axis {major_axis_m:.0f} m"
    if lost:
        return f"LOST: {axis} (over {lost_major_axis_m:.0f} m); guidance unreliable"
    return f"position good to about {about:.0f} m ({axis})"


def chance_text(p: float) -> str:
    """The CHANCE row: the study table's estimate, said as what it is."""
    return f"{shown(p)} chance of reaching the goal from here (simulated cars like this one)"


def _sentence(text: str) -> str:
    return text[:1].upper() + text[1:]


def _input_text(st: Health) -> tuple[str, str]:
    if not st.alive:
        word, style = ("silent" if st.age_s is not None else "no data"), "bad"
    elif st.age_s is None:
        word, style = "starting", "warn"  # in its grace period: nothing received yet
    elif not st.valid:
        word, style = "garbled", "bad"
    else:
        word, style = "ok", "ok"
    measured = st.rate_hz or 0.0
    rate = f" {measured:.1f}/{st.expected_rate_hz:.0f} Hz" if st.expected_rate_hz else ""
    detail = f" ({st.detail})" if st.detail and style != "ok" else ""
    return f"{st.name} {word}{rate}{detail}", style


class OperatorView:
    """The operator screen's content, folded from the app's messages (see the module)."""

    def __init__(
        self,
        *,
        vehicle_id: str = "",
        landmark_names: Mapping[int, str] | None = None,
        lost_major_axis_m: float = 100.0,
        chance_warn_below: float = 0.5,
    ) -> None:
        self.vehicle_id = vehicle_id
        self.landmark_names = dict(landmark_names or {})
        self.lost_major_axis_m = lost_major_axis_m
        self.instruction = ""
        self.instruction_wall_s: float | None = None
        self.distance_m: float | None = None
        self.state: EstimateState | None = None
        self.heading_known = True
        self.speed_mps = 0.0
        self.target: Target | None = None
        self.inputs: dict[str, Health] = {}
        self.co_driver = ""
        self.co_driver_style = ""
        self.voice = ""
        """The VOICE row: "" (no row), "on", or "MUTED ..." (``set_voice``)."""
        self.arrived = False
        self.chance: float | None = None
        """The chance of reaching the goal, with each state (``guidance.core.plan.chance``)."""
        self.chance_warn_below = chance_warn_below
        """``[chance] warn_below``: the CHANCE row is yellow below it."""
        self.last_turn_prompt = ""
        self.events: deque[ScreenEvent] = deque(maxlen=EVENTS_KEPT)
        self.exit_note: ScreenEvent | None = None
        self._seq = 0

    # -- folding ------------------------------------------------------------------------------
    def add(self, wall_s: float, kind: str, text: str, style: str = "") -> ScreenEvent:
        self._seq += 1
        event = ScreenEvent(self._seq, wall_s, kind, text, style)
        self.events.append(event)
        return event

    def apply(self, msg: Any, out: Any, wall_s: float) -> None:
        """One ``App.listeners`` call: the input (None on a tick) and the pipeline's outputs."""
        if isinstance(msg, Approach):
            self.distance_m = msg.distance_m
        for d in out.decisions:
            self.instruction = _sentence(manoeuvre(d.turn_rad))
            self.instruction_wall_s = wall_s
            self.distance_m = msg.distance_m if isinstance(msg, IntersectionScene) else None
        for p in out.prompts:
            style = "bad" if p.priority >= 2 else ""
            self.add(wall_s, "prompt", p.text, style)
            if p.kind == "turn":
                self.last_turn_prompt = p.text
        for taken in out.exits_taken:
            self._exit_taken(taken, wall_s)
        for h in out.health:
            self.inputs[h.status.name] = h.status
            text, style = _input_text(h.status)
            self.add(wall_s, "health", text, style)
        if out.state is not None:
            self.state = out.state
            self.chance = out.chance
        if out.arrived:
            self.arrived = True
            self.instruction = "Arrived"

    def _exit_taken(self, taken: ExitTaken, wall_s: float) -> None:
        d = taken.decision
        took = manoeuvre(d.options[taken.exit_index].turn_rad) if d.options else "?"
        self.instruction = ""
        self.distance_m = None
        if taken.followed:
            self.add(wall_s, "exit", f"exit taken as advised: {took} ({taken.source})", "ok")
            return
        advised = manoeuvre(d.turn_rad)
        self.exit_note = self.add(
            wall_s,
            "exit",
            f"DIFFERENT EXIT TAKEN: advised {advised}, took {took} ({taken.source})",
            "warn",
        )

    def set_live(
        self,
        *,
        inputs: Mapping[str, Health],
        target: Target | None,
        heading_known: bool,
        speed_mps: float,
        co_driver: str,
        co_driver_ok: bool,
    ) -> None:
        """What the app knows now (read from the pipeline and the sources on the loop)."""
        self.inputs.update(inputs)
        self.target = target
        self.heading_known = heading_known
        self.speed_mps = speed_mps
        self.co_driver = co_driver
        self.co_driver_style = "ok" if co_driver_ok else "bad"

    def set_voice(self, muted: bool, not_spoken: int = 0) -> None:
        """Whether the co-driver muted the voice (and how many prompts went unsaid since)."""
        if not muted:
            self.voice = "on"
            return
        unsaid = (
            f"; {not_spoken} prompt{'s' if not_spoken != 1 else ''} not spoken"
            if not_spoken
            else ""
        )
        self.voice = f"MUTED (warnings still spoken{unsaid}): / or mute to turn it on"

    def ack(self, text: str, wall_s: float) -> None:
        """A co-driver key or line acknowledged (or answered, or help)."""
        style = "warn" if text.startswith("?") else ""
        self.add(wall_s, "key", text, style)

    # -- reading ------------------------------------------------------------------------------
    def of_kind(self, kind: str, n: int) -> list[ScreenEvent]:
        return [e for e in self.events if e.kind == kind][-n:]

    def _target_text(self) -> str:
        if self.target is None:
            return "-"
        tx, ty, kind, tid = self.target.x_m, self.target.y_m, self.target.kind, self.target.id
        name = "goal" if kind == "goal" else f"landmark {self.landmark_names.get(tid or -1, tid)}"
        if self.state is None:
            return name
        dx, dy = tx - self.state.x_m, ty - self.state.y_m
        bearing = round(compass_deg(math.atan2(dy, dx))) % 360
        return (
            f"{name}: {distance_text(math.hypot(dx, dy))}, bearing {bearing:03.0f} deg "
            f"({compass_point(bearing)})"
        )

    def _next_text(self) -> tuple[str, str]:
        if self.arrived:
            return "Arrived at the destination", "ok"
        if not self.heading_known:
            return "no advice: waiting for a heading (compass or start heading)", "warn"
        if not self.instruction:
            return "waiting for the next intersection (type its exits)", ""
        where = (
            f"in {distance_text(self.distance_m)}"
            if self.distance_m is not None
            else "at the next intersection (distance unknown)"
        )
        return f"{self.instruction}, {where}", "ok"

    def rows(self) -> list[tuple[str, str, str]]:
        """(label, text, style) lines, top to bottom."""
        nxt, nstyle = self._next_text()
        out = [("NEXT", nxt, nstyle), ("TARGET", self._target_text(), "")]
        st = self.state
        if st is None:
            out += [("HEADING", "-", ""), ("POSITION", "no estimate yet", "")]
        else:
            deg = round(compass_deg(st.heading_rad)) % 360
            heading = f"{deg:03.0f} deg {compass_point(deg)} (clockwise from north)"
            if not self.heading_known:
                heading = "unknown (waiting for the compass or a start heading)"
            kmh = self.speed_mps * 3.6
            out.append(("HEADING", f"{heading}   speed {kmh:.0f} km/h", ""))
            major = st.ellipse.major_axis_m
            pos_style = (
                "bad" if st.lost else ("warn" if major > 0.5 * self.lost_major_axis_m else "ok")
            )
            out.append(
                ("POSITION", uncertainty_text(major, st.lost, self.lost_major_axis_m), pos_style)
            )
            if self.chance is not None and not self.arrived:
                low = self.chance < self.chance_warn_below
                out.append(("CHANCE", chance_text(self.chance), "warn" if low else "ok"))
        for name in sorted(self.inputs):
            text, style = _input_text(self.inputs[name])
            out.append(("INPUT", text, style))
        if self.co_driver:
            out.append(("INPUT", f"co-driver {self.co_driver}", self.co_driver_style))
        if self.voice:
            out.append(("VOICE", self.voice, "warn" if self.voice.startswith("MUTED") else ""))
        if self.exit_note is not None:
            e = self.exit_note
            out.append(("EXIT", f"{clock_text(e.wall_s)} {e.text}", e.style))
        prompts = self.of_kind("prompt", PROMPTS_SHOWN)
        for e in prompts:
            out.append(("PROMPT", f"{clock_text(e.wall_s)} {e.text}", e.style))
        shown = {" ".join(e.text.split()) for e in prompts}
        # what the text speaker said (it may not write on the live view's terminal), unless
        # it is a prompt shown just above
        for e in [e for e in self.of_kind("voice", 4) if e.text not in shown][-2:]:
            out.append(("SAID", f"{clock_text(e.wall_s)} {e.text}", e.style))
        for e in self.of_kind("typing", 1):
            out.append(("TYPING", f"{clock_text(e.wall_s)} {e.text}", ""))
        for e in self.of_kind("key", KEYS_SHOWN):
            out.append(("KEY", f"{clock_text(e.wall_s)} {e.text}", e.style))
        for e in self.of_kind("log", 2):
            out.append(("LOG", f"{clock_text(e.wall_s)} {e.text}", e.style))
        out.append(("KEYS", KEYS_LINE, ""))
        return out

    def status_line(self) -> str:
        """One line for the journal: next instruction, position, inputs."""
        nxt, _ = self._next_text()
        parts = [f"next: {nxt}"]
        if self.state is not None:
            parts.append(
                uncertainty_text(
                    self.state.ellipse.major_axis_m, self.state.lost, self.lost_major_axis_m
                )
            )
        if self.chance is not None and not self.arrived:
            parts.append(chance_text(self.chance))
        parts += [_input_text(st)[0] for _, st in sorted(self.inputs.items())]
        if self.co_driver:
            parts.append(f"co-driver {self.co_driver}")
        if self.voice.startswith("MUTED"):
            parts.append("voice muted")
        return " | ".join(parts)
