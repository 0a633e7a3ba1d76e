"""The truth oracle for spoken guidance: every turn prompt checked against what the car then did.

A simulated drive knows the truth. ``check`` takes a drive's truth track, the intersections
reported on it (each at a known place along the true path: where the car was at the report,
plus the reported distance) and the prompts, and checks, for every turn prompt:

* **the manoeuvre**: the intersection a prompt is about is the next one along the true path
  after it is spoken (the second for a "..., then ..." part), or the one after that when the
  car is already in the next one's corner and the prompt names a distance well past it
  (``_about``); its true turn is the change of
  the true heading from ``TURN_WINDOW_M`` before it to ``TURN_WINDOW_M`` after it, named by the
  voice's own ``speech.manoeuvre``; the spoken words must be exactly that name;
* **the distance**: "In 250 metres" against the true distance to go, within
  max(``DIST_ABS_M``, ``DIST_REL`` of it);
* **the margin**: the last prompt before every true turn comes at least ``MIN_MARGIN_S``
  before the car gets there, and no true turn goes unannounced;
* **repeats**: no sentence twice within ``REPEAT_S``.

``from_recording`` reads the same inputs from a recorded drive (``/truth``, ``/scene`` and
``/approach``, ``/prompt``), so the check runs on any recorded simulated drive;
``guidance check-guidance REC`` prints it. ``hal_sim.guided`` drives many quick trips
through the car's pipeline for the test suite and ``benchmarks/guidance_truth.py``.
"""

from __future__ import annotations

import bisect
import itertools
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from guidance.core.model import wrap_angle
from guidance.core.speech import BEARINGS, METRES_PER_FOOT, METRES_PER_MILE, manoeuvre

TURN_WINDOW_M = 25.0
"""The true turn at an intersection: the mean heading over 15 m from this far after it minus
the same before it (blocks are at least 50 m long; a corner's arc starts 7 m before its
node, a dead end's U-turn ends within 25 m after it)."""
SAME_PLACE_M = 20.0
"""Reports placing an intersection within this of each other are one intersection (streets
are at least 50 m apart; a first sight measured along the streets is off by a few metres)."""
DIST_ABS_M = 15.0
CORNER_M = 7.0
"""A corner's arc starts this far before its intersection's place (a town corner's radius)."""
DIST_REL = 0.20
MIN_MARGIN_S = 3.0
REPEAT_S = 5.0

_CHANGE = "change of plan: "
_DIST_RE = re.compile(
    r"^in ([\d.]+) (metres|metre|kilometres|kilometre|feet|miles|mile), (.+)$", re.IGNORECASE
)
_UNIT_M = {"metre": 1.0, "metres": 1.0, "kilometre": 1000.0, "kilometres": 1000.0,
           "feet": METRES_PER_FOOT, "mile": METRES_PER_MILE, "miles": METRES_PER_MILE}  # fmt: skip


@dataclass(frozen=True, slots=True)
class TruthSample:
    t_s: float
    x_m: float
    y_m: float
    heading_rad: float


@dataclass(frozen=True, slots=True)
class Report:
    """An intersection reported to the car: when, and how far ahead on the true path."""

    t_s: float
    distance_m: float
    true_turn_rad: float | None = None
    """The turn the car then made there, when the simulator gives it exactly (the street's
    heading after minus before); None: measured on the true track."""


@dataclass(frozen=True, slots=True)
class SpokenPrompt:
    t_s: float
    text: str
    kind: str = "turn"


@dataclass(frozen=True, slots=True)
class ParsedPrompt:
    """A turn prompt's parts: its manoeuvre, its distance (None: "at the next intersection"),
    the "then" manoeuvre, and whether it was said as a change."""

    action: str
    distance_m: float | None
    then: str | None
    changed: bool


def parse_prompt(text: str) -> ParsedPrompt | None:
    """The voice's turn sentences (``guidance.core.speech.turn_prompt``) read back; None for
    any other sentence."""
    t = text.strip()
    changed = t.lower().startswith(_CHANGE)
    if changed:
        t = t[len(_CHANGE) :]
    then = None
    if t.endswith(" again"):  # the same manoeuvre at the next intersection, said right after
        t = t[: -len(" again")]
    if ", then " in t:
        t, then = t.split(", then ", 1)
    low = t.lower()
    if low == "continue straight":
        return ParsedPrompt("continue straight", None, then, changed)
    if low.startswith("at the next intersection, "):
        return ParsedPrompt(low[len("at the next intersection, ") :], None, then, changed)
    m = _DIST_RE.match(t)
    if m is None:
        return None
    dist = float(m.group(1)) * _UNIT_M[m.group(2).lower()]
    return ParsedPrompt(m.group(3).lower(), dist, then, changed)


