"""What the car keeps about the road (pure): each intersection reported ahead (``Ahead``, a
checkpoint's plain data), and the estimate along the road behind it (``RoadHistory``: where the
car was when it got somewhere, whether it is on a road or in a turn, the road's heading).
``guidance.core.plan.guide`` decides and speaks with them."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from guidance.core.messages import EstimateState
from guidance.core.model import wrap_angle
from guidance.core.plan.announce import heading_sd, heads_along
from guidance.core.plan.navigator import Decision, ExitOption
from guidance.core.snapshot_check import check_decision, integer, number

HISTORY_M = 120.0
"""How much of the road behind is kept (position and heading every metre)."""
ROAD_MEAN_M = 60.0
"""The approach road's heading is the estimate's mean heading over up to this much of it."""


@dataclass(slots=True)
class Ahead:
    """One intersection reported ahead, until the car has gone through it."""

    seq: int
    """Its report's number (1, 2, ...): what the simulated driver follows."""
    t_s: float
    exits_rad: tuple[float, ...]
    """As reported: absolute headings, or (``relative``) the car's heading plus the typed
    direction, the car's heading at the report being ``report_heading_rad``."""
    report_heading_rad: float
    relative: bool
    at_odometer_m: float | None
    """Where it is along the road (the pipeline's odometer); None: unknown (the co-driver)."""
    approach_heading_rad: float | None = None
    """The heading of the road it is approached on, once known (estimate frame)."""
    approach_estimated: bool = False
    """The approach heading is the car's own estimated heading (its uncertainty is the
    estimate's), not an exit heading the scene gave (exact in the scene's frame)."""
    decision: Decision | None = None
    announced: set[str] = field(default_factory=set)
    """Announcements made for it: "now" (distance unknown), "early", "before", "then"."""
    said: str = ""
    """The manoeuvre last said for it (the repeat rule reads it)."""
    said_exit: int = -1
    """The exit it was said for (-1: nothing said): another exit later is a change."""
    frozen: bool = False
    passed_odometer_m: float | None = None
    """Distance unknown: the odometer when a later report said the car is through it."""
    passed_heading_rad: float | None = None
    """The heading then (straight on if it has not changed ``guide.PASSED_STRAIGHT_M`` later)."""
    reached: tuple[float, float, float, float, float] | None = None
    """(x, y, Pxx, Pxy, Pyy) of the estimate when the car got there (the tabu memory's place)."""
    last_eval_odometer_m: float = -math.inf
    on_taken_road: bool = False
    """Reported while the car was at the intersection before it (within the guide's same
    place): on the road the car really takes there, whatever exit it was advised."""
    placed_from_m: float = 0.0
    """The distance it was last placed from (a report's or an approach's): its place is
    uncertain by a share of that (``PLACE_REL``)."""

    def exits_now(self) -> tuple[float, ...] | None:
        """The exits in the estimate frame, or None while the approach road is unknown."""
        if not self.relative:
            return self.exits_rad
        if self.approach_heading_rad is None:
            return None
        base = self.approach_heading_rad - self.report_heading_rad
        return tuple(wrap_angle(h + base) for h in self.exits_rad)

    def to_dict(self) -> dict[str, object]:
        """JSON-able (the checkpoint)."""
        d: dict[str, object] = {f.name: getattr(self, f.name) for f in fields(self)}
        d["exits_rad"] = list(self.exits_rad)
        d["announced"] = sorted(self.announced)
        d["reached"] = None if self.reached is None else list(self.reached)
        d["last_eval_odometer_m"] = None
        d["decision"] = None if self.decision is None else asdict(self.decision)
        return d

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> Ahead:
        """``to_dict`` read back; every number checked (``SnapshotError`` on a bad one)."""

        def opt(key: str) -> float | None:
            v = data.get(key)
            return None if v is None else number(v, f"ahead.{key}")

        exits = data.get("exits_rad")
        announced = data.get("announced", [])
        reached = data.get("reached")
        dec = data.get("decision")
        decision = None
        if isinstance(dec, dict):
            check_decision(dec, "ahead.decision")
            opts = tuple(ExitOption(**o) for o in dec["options"])
            decision = Decision(options=opts, **{k: v for k, v in dec.items() if k != "options"})
        if not isinstance(exits, list) or not 0 < len(exits) <= 64:
            raise ValueError("ahead.exits_rad must be a list of 1-64 headings")
        return cls(
            seq=integer(data.get("seq"), "ahead.seq"),
            t_s=number(data.get("t_s"), "ahead.t_s"),
            exits_rad=tuple(number(h, "ahead.exits_rad") for h in exits),
            report_heading_rad=number(data.get("report_heading_rad"), "ahead.report_heading"),
            relative=bool(data.get("relative")),
            at_odometer_m=opt("at_odometer_m"),
            approach_heading_rad=opt("approach_heading_rad"),
            approach_estimated=bool(data.get("approach_estimated", False)),
            decision=decision,
            announced={str(a) for a in announced} if isinstance(announced, list) else set(),
            said=str(data.get("said", ""))[:40],
            said_exit=integer(data.get("said_exit", -1), "ahead.said_exit", -1, 64),
            frozen=bool(data.get("frozen")),
            on_taken_road=bool(data.get("on_taken_road", False)),
            placed_from_m=number(data.get("placed_from_m", 0.0), "ahead.placed_from_m"),
            passed_odometer_m=opt("passed_odometer_m"),
            passed_heading_rad=opt("passed_heading_rad"),
            reached=(
                None
                if not isinstance(reached, list) or len(reached) != 5
                else tuple(number(v, "ahead.reached") for v in reached)  # type: ignore[arg-type]
            ),
        )


