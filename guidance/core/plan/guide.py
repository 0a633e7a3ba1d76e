"""The intersections reported ahead (pure): which exit to take, what to say, which exit was taken.

An intersection report (``IntersectionScene``) is a place on the car's road: ``distance_m``
ahead when it is known (the simulator, a detector), or "the next intersection" when it is not
(the co-driver). Each report becomes an ``Ahead`` in a short queue, first the nearest:

* **The road it is approached on.** The turn to announce is the law's exit heading relative to
  the heading the car will have on approach to *that* intersection, computed each time it is
  announced: the car's own heading once it is steady on that road, or, for an intersection
  reported behind another one still ahead (the simulator sees the next two; a report that
  comes in while the car is still turning out of the previous one), the exit heading chosen
  there. A co-driver's exits are typed relative to the car; when the report comes in during a
  turn they are taken against the road after the turn (``relative``).
* **Re-evaluated, never silently changed.** The decision is re-evaluated as the car
  approaches (every ``EVAL_EVERY_M`` and at each ``Approach``, with nothing remembered:
  ``Navigator.evaluate``). A changed exit after something was said is announced as a change;
  once the just-before prompt is out, or a later intersection was reported behind it (the car
  is committed), it is frozen.
* **The exit taken, from what the car did.** An intersection is resolved from the car's heading
  through it (the turn detector on the estimated heading, which the compass and odometry
  drive), with the distance where it is known: a turn once the car is near it, or
  ``straight_after_m`` past it with no turn. With no distance, never by distance alone: by a
  detected turn, a co-driver's turn report, or, once the co-driver has reported the next
  intersection (so this one is behind), ``straight_after_m`` of steady heading after that.
  Only then is the intersection remembered for the tabu law, at the estimate where the car got
  to it, with the exit it really took (``Navigator.commit``).
* **"Then".** When the next intersection after the announced one is decided and within
  ``speech.THEN_MAX_GAP_M`` of it, its manoeuvre is appended ("..., then turn right").
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np

from guidance.core import speech
from guidance.core.localize.estimator import PoseEstimator
from guidance.core.messages import (
    Approach,
    ExitTaken,
    IntersectionScene,
    Priority,
    Say,
    Speech,
    TurnCompleted,
)
from guidance.core.model import wrap_angle
from guidance.core.pipeline_config import Outputs, PipelineConfig
from guidance.core.plan.announce import (
    WORD_SIGMAS,
    arrives_before,
    due_announcements,
    heading_cannot_tell,
    heading_sd,
)
from guidance.core.plan.navigator import Decision, Navigator
from guidance.core.plan.road import (
    Ahead,
    LastReport,
    RoadHistory,
    announce_target,
    predicted_xy,
    unplaced_after_gap,
)
from guidance.core.snapshot_check import integer

log = logging.getLogger(__name__)

EVAL_EVERY_M = 10.0
"""The decision ahead is re-evaluated after this much travel (and at each ``Approach``)."""
CHANGE_MARGIN_RAD = math.radians(25.0)
"""Once an instruction was said, another exit replaces it only if it is this much cheaper
(two exits of nearly equal cost, the goal straight beyond a T junction, swap with the
estimate's wobble; a change the driver hears must be worth it). It is changed once at most,
and never after the just-before prompt."""
SAME_PLACE_M = 20.0
"""A report within this distance (or 15 %) of one already ahead is the same intersection."""
UNKNOWN_AHEAD_M = 50.0
"""Where "the next intersection" (distance unknown) is taken to be for the law: a town
block's least length ahead (never the intersection the car has just left behind)."""
PASS_MARGIN_M = 5.0
"""The next intersection is announced once the car is this far past the one before it."""
PASSED_STRAIGHT_M = 10.0
"""No distance: once the next intersection is reported (so the car is at or in this one), a
heading that has not turned over this much travel means the car went straight on (a car that
turns at a corner a few metres ahead has turned by half within it)."""
REPEAT_S = 5.0
"""The same sentence is not said twice within this time (unless it says a change)."""
ROAD_STEADY_M = 20.0
"""The car's own heading is the road's once it has been steady over this much travel."""
MAX_AHEAD = 4
"""Intersections kept ahead at once (a co-driver who reports far ahead)."""

SayFn = Callable[[Outputs, float, Say, Priority, str], None]


class Guide:
    """The queue of intersections ahead and everything said and decided about them (see the
    module doc). The pipeline calls ``report``, ``approach``, ``co_driver_turn`` and, after
    every odometry step, ``step``; ``replan`` after an accepted landmark fix or a new goal."""

    def __init__(
        self,
        config: PipelineConfig,
        navigator: Navigator,
        say: SayFn,
        counts: Counter[str],
        speed_fn: Callable[[], float],
        reckoning_fn: Callable[[], bool],
    ) -> None:
        self.config = config
        self._speed = speed_fn
        self._reckoning = reckoning_fn
        """The distance is dead-reckoned (odometry overdue): no turn named for a place on the
        road, nothing passed straight by distance alone."""
        self.navigator = navigator
        self._say = say
        self.counts = counts
        td = config.turn_detector
        self.history = RoadHistory(td.settle_m, td.settle_tol_rad)
        self.ahead: list[Ahead] = []
        self.reports = 0
        self.last_seq = 0
        """The report number of the intersection the last report was about (a new one, or
        one already ahead reported again, e.g. by a simulator resumed from a checkpoint)."""
        self.last_decision: Decision | None = None
        self.last_said = ""
        """The last turn manoeuvre said (a straight after a straight is not repeated)."""
        self._said_at: dict[str, float] = {}
        self.last_exit_heading_rad: float | None = None
        """The exit the car took at the last intersection it went through (estimate frame)."""
        self._undo: LastReport | None = None  # what ``cancel`` undoes
        self._heading_before_gap = 0.0  # the history's heading at the last odometry step

    # -- inputs ---------------------------------------------------------------------------------
    def report(
        self, scene: IntersectionScene, est: PoseEstimator, odometer_m: float, out: Outputs
    ) -> None:
        """A reported intersection: queued, decided when its road is known, announced."""
        heading = est.heading_rad
        d = scene.distance_m
        known = d is not None and math.isfinite(d)
        self.reports += 1
        at = odometer_m + max(0.0, float(d)) if known and d is not None else None
        if at is not None:
            tol = max(SAME_PLACE_M, 0.15 * (at - odometer_m))
            same = next(
                (a for a in self.ahead if a.at_odometer_m is not None
                 and abs(a.at_odometer_m - at) <= tol and a.at_odometer_m > odometer_m),
                None,
            )  # fmt: skip
            if same is not None and same.exits_rad == tuple(scene.exit_headings_rad):
                same.at_odometer_m = at  # the same intersection again: a better distance
                self.counts["report_repeated"] += 1
                self.last_seq = same.seq
                self._evaluate(same, est, odometer_m, scene.t_s, out)
                self.announce(scene.t_s, odometer_m, out, est)
                return
        undo = LastReport.of(self.reports, self.ahead)
        if at is None:
            for a in self.ahead:  # the co-driver reports the next one: the earlier are behind
                if a.at_odometer_m is None and a.passed_odometer_m is None:
                    a.passed_odometer_m = odometer_m
                    a.passed_heading_rad = heading
        for a in self.ahead:
            a.frozen = True  # the car is committed to the exits before this one
        self.last_seq = self.reports
        self._undo = undo
        item = Ahead(self.reports, scene.t_s, tuple(scene.exit_headings_rad), heading,
                     relative=not known, at_odometer_m=at)  # fmt: skip
        self.ahead.append(item)
        if at is not None:
            self.ahead.sort(key=lambda a: math.inf if a.at_odometer_m is None else a.at_odometer_m)
        while len(self.ahead) > MAX_AHEAD:
            self.ahead.pop(0)
            self.counts["ahead_dropped"] += 1
        self._update(scene.t_s, est, odometer_m, out, force=True)

    def cancel(self, odometer_m: float) -> bool:
        """Withdraw the last new report (``LastReport.withdraw``); False when there is none
        the car has not acted on. One level (and none after a restart from a checkpoint)."""
        undo, self._undo = self._undo, None
        if undo is None or not undo.withdraw(self.ahead, odometer_m):
            return False
        self.last_decision = next((b.decision for b in reversed(self.ahead) if b.decision), None)
        self.counts["reports_cancelled"] += 1
        return True

    def approach(self, msg: Approach, est: PoseEstimator, odometer_m: float, out: Outputs) -> None:
        """The distance to an intersection ahead: re-anchors the one it matches, re-evaluates."""
        d = msg.distance_m
        if not math.isfinite(d):
            return
        cands = [a for a in self.ahead if a.at_odometer_m is not None
                 and a.at_odometer_m > odometer_m - 1.0]  # fmt: skip
        if cands:
            a = min(cands, key=lambda a: abs((a.at_odometer_m or 0.0) - odometer_m - d))
            assert a.at_odometer_m is not None
            if abs(a.at_odometer_m - odometer_m - d) <= max(15.0, 0.2 * d):
                a.at_odometer_m = odometer_m + max(0.0, d)
        self._update(msg.t_s, est, odometer_m, out, force=True)

    def co_driver_turn(self, turn: TurnCompleted, est: PoseEstimator, out: Outputs) -> bool:
        """The co-driver says which way the car went: the first intersection ahead resolved
        with it. False when nothing was ahead."""
        first = self._first_unresolved()
        if first is None:
            return False
        base = first.approach_heading_rad
        heading = est.heading_rad if base is None else wrap_angle(base + turn.heading_change_rad)
        self._resolve(first, turn.t_s, heading, turn.source, est, out)
        return True

    def after_gap(
        self, t_s: float, gap_from_s: float, placeable_s: float, est: PoseEstimator, out: Outputs
    ) -> None:
        """The wheel speeds are back after a silence (``road.unplaced_after_gap``). One place
        no longer placed and a turn on the compass meanwhile: the turn was made there. Others
        cannot be told apart (passed straight, turned at, still ahead): dropped unsaid, never
        resolved by distance or credited with a later turn."""
        lost = unplaced_after_gap(self.ahead, gap_from_s, t_s, placeable_s)
        turned = abs(self.history.unwrapped_rad - self._heading_before_gap)
        if len(lost) == 1 and turned >= self.config.turn_detector.min_turn_rad:
            self._resolve(lost[0], t_s, est.heading_rad, "compass_gap", est, out)
            lost = []
        for a in lost:
            self.ahead.remove(a)
        self.counts["ahead_unplaced_after_gap"] += len(lost)

    def replan(self, t_s: float, est: PoseEstimator, odometer_m: float, out: Outputs) -> None:
        """The estimate jumped (a landmark fix) or the goal moved: the decisions ahead are looked
        at again, and may change even once said (``_evaluate``)."""
        self._update(t_s, est, odometer_m, out, force=True, jumped=True)

    def step(
        self,
        t_s: float,
        est: PoseEstimator,
        odometer_m: float,
        turn: TurnCompleted | None,
        out: Outputs,
    ) -> None:
        """After each odometry step: the road history, arrivals at intersections, exits taken,
        re-evaluation and announcements."""
        x = est.x
        self.history.add(odometer_m, float(x[0]), float(x[1]), est.heading_rad)
        if not self._reckoning():
            self._heading_before_gap = self.history.unwrapped_rad
        first = self._first_unresolved()
        if first is not None:
            self._check_resolution(first, t_s, est, odometer_m, turn, out)
        elif turn is not None:
            log.info("turn of %.0f deg with no intersection announced",
                     math.degrees(turn.heading_change_rad))  # fmt: skip
        self._update(t_s, est, odometer_m, out, force=False)

    # -- resolution -----------------------------------------------------------------------------
    def _first_unresolved(self) -> Ahead | None:
        return self.ahead[0] if self.ahead else None

    def _check_resolution(
        self,
        a: Ahead,
        t_s: float,
        est: PoseEstimator,
        odometer_m: float,
        turn: TurnCompleted | None,
        out: Outputs,
    ) -> None:
        cfg = self.config
        heading = est.heading_rad
        if a.at_odometer_m is not None:
            if a.reached is None and odometer_m >= a.at_odometer_m:
                x, P = est.x, est.P
                a.reached = (float(x[0]), float(x[1]), float(P[0, 0]), float(P[0, 1]),
                             float(P[1, 1]))  # fmt: skip
            near = odometer_m >= a.at_odometer_m - cfg.turn_detector.window_m
            if turn is not None and near:
                self._resolve(a, t_s, heading, "detected", est, out)
            elif odometer_m >= a.at_odometer_m + cfg.straight_after_m and not self._reckoning():
                self._resolve(a, t_s, heading, "no_turn", est, out)
            return
        if turn is not None and a.approach_heading_rad is not None:
            self._resolve(a, t_s, heading, "detected", est, out)
        elif (
            a.passed_odometer_m is not None
            and a.passed_heading_rad is not None
            and odometer_m >= a.passed_odometer_m + PASSED_STRAIGHT_M
            and self.history.steady(odometer_m)
            and abs(wrap_angle(heading - a.passed_heading_rad))
            < 0.5 * cfg.turn_detector.min_turn_rad
        ):
            self._resolve(a, t_s, heading, "passed", est, out)

    def _resolve(
        self, a: Ahead, t_s: float, heading: float, source: str, est: PoseEstimator, out: Outputs
    ) -> None:
        """``a`` is behind the car, which left it with ``heading``: the exit taken, remembered."""
        self.ahead.remove(a)
        d = a.decision
        if d is None:  # never decided (its road never became known): nothing to remember
            self.counts["resolved_undecided"] += 1
            return
        best = min(d.options, key=lambda o: abs(wrap_angle(o.heading_rad - heading))).index
        blind = heading_cannot_tell(d, heading_sd(est.P))
        if best != d.exit_index and source != "co-driver" and blind:
            best = d.exit_index  # the heading cannot tell the exits apart: as advised
            self.counts["exit_assumed_followed"] += 1
        followed = best == d.exit_index
        if not followed:
            self.counts["advice_not_followed"] += 1
            # Intersections reported behind this one were on the road of the advised exit.
            dropped = [b for b in self.ahead if b.t_s <= t_s and b.at_odometer_m is not None]
            for b in dropped:
                self.ahead.remove(b)
            self.counts["ahead_dropped"] += len(dropped)
        reached = a.reached
        if reached is None:  # distance unknown: where the turn began, else where it was passed
            back = self.config.turn_detector.settle_m + 5.0 if source == "detected" else 0.0
            odo = (a.passed_odometer_m if a.passed_odometer_m is not None and source != "detected"
                   else self.history.last_odometer_m - back)  # fmt: skip
            xy = self.history.at(odo)
            P = est.P
            x = est.x
            px, py = xy if xy is not None else (float(x[0]), float(x[1]))
            reached = (px, py, float(P[0, 0]), float(P[0, 1]), float(P[1, 1]))
        rx, ry, pxx, pxy, pyy = reached
        Pm = np.array([[pxx, pxy], [pxy, pyy]])
        k = self.navigator.commit((rx, ry), Pm, d.options[best].heading_rad)
        nxt = self.ahead[0] if self.ahead else None
        if nxt is not None and nxt.relative and nxt.approach_heading_rad is None:
            nxt.approach_heading_rad = d.options[best].heading_rad  # the road it is typed on
        self.last_exit_heading_rad = d.options[best].heading_rad
        out.exits_taken.append(
            ExitTaken(t_s, replace(d, intersection_id=k), best, followed, source)
        )

    # -- decisions and announcements ------------------------------------------------------------
    def _update(
        self,
        t_s: float,
        est: PoseEstimator,
        odometer_m: float,
        out: Outputs,
        *,
        force: bool,
        jumped: bool = False,
    ) -> None:
        """Approach roads, decisions (re-evaluated every ``EVAL_EVERY_M`` where the distance is
        known; with none, where the intersection is stays unknown, so only a jump of the
        estimate re-evaluates it), then what is due to be said."""
        if not self.ahead:
            return
        prev: Ahead | None = None
        steady_for = self.history.steady_for_m(
            odometer_m, max(ROAD_STEADY_M, self.history.steady_m)
        )
        steady = steady_for >= self.history.steady_m
        on_road = steady_for >= ROAD_STEADY_M
        for i, a in enumerate(self.ahead[:2]):
            if i == 0 or (prev is not None and prev.decision is not None):
                self._set_approach(a, prev, est, odometer_m, steady, on_road)
                due = force or odometer_m - a.last_eval_odometer_m >= EVAL_EVERY_M
                if a.at_odometer_m is None and a.decision is not None:
                    due = jumped
                if a.approach_heading_rad is not None and due:
                    self._evaluate(a, est, odometer_m, t_s, out, jumped)
            prev = a
        self.announce(t_s, odometer_m, out, est)

    def _set_approach(
        self,
        a: Ahead,
        prev: Ahead | None,
        est: PoseEstimator,
        odometer_m: float,
        steady: bool,
        on_road: bool,
    ) -> None:
        """The heading of the road ``a`` is approached on: the car's own once it has been
        steady on that road for ``ROAD_STEADY_M`` (a turn's tail, a U-turn settling back onto
        the road, must not name the manoeuvre), else the exit chosen at the intersection
        before it."""
        on_its_road = prev is None or (
            prev.at_odometer_m is not None and odometer_m > prev.at_odometer_m + 5.0
        )
        if a.relative:
            # Typed relative to the car: fixed once, against the road after any turn.
            if a.approach_heading_rad is None:
                if prev is None and steady:
                    a.approach_heading_rad = est.heading_rad
                elif (
                    prev is not None
                    and prev.decision is not None
                    and prev.passed_odometer_m is None
                ):
                    a.approach_heading_rad = prev.decision.exit_heading_rad
            return
        near = a.at_odometer_m is not None and odometer_m >= a.at_odometer_m - 10.0
        if on_its_road and on_road and (a.approach_heading_rad is None or not near):
            a.approach_heading_rad = self.history.road_heading(est.heading_rad)
            a.approach_estimated = True
        elif prev is not None and prev.decision is not None and a.approach_heading_rad is None:
            a.approach_heading_rad = prev.decision.exit_heading_rad
        elif prev is None and a.approach_heading_rad is None and steady:
            # Just out of a turn: the exit it took is the road, if the car has kept to it.
            taken = self.last_exit_heading_rad
            heading = est.heading_rad
            if (
                taken is not None
                and abs(wrap_angle(heading - taken)) <= self.history.steady_tol_rad
            ):
                a.approach_heading_rad = taken

    def _evaluate(
        self,
        a: Ahead,
        est: PoseEstimator,
        odometer_m: float,
        t_s: float,
        out: Outputs,
        jumped: bool = False,
    ) -> None:
        """The law for ``a`` now. Once its instruction was said, another exit replaces it only
        after the estimate jumped (a landmark fix), where the distance is known, and by more
        than ``CHANGE_MARGIN_RAD``: the target the law picks drifts as the car drives, and a
        driver told one way must not hear the other for that."""
        exits = a.exits_now()
        if exits is None or a.approach_heading_rad is None:
            return
        a.last_eval_odometer_m = odometer_m
        car = (float(est.x[0]), float(est.x[1]))
        at = predicted_xy(self.ahead, a, car, odometer_m, UNKNOWN_AHEAD_M)
        new = self.navigator.evaluate(t_s, at, est.P, exits, a.approach_heading_rad, car)
        old = a.decision
        if old is not None and new.exit_index != old.exit_index:
            keep = a.frozen or (
                a.said_exit >= 0
                and (
                    a.at_odometer_m is None  # no distance: no telling how close it is now
                    or not jumped
                    or new.options[old.exit_index].cost_rad - CHANGE_MARGIN_RAD
                    <= new.options[new.exit_index].cost_rad
                )
            )
            if keep:  # the same exit, turned relative to today's approach heading
                self.counts["change_kept"] += 1
                o = new.options[old.exit_index]
                a.decision = new.with_exit(o)
                return
            self.counts["decision_changed"] += 1
        a.decision = new
        if old is None or new.exit_index != old.exit_index:
            self.last_decision = new
            out.decisions.append(new)

    def announce(self, t_s: float, odometer_m: float, out: Outputs, est: PoseEstimator) -> None:
        """What is due for the next intersection still ahead of the car."""
        i, a = announce_target(self.ahead, odometer_m, PASS_MARGIN_M)
        if a is None or a.decision is None:
            return
        if self._arrives_before(a, est, odometer_m):
            self.counts["goal_intersection_not_said"] += 1  # "You have arrived" comes first
            a.said_exit = a.decision.exit_index  # held as if said: no silent swapping
            return
        if self._reckoning() and a.at_odometer_m is not None:
            self.counts["words_withheld_gap"] += 1  # said once the wheels speak again
            return
        d = a.decision
        band = WORD_SIGMAS * heading_sd(est.P) if a.approach_estimated else 0.0
        action = speech.manoeuvre_within(d.turn_rad, band, d.exit_heading_rad)
        changed = a.said_exit >= 0 and a.said_exit != d.exit_index
        straight = action == "continue straight"
        if a.at_odometer_m is None:
            if "now" in a.announced and not changed:
                return
            a.announced.add("now")
            if straight and not changed and self.last_said == "continue straight":
                self.counts["straight_not_repeated"] += 1  # the screen shows it; nothing new
                a.said, a.said_exit = action, d.exit_index
                return
            then = self._then(i, a, est, odometer_m)
            say = Say(Speech.TURN, d.turn_rad, None, *then, band, d.exit_heading_rad, changed)
            self._speak(a, out, t_s, say, action)
            return
        distance = max(0.0, a.at_odometer_m - odometer_m)
        due = due_announcements(distance, self._speed(), a.announced)
        if not due and not changed:
            return
        if due:
            a.announced.add(due[0])
            if due[0] == "before":
                a.frozen = True  # what the driver hears just before is what the car does
        if straight and not changed and (not due or due[0] == "early"):
            return  # straight through needs no early warning (OsmAnd, Organic Maps)
        if straight and not changed and self.last_said == "continue straight":
            self.counts["straight_not_repeated"] += 1
            a.said, a.said_exit = action, d.exit_index
            return
        then = self._then(i, a, est, odometer_m)
        say = Say(Speech.TURN, d.turn_rad, distance, *then, band, d.exit_heading_rad, changed)
        self._speak(a, out, t_s, say, action)

    def _arrives_before(self, a: Ahead, est: PoseEstimator, odometer_m: float) -> bool:
        """The car will be told it has arrived ``ARRIVE_MARGIN_M`` before it gets to ``a``:
        its road to ``a`` (from the car, or from the intersection before it) enters the arrival
        circle that far before ``a`` (a turn made before arriving is announced as any other)."""
        if a.at_odometer_m is None or a.approach_heading_rad is None:
            return False
        start, start_odo = (float(est.x[0]), float(est.x[1])), odometer_m
        i = self.ahead.index(a) if a in self.ahead else 0
        if i > 0:  # on the road from the intersection before it
            prev = self.ahead[i - 1]
            if prev.at_odometer_m is not None and prev.at_odometer_m > odometer_m:
                if self._arrives_before(prev, est, odometer_m):
                    return True
                start = predicted_xy(self.ahead, prev, start, odometer_m, UNKNOWN_AHEAD_M)
                start_odo = prev.at_odometer_m
        radius = self.navigator.config.arrival_radius_m
        ahead = a.at_odometer_m - start_odo
        return arrives_before(self.navigator.goal, radius, start, a.approach_heading_rad, ahead)

    def _then(
        self, i: int, a: Ahead, est: PoseEstimator, odometer_m: float
    ) -> tuple[float | None, float | None]:
        if i + 1 >= len(self.ahead):
            return None, None
        b = self.ahead[i + 1]
        if b.decision is None or a.at_odometer_m is None or b.at_odometer_m is None:
            return None, None
        if self._arrives_before(b, est, odometer_m):
            b.said_exit = b.decision.exit_index  # held as if said, but the car arrives first
            return None, None
        return b.decision.turn_rad, b.at_odometer_m - a.at_odometer_m

    def _speak(self, a: Ahead, out: Outputs, t_s: float, say: Say, action: str) -> None:
        assert a.decision is not None
        a.frozen = a.frozen or say.changed  # one change at most
        text = speech.words(say, self.config.units)  # compared with what was said last
        last_t = self._said_at.get(text)
        if last_t is not None and t_s - last_t < REPEAT_S and not say.changed:
            if a.said_exit >= 0:  # the same words again so soon tell nothing
                self.counts["repeat_not_said"] += 1
                return
            say = replace(say, again=True)  # another intersection, same manoeuvre, right after
            text = speech.words(say, self.config.units)
        self._said_at = {k: v for k, v in self._said_at.items() if t_s - v < REPEAT_S}
        self._said_at[text] = t_s
        a.said, a.said_exit = action, a.decision.exit_index
        self.last_said = action
        self._say(out, t_s, say, Priority.GUIDANCE, text)
        i = self.ahead.index(a)
        if i + 1 < len(self.ahead) and ", then " in text:
            nxt = self.ahead[i + 1]
            if nxt.decision is not None:
                nxt.said = speech.manoeuvre(nxt.decision.turn_rad)
                nxt.said_exit = nxt.decision.exit_index

    # -- views and checkpoints ------------------------------------------------------------------
    def planned_exit(self, seq: int) -> int | None:
        """The exit now planned for report ``seq`` (the simulated driver follows it)."""
        for a in self.ahead:
            if a.seq == seq and a.decision is not None:
                return a.decision.exit_index
        return None

    def next_ahead(self, odometer_m: float) -> tuple[Decision | None, float | None]:
        """The decision for the next intersection still ahead and its distance (None: unknown)."""
        _i, a = announce_target(self.ahead, odometer_m, PASS_MARGIN_M)
        if a is None:
            return None, None
        dist = None if a.at_odometer_m is None else max(0.0, a.at_odometer_m - odometer_m)
        return a.decision, dist

    def snapshot(self) -> dict[str, object]:
        return {
            "ahead": [a.to_dict() for a in self.ahead],
            "history": self.history.snapshot(),
            "reports": self.reports,
            "last_seq": self.last_seq,
            "last_said": self.last_said,
        }

    def restore(self, snap: Mapping[str, object]) -> None:
        ahead = snap.get("ahead", [])
        if not isinstance(ahead, list) or len(ahead) > MAX_AHEAD:
            raise ValueError(f"guide.ahead must be a list of at most {MAX_AHEAD}")
        self.ahead = [Ahead.from_dict(a) for a in ahead if isinstance(a, dict)]
        self.history.restore(snap.get("history", []))
        self.reports = integer(snap.get("reports", 0), "guide.reports")
        self.last_seq = integer(snap.get("last_seq", 0), "guide.last_seq")
        self.last_said = str(snap.get("last_said", ""))[:40]
        decided = [a.decision for a in self.ahead if a.decision is not None]
        self.last_decision = decided[-1] if decided else None