@dataclass(slots=True)
class Finding:
    t_s: float
    text: str
    problem: str

    def line(self) -> str:
        return f"{self.t_s:8.1f} s  {self.text!r}: {self.problem}"


@dataclass(slots=True)
class CheckResult:
    """What ``check`` found on one drive (or, with ``merge``, on many)."""

    drives: int = 1
    km: float = 0.0
    turn_prompts: int = 0
    manoeuvres_checked: int = 0
    wrong: list[Finding] = field(default_factory=list)
    distances_checked: int = 0
    distances_ok: int = 0
    bad_distances: list[Finding] = field(default_factory=list)
    turns: int = 0
    unannounced: list[Finding] = field(default_factory=list)
    margins_s: list[float] = field(default_factory=list)
    late: list[Finding] = field(default_factory=list)
    repeats: list[Finding] = field(default_factory=list)
    unchecked: int = 0
    """Turn prompts about an intersection the truth does not reach (the drive ended first)."""
    coarse: int = 0
    """Manoeuvres said truly but coarser than their name (a side, or a direction), the
    heading being too uncertain for the name."""
    damage: list[str] = field(default_factory=list)
    """What of the recording could not be read (chunks, records, a file cut short): a check
    of part of a drive is no pass (issue 40, defect 6)."""

    @property
    def distance_ok_frac(self) -> float:
        return self.distances_ok / self.distances_checked if self.distances_checked else 1.0

    @property
    def wrong_rate(self) -> float:
        return len(self.wrong) / self.manoeuvres_checked if self.manoeuvres_checked else 0.0

    @property
    def prompts_per_km(self) -> float:
        return self.turn_prompts / self.km if self.km > 0 else 0.0

    def merge(self, other: CheckResult) -> None:
        self.drives += other.drives
        self.km += other.km
        for name in ("turn_prompts", "manoeuvres_checked", "distances_checked", "distances_ok",
                     "turns", "unchecked", "coarse"):  # fmt: skip
            setattr(self, name, getattr(self, name) + getattr(other, name))
        for name in ("wrong", "bad_distances", "unannounced", "margins_s", "late", "repeats",
                     "damage"):  # fmt: skip
            getattr(self, name).extend(getattr(other, name))

    def ok(self, min_distance_frac: float = 0.95) -> bool:
        """The issue's bar: no wrong manoeuvre, no unannounced or late turn, no repeat, and at
        least ``min_distance_frac`` of the spoken distances right."""
        return (
            not self.damage
            and not self.wrong
            and not self.unannounced
            and not self.late
            and not self.repeats
            and self.distance_ok_frac >= min_distance_frac
        )

    def summary(self) -> str:
        margins = sorted(self.margins_s)
        p = (lambda q: margins[min(len(margins) - 1, int(q * len(margins)))]) if margins else None
        lines = [
            f"{self.drives} drive(s), {self.km:.1f} km, {self.turn_prompts} turn prompts "
            f"({self.prompts_per_km:.1f} per km), {self.turns} turns",
            f"wrong manoeuvre: {len(self.wrong)} of {self.manoeuvres_checked} "
            f"({100 * self.wrong_rate:.1f} %); said coarser than the name (heading uncertain): "
            f"{self.coarse}",
            f"spoken distances within max({DIST_ABS_M:.0f} m, {100 * DIST_REL:.0f} %): "
            f"{self.distances_ok} of {self.distances_checked} "
            f"({100 * self.distance_ok_frac:.1f} %)",
            f"turns unannounced: {len(self.unannounced)}; last prompt under {MIN_MARGIN_S:.0f} s "
            f"before the turn: {len(self.late)}",
        ]
        if p is not None:
            lines.append(
                f"announcement margin before turns: min {margins[0]:.1f} s, p5 {p(0.05):.1f} s, "
                f"median {p(0.5):.1f} s"
            )
        lines.append(f"same sentence twice within {REPEAT_S:.0f} s: {len(self.repeats)}")
        lines += [f"damaged recording: {d}: only what was read is checked" for d in self.damage]
        for name in ("wrong", "unannounced", "late", "repeats", "bad_distances"):
            for f in getattr(self, name)[:10]:
                lines.append(f"  {name}: {f.line()}")
        return "\n".join(lines)