PASS_MARGIN_M = 5.0
"""The next intersection is announced once the car is this far past the one before it..."""
PLACE_REL = 0.1
"""...or this share of the distance it was placed from, if more: a distance judged from afar
is off by up to about a tenth (the simulated co-driver's first sight, measured along the
streets, by 7 %), and the driver must not hear the next manoeuvre at the one before."""


def pass_margin_m(a: Ahead) -> float:
    """How far past ``a``'s place the car must be to be sure it is through it."""
    return max(PASS_MARGIN_M, PLACE_REL * a.placed_from_m)


def announce_target(ahead: list[Ahead], odometer_m: float) -> tuple[int, Ahead | None]:
    """The next intersection still ahead and its index (-1, None: none now): the first one the
    car has not reached, once it is ``pass_margin_m`` past every one before it (a distance is
    a few metres off; the driver must not hear the next manoeuvre while still at the previous
    corner). With no distance: once the ones before are behind."""
    for i, a in enumerate(ahead):
        if a.at_odometer_m is not None:
            if a.at_odometer_m > odometer_m:
                return i, a
            if odometer_m < a.at_odometer_m + pass_margin_m(a):
                return -1, None
        elif a.passed_odometer_m is None:
            return (i, a) if i == 0 else (-1, None)
    return -1, None


def past(prev: Ahead | None, est: EstimateState, tol_rad: float) -> bool:
    """The car is on the road after ``prev`` (the intersection before the one it approaches):
    there is none, or the car is past its place by its reported distance and out of its turn
    (heading along its chosen exit: one reported short must not give the car's road before
    the turn as the road after it)."""
    if prev is None:
        return True
    if prev.at_odometer_m is None or est.odometer_m <= prev.at_odometer_m + PASS_MARGIN_M:
        return False
    if prev.decision is None:
        return True
    sd = heading_sd(pose_covariance(est))
    return heads_along(est.heading_rad, prev.decision.exit_heading_rad, sd, tol_rad)


def unplaced_after_gap(
    ahead: list[Ahead], gap_from_s: float, resume_s: float, placeable_s: float
) -> list[Ahead]:
    """The intersections ahead, placed by distance, that the car can no longer place once the
    wheel speeds come back after a silence from ``gap_from_s`` to ``resume_s``: the odometer
    was dead-reckoned at the last speed meanwhile, so where each one is along the road is
    uncertain by what the car may have gained or lost since the gap began (or since it was
    reported, if later). Past ``placeable_s`` of that (the time after which the gap's
    along-road bound exceeds the guide's "same place") the car cannot tell whether it is still
    ahead, passed straight or turned at: none of its distances or exits can be trusted."""
    return [
        a for a in ahead
        if a.at_odometer_m is not None and resume_s - max(gap_from_s, a.t_s) > placeable_s
    ]  # fmt: skip


UNKNOWN_AHEAD_M = 50.0
"""Where "the next intersection" (distance unknown) is taken to be for the law: a town
block's least length ahead (never the intersection the car has just left behind)."""


def predicted_xy(ahead: list[Ahead], a: Ahead, est: EstimateState) -> tuple[float, float]:
    """Where the car will be at ``a``: along its approach road from the car, or from the
    intersection before it."""
    odometer_m = est.odometer_m
    base_xy, base_odo = (est.x_m, est.y_m), odometer_m
    i = ahead.index(a)
    if i > 0:
        prev = ahead[i - 1]
        if prev.at_odometer_m is not None and prev.at_odometer_m > odometer_m:
            base_xy = predicted_xy(ahead, prev, est)
            base_odo = prev.at_odometer_m
    if a.approach_heading_rad is None:
        return base_xy
    known = a.at_odometer_m
    to_go = UNKNOWN_AHEAD_M if known is None else max(0.0, known - base_odo)
    h = a.approach_heading_rad
    return base_xy[0] + to_go * math.cos(h), base_xy[1] + to_go * math.sin(h)


def pose_covariance(est: EstimateState) -> np.ndarray:
    """The estimate's pose covariance (x, y, heading) as a matrix."""
    return np.array(est.covariance, dtype=float)


class RoadHistory:
    """The estimate along the road behind the car, one sample per metre of travel: where the
    car was when it got to an intersection, and whether its heading is steady now."""

    def __init__(self, steady_m: float, steady_tol_rad: float) -> None:
        self.steady_m, self.steady_tol_rad = steady_m, steady_tol_rad
        self._s: deque[tuple[float, float, float, float]] = deque()
        self._unwrapped = 0.0
        self._last_raw: float | None = None

    def clear(self) -> None:
        self._s.clear()
        self._last_raw = None

    def add(self, odometer_m: float, x: float, y: float, heading_rad: float) -> None:
        if self._last_raw is None:
            self._unwrapped = heading_rad
        else:
            self._unwrapped += wrap_angle(heading_rad - self._last_raw)
        self._last_raw = heading_rad
        s = self._s
        if s and odometer_m - s[-1][0] < 1.0:
            return
        s.append((odometer_m, x, y, self._unwrapped))
        while s and odometer_m - s[0][0] > HISTORY_M:
            s.popleft()

    def steady(self, odometer_m: float, span_m: float | None = None) -> bool:
        """The heading has stayed within the tolerance over the last ``span_m`` (default
        ``steady_m``) of travel (so the car is on a road, not in a turn)."""
        span = self.steady_m if span_m is None else span_m
        return self.steady_for_m(odometer_m, span) >= span

    def steady_for_m(self, odometer_m: float, up_to_m: float) -> float:
        """How far back the heading has stayed within the tolerance, looking no further than
        ``up_to_m`` (one walk answers every span up to it): infinite before the car has
        driven or when it has not turned since the drive began, 0 across a dead-reckoned gap
        (the road was not seen)."""
        if len(self._s) <= 1:  # not driven yet (the start): not in a turn
            return math.inf
        if odometer_m - self._s[-1][0] > 2.0:  # dead-reckoned through a gap: not seen
            return 0.0
        lo = hi = self._unwrapped
        covered = 0.0
        for odo, _x, _y, h in reversed(self._s):
            lo, hi = min(lo, h), max(hi, h)
            if hi - lo > self.steady_tol_rad:
                return covered
            covered = odometer_m - odo
            if covered >= up_to_m:
                return covered
        return math.inf if self._s[0][0] <= 1.0 else covered  # not turned since the start

    @property
    def unwrapped_rad(self) -> float:
        """The newest heading, unwrapped (turns accumulate): differences are turns made."""
        return self._unwrapped

    @property
    def last_odometer_m(self) -> float:
        """The odometer at the newest sample (0 before any)."""
        return self._s[-1][0] if self._s else 0.0

    def road_heading(self, heading_rad: float) -> float:
        """The heading of the road the car is on: the mean over the stretch behind it that
        stays within the tolerance of the latest sample (up to ``ROAD_MEAN_M``), so the
        compass's and the filter's wobble does not swing a point far ahead."""
        s = self._s
        if not s:
            return heading_rad
        last_odo, last_h = s[-1][0], s[-1][3]
        total, n = 0.0, 0
        for odo, _x, _y, h in reversed(s):
            if abs(h - last_h) > self.steady_tol_rad or last_odo - odo > ROAD_MEAN_M:
                break
            total += h
            n += 1
        return wrap_angle(total / n)

    def at(self, odometer_m: float) -> tuple[float, float] | None:
        """The estimate where the odometer read ``odometer_m`` (the nearest sample kept)."""
        if not self._s:
            return None
        best = min(self._s, key=lambda s: abs(s[0] - odometer_m))
        return best[1], best[2]

    def snapshot(self) -> list[list[float]]:
        return [list(s) for s in self._s]

    def restore(self, samples: object) -> None:
        self.clear()
        if isinstance(samples, list):
            for s in samples[-int(HISTORY_M) - 2 :]:
                if isinstance(s, list) and len(s) == 4:
                    o, x, y, h = (number(v, "guide.history") for v in s)
                    self._s.append((o, x, y, h))
            if self._s:
                self._unwrapped = self._s[-1][3]
                self._last_raw = wrap_angle(self._unwrapped)


@dataclass(slots=True)
class LastReport:
    """The last new intersection report and what it did to the ones before it (taken as behind
    the car, frozen): what the co-driver's "cancel" undoes."""

    seq: int
    before: dict[int, tuple[float | None, float | None, bool]]

    @classmethod
    def of(cls, seq: int, ahead: list[Ahead]) -> LastReport:
        """Report ``seq``, about to be queued behind ``ahead``."""
        return cls(seq, {a.seq: (a.passed_odometer_m, a.passed_heading_rad, a.frozen)
                         for a in ahead})  # fmt: skip

    def withdraw(self, ahead: list[Ahead], odometer_m: float) -> bool:
        """Take the report out of ``ahead`` and undo what it did, unless the car has acted on
        it (resolved: gone from ``ahead``; or reached). True when withdrawn."""
        a = next((x for x in ahead if x.seq == self.seq), None)
        if a is None or a.reached is not None:
            return False
        if a.at_odometer_m is not None and odometer_m >= a.at_odometer_m:
            return False
        ahead.remove(a)
        for b in ahead:
            if b.seq in self.before:
                b.passed_odometer_m, b.passed_heading_rad, b.frozen = self.before[b.seq]
        return True