class TruthPath:
    """The true track as distance along the path."""

    def __init__(self, truth: Sequence[TruthSample]) -> None:
        self.t = [s.t_s for s in truth]
        self.s = [0.0]
        for a, b in itertools.pairwise(truth):
            self.s.append(self.s[-1] + math.hypot(b.x_m - a.x_m, b.y_m - a.y_m))
        self.h = [s.heading_rad for s in truth]

    @property
    def length_m(self) -> float:
        return self.s[-1] if self.s else 0.0

    def s_at(self, t: float) -> float:
        i = bisect.bisect_right(self.t, t) - 1
        return self.s[max(0, min(i, len(self.s) - 1))]

    def t_at(self, s: float) -> float:
        i = bisect.bisect_left(self.s, s)
        return self.t[min(i, len(self.t) - 1)]

    def mean_heading(self, s0: float, s1: float) -> float:
        """The circular mean of the true heading between path positions s0 and s1."""
        i0 = max(0, min(bisect.bisect_left(self.s, s0), len(self.h) - 1))
        i1 = max(i0 + 1, min(bisect.bisect_right(self.s, s1), len(self.h)))
        hs = self.h[i0:i1]
        return math.atan2(sum(math.sin(h) for h in hs), sum(math.cos(h) for h in hs))


def check(
    truth: Sequence[TruthSample],
    reports: Iterable[Report],
    prompts: Iterable[SpokenPrompt],
) -> CheckResult:
    """Check one drive's turn prompts against its truth (see the module doc)."""
    path = TruthPath(truth)
    res = CheckResult(km=path.length_m / 1000.0)
    # Each report places an intersection on the true path; reports of one intersection (the
    # first sight of it, the distances as the car approaches) form one cluster, placed by the
    # nearest report (the most exact: a far one is measured along the streets, not the path).
    placed = sorted((path.s_at(r.t_s) + r.distance_m, r.distance_m, r.true_turn_rad)
                    for r in reports)  # fmt: skip
    clusters: list[list[tuple[float, float, float | None]]] = []
    for pl in placed:
        if clusters and pl[0] - clusters[-1][-1][0] <= SAME_PLACE_M:
            clusters[-1].append(pl)
        else:
            clusters.append([pl])
    merged: list[float] = []
    given: dict[float, float | None] = {}
    for c in clusters:
        place = min(c, key=lambda pl: pl[1])[0]
        merged.append(place)
        given[place] = next((pl[2] for pl in c if pl[2] is not None), None)
    true_turn: dict[float, float] = {}
    true_after: dict[float, float] = {}
    for i, s in enumerate(merged):
        # On the track: the settled heading before it, and near the next one (a dead end's
        # U-turn takes tens of metres to settle on the road back).
        end = min(merged[i + 1] if i + 1 < len(merged) else math.inf, s + 80.0)
        after0 = max(s + TURN_WINDOW_M, end - 20.0)
        if after0 + 12.0 <= path.length_m:
            true_after[s] = path.mean_heading(after0, after0 + 12.0)
        exact = given[s]
        if exact is not None:
            true_turn[s] = exact
            continue
        if s not in true_after:
            continue
        before = path.mean_heading(s - TURN_WINDOW_M - 15.0, s - TURN_WINDOW_M)
        true_turn[s] = wrap_angle(true_after[s] - before)
    last_prompt: dict[float, float] = {}
    last_text: dict[str, float] = {}
    turn_prompts = [p for p in prompts if p.kind == "turn"]
    for p in turn_prompts:
        parsed = parse_prompt(p.text)
        if parsed is None:
            continue
        res.turn_prompts += 1
        prev = last_text.get(p.text)
        if prev is not None and p.t_s - prev < REPEAT_S:
            res.repeats.append(Finding(p.t_s, p.text, f"also said {p.t_s - prev:.1f} s before"))
        last_text[p.text] = p.t_s
        s_now = path.s_at(p.t_s)
        k = _about(merged, s_now, parsed.distance_m)
        for part, action, dist in ((0, parsed.action, parsed.distance_m), (1, parsed.then, None)):
            if action is None:
                continue
            if k + part >= len(merged) or merged[k + part] not in true_turn:
                res.unchecked += 1
                continue
            s_int = merged[k + part]
            if action.lower().startswith(_TOWARDS) and s_int not in true_after:
                res.unchecked += 1  # the track ends before the road taken settles
                continue
            truth_action = manoeuvre(true_turn[s_int])
            res.manoeuvres_checked += 1
            if not _words_true(action.lower(), truth_action.lower(), true_after.get(s_int)):
                res.wrong.append(Finding(p.t_s, p.text, f"the car then made: {truth_action}"))
            elif action.lower() != truth_action.lower():
                res.coarse += 1
            if part == 0:
                last_prompt[s_int] = p.t_s
            if dist is not None:
                to_go = s_int - s_now
                res.distances_checked += 1
                if abs(dist - to_go) <= max(DIST_ABS_M, DIST_REL * to_go):
                    res.distances_ok += 1
                else:
                    res.bad_distances.append(Finding(p.t_s, p.text, f"true distance {to_go:.0f} m"))
    for s_int, turn in true_turn.items():
        if manoeuvre(turn) == "continue straight":
            continue
        res.turns += 1
        t_there = path.t_at(s_int)
        said = last_prompt.get(s_int)
        if said is None:
            res.unannounced.append(Finding(t_there, "", f"{manoeuvre(turn)} with no prompt"))
            continue
        margin = t_there - said
        res.margins_s.append(margin)
        if margin < MIN_MARGIN_S:
            res.late.append(Finding(said, "", f"last prompt {margin:.1f} s before the turn"))
    return res


def _about(merged: Sequence[float], s_now: float, distance_m: float | None) -> int:
    """The index of the intersection a prompt spoken at ``s_now`` is about: the next one along
    the true path, unless the car is already in its corner (within ``CORNER_M`` of it) and the
    prompt names a distance well beyond it (by more than ``DIST_ABS_M``): a driver turning at
    one intersection hears "In 50 metres, ..." as the next one."""
    k = bisect.bisect_right(merged, s_now)
    if (
        distance_m is not None
        and k + 1 < len(merged)
        and merged[k] - s_now <= CORNER_M
        and distance_m > merged[k] - s_now + DIST_ABS_M
    ):
        return k + 1
    return k


def _words_true(action: str, truth_action: str, after_rad: float | None) -> bool:
    """The spoken manoeuvre against the turn the car made: its exact name; "go left" / "go
    right" for any left / right turn short of a U-turn; "take the road towards the X" when
    the road the car then took heads within ``BEARING_TOL_DEG`` of X."""
    if action == truth_action:
        return True
    if action in ("go left", "go right"):
        return truth_action != "make a u-turn" and truth_action.endswith(action[3:])
    if action.startswith(_TOWARDS) and after_rad is not None:
        name = action[len(_TOWARDS) :]
        if name not in BEARINGS:
            return False
        named = math.radians(90.0 - 45.0 * BEARINGS.index(name))
        return abs(math.degrees(wrap_angle(after_rad - named))) <= BEARING_TOL_DEG
    return False


_TOWARDS = "take the road towards the "
BEARING_TOL_DEG = 30.0
"""A named direction is right when the road taken heads within this of it: half the 45
degrees between two names, and 7.5 degrees for the true track's wobble over 12 m."""


def from_recording(path: str | Path) -> CheckResult:
    """``check`` on a recorded simulated drive (its ``/truth``, ``/scene`` and ``/prompt``)."""
    from guidance.errors import UserError
    from guidance.recording.reader import Reader

    truth: list[TruthSample] = []
    reports: list[Report] = []
    prompts: list[SpokenPrompt] = []
    reader = Reader(path, topics=("/truth", "/scene", "/approach", "/prompt"))
    for m in reader:
        d = m.data
        try:
            if m.topic == "/truth":
                truth.append(TruthSample(float(d["t_s"]), float(d["x_m"]), float(d["y_m"]),
                                         float(d["heading_rad"])))  # fmt: skip
            elif m.topic == "/scene" and d.get("kind") == "intersection":
                if d.get("distance_m") is not None:
                    reports.append(Report(float(d["t_s"]), float(d["distance_m"])))
            elif m.topic == "/approach":
                reports.append(Report(float(d["t_s"]), float(d["distance_m"])))
            elif m.topic == "/prompt":
                prompts.append(SpokenPrompt(float(d["t_s"]), str(d["text"]), str(d["kind"])))
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise UserError(f"{path}: a {m.topic} record cannot be read ({exc})") from None
    damage = _damage(reader)
    if not truth:
        raise UserError(
            f"{path}: no /truth topic: only a simulated drive can be checked"
            + (f" (damaged recording: {'; '.join(damage)})" if damage else "")
        )
    if not all(math.isfinite(v) for s in truth for v in (s.t_s, s.x_m, s.y_m, s.heading_rad)):
        raise UserError(f"{path}: a /truth record holds a number that is not finite")
    if not reports:
        raise UserError(
            f"{path}: no intersection reports with a distance: nothing to place the prompts at"
        )
    res = check(truth, reports, prompts)
    res.damage = damage
    return res


def _damage(reader: Any) -> list[str]:
    """What ``reader`` could not read, in words (the words ``guidance replay`` uses)."""
    from guidance.recording.repair import damage_text

    out = [damage_text(reader.damage)] if reader.damage.any else []
    if reader.recovered:
        names = ", ".join(p.name for p in reader.recovered)
        out.append(f"cut short ({names}): read up to the damage")
    if reader.skipped:
        out.append(f"{reader.skipped} record(s) left out ({reader.skipped_why[0]})")
    return out
