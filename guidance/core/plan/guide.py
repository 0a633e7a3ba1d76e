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
from collections.abc import Mapping

from guidance.core.messages import (
    Approach,
    EstimateState,
    IntersectionScene,
    TurnCompleted,
)
from guidance.core.model import wrap_angle
from guidance.core.plan.announcer import Announcer
from guidance.core.plan.config import PlannerConfig
from guidance.core.plan.exits import ExitResolver
from guidance.core.plan.navigator import Decision, Navigator
from guidance.core.plan.road import (
    PLACE_REL,
    Ahead,
    LastReport,
    RoadHistory,
    announce_target,
    past,
    pose_covariance,
    predicted_xy,
)
from guidance.core.snapshot_check import integer
from guidance.core.stages import Outputs

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
ROAD_STEADY_M = 20.0
"""The car's own heading is the road's once it has been steady over this much travel."""
MAX_AHEAD = 4
"""Intersections kept ahead at once (a co-driver who reports far ahead)."""


class Guide:
    """The queue of intersections ahead and everything said and decided about them (see the
    module doc). The planner calls ``report``, ``approach``, ``co_driver_turn`` and, after
    every move of the estimate, ``step``; ``replan`` after an accepted landmark fix or a new
    goal. Each takes the estimate as a value (``EstimateState``: the pose, its covariance, the
    distance driven, the speed, whether the distance is dead-reckoned) and writes what it
    decides and says into ``out``."""

    def __init__(self, config: PlannerConfig, navigator: Navigator, counts: Counter[str]) -> None:
        self.config = config
        self.navigator = navigator
        self.counts = counts
        td = config.turn_detector
        self.history = RoadHistory(td.settle_m, td.settle_tol_rad)
        self.ahead: list[Ahead] = []
        self.reports = 0
        self.last_seq = 0
        """The report number of the intersection the last report was about (a new one, or
        one already ahead reported again, e.g. by a simulator resumed from a checkpoint)."""
        self.last_decision: Decision | None = None
        self.announcer = Announcer(config, navigator, counts)
        """What is said of the intersections ahead, and when."""
        self.exits = ExitResolver(config, navigator, counts, self.history)
        """The exit taken at each intersection, from what the car did."""
        self.silent = False  # the car does not know where it is (started anywhere): no advice
        self._undo: LastReport | None = None  # what ``cancel`` undoes

    # -- inputs ---------------------------------------------------------------------------------
    def report(self, scene: IntersectionScene, est: EstimateState, out: Outputs) -> None:
        """A reported intersection: queued, decided when its road is known, announced."""
        heading, odometer_m = est.heading_rad, est.odometer_m
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
                same.placed_from_m = at - odometer_m
                self.counts["report_repeated"] += 1
                self.last_seq = same.seq
                self._evaluate(same, est, scene.t_s, out)
                self.announcer.announce(self.ahead, scene.t_s, est, out)
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
        at_one = any(a.at_odometer_m is not None and abs(a.at_odometer_m - odometer_m)
                     <= SAME_PLACE_M for a in self.ahead)  # fmt: skip
        item = Ahead(self.reports, scene.t_s, tuple(scene.exit_headings_rad), heading,
                     relative=not known, at_odometer_m=at, on_taken_road=at_one,
                     placed_from_m=0.0 if at is None else at - odometer_m)  # fmt: skip
        self.ahead.append(item)
        if at is not None:
            self.ahead.sort(key=lambda a: math.inf if a.at_odometer_m is None else a.at_odometer_m)
        while len(self.ahead) > MAX_AHEAD:
            self.ahead.pop(0)
            self.counts["ahead_dropped"] += 1
        self._update(scene.t_s, est, out, force=True)

    def cancel(self, odometer_m: float) -> bool:
        """Withdraw the last new report (``LastReport.withdraw``); False when there is none
        the car has not acted on. One level (and none after a restart from a checkpoint)."""
        undo, self._undo = self._undo, None
        if undo is None or not undo.withdraw(self.ahead, odometer_m):
            return False
        self.last_decision = next((b.decision for b in reversed(self.ahead) if b.decision), None)
        self.counts["reports_cancelled"] += 1
        return True

    def approach(self, msg: Approach, est: EstimateState, out: Outputs) -> None:
        """The distance to an intersection ahead: re-anchors the one it matches, re-evaluates."""
        d, odometer_m = msg.distance_m, est.odometer_m
        if not math.isfinite(d):
            return
        cands = [a for a in self.ahead if a.at_odometer_m is not None
                 and a.at_odometer_m > odometer_m - 1.0]  # fmt: skip
        if cands:
            a = min(cands, key=lambda a: abs((a.at_odometer_m or 0.0) - odometer_m - d))
            assert a.at_odometer_m is not None
            # each place is off by up to a share of the distance it was judged from
            tol = max(15.0, 2.0 * PLACE_REL * max(d, a.placed_from_m))
            if abs(a.at_odometer_m - odometer_m - d) <= tol:
                a.at_odometer_m = odometer_m + max(0.0, d)
                a.placed_from_m = max(0.0, d)
        self._update(msg.t_s, est, out, force=True)

    def co_driver_turn(self, turn: TurnCompleted, est: EstimateState, out: Outputs) -> bool:
        """The co-driver says which way the car went: the first intersection ahead resolved
        with it. False when nothing was ahead."""
        return self.exits.co_driver_turn(self.ahead, turn, est, out)

    def after_gap(
        self, t_s: float, gap_from_s: float, placeable_s: float, est: EstimateState, out: Outputs
    ) -> None:
        """The wheel speeds are back after a silence: the places ahead it leaves unplaced
        (``ExitResolver.after_gap``)."""
        self.exits.after_gap(self.ahead, t_s, gap_from_s, placeable_s, est, out)

    def replan(self, t_s: float, est: EstimateState, out: Outputs) -> None:
        """The estimate jumped (a landmark fix) or the goal moved: the decisions ahead are looked
        at again, and may change even once said (``_evaluate``)."""
        self._update(t_s, est, out, force=True, jumped=True)

    def step(
        self, t_s: float, est: EstimateState, turn: TurnCompleted | None, out: Outputs
    ) -> None:
        """After each move of the estimate: the road history, arrivals at intersections, exits
        taken, re-evaluation and announcements."""
        self.history.add(est.odometer_m, est.x_m, est.y_m, est.heading_rad)
        if not est.reckoning:
            self.exits.heading_before_gap = self.history.unwrapped_rad
        if self.ahead:
            self.exits.check(self.ahead, t_s, est, turn, out)
        elif turn is not None:
            log.info("turn of %.0f deg with no intersection announced",
                     math.degrees(turn.heading_change_rad))  # fmt: skip
        self._update(t_s, est, out, force=False)

    # -- decisions and announcements ------------------------------------------------------------
    def _update(
        self,
        t_s: float,
        est: EstimateState,
        out: Outputs,
        *,
        force: bool,
        jumped: bool = False,
    ) -> None:
        """Approach roads, decisions (re-evaluated every ``EVAL_EVERY_M`` where the distance is
        known; with none, where the intersection is stays unknown, so only a jump of the
        estimate re-evaluates it), then what is due to be said. Nothing while ``silent``."""
        if not self.ahead or self.silent:
            return
        odometer_m = est.odometer_m
        prev: Ahead | None = None
        steady_for = self.history.steady_for_m(
            odometer_m, max(ROAD_STEADY_M, self.history.steady_m)
        )
        steady = steady_for >= self.history.steady_m
        on_road = steady_for >= ROAD_STEADY_M
        for i, a in enumerate(self.ahead[:2]):
            if i == 0 or (prev is not None and prev.decision is not None):
                was = a.approach_heading_rad
                self._set_approach(a, prev, est, steady, on_road)
                due = force or odometer_m - a.last_eval_odometer_m >= EVAL_EVERY_M
                if was is not None and a.approach_heading_rad is not None:
                    # a new road (the car settled on another after a turn): a new turn
                    moved = abs(wrap_angle(a.approach_heading_rad - was))
                    due = due or moved > self.history.steady_tol_rad
                if a.at_odometer_m is None and a.decision is not None:
                    due = jumped
                if a.approach_heading_rad is not None and due:
                    self._evaluate(a, est, t_s, out, jumped)
            prev = a
        self.announcer.announce(self.ahead, t_s, est, out)

    def _set_approach(
        self,
        a: Ahead,
        prev: Ahead | None,
        est: EstimateState,
        steady: bool,
        on_road: bool,
    ) -> None:
        """The heading of the road ``a`` is approached on: the car's own once it has been
        steady on that road for ``ROAD_STEADY_M`` (a turn's tail, a U-turn settling back onto
        the road, must not name the manoeuvre), else the exit chosen at the intersection
        before it (not for one reported once the car was there: ``Ahead.on_taken_road``)."""
        odometer_m = est.odometer_m
        on_its_road = past(prev, est, self.history.steady_tol_rad)
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
        elif prev and prev.decision and a.approach_heading_rad is None and not a.on_taken_road:
            a.approach_heading_rad = prev.decision.exit_heading_rad  # (else: the car's own)
        elif prev is None and a.approach_heading_rad is None and steady:
            # Just out of a turn: the exit it took is the road, if the car has kept to it.
            taken = self.exits.last_exit_heading_rad
            heading = est.heading_rad
            if (
                taken is not None
                and abs(wrap_angle(heading - taken)) <= self.history.steady_tol_rad
            ):
                a.approach_heading_rad = taken

    def _evaluate(
        self,
        a: Ahead,
        est: EstimateState,
        t_s: float,
        out: Outputs,
        jumped: bool = False,
    ) -> None:
        """The law for ``a`` now. Once its instruction was said, another exit replaces it only
        after the estimate jumped (a landmark fix), where the distance is known, and by more
        than ``CHANGE_MARGIN_RAD``: the target the law picks drifts as the car drives, and a
        driver told one way must not hear the other for that."""
        exits = a.exits_now()
        if exits is None or a.approach_heading_rad is None or self.navigator.goal is None:
            return  # (no goal: the planner takes no report, but a checkpoint may hold one)
        a.last_eval_odometer_m = est.odometer_m
        at = predicted_xy(self.ahead, a, est)
        new = self.navigator.evaluate(
            t_s, at, pose_covariance(est), exits, a.approach_heading_rad, (est.x_m, est.y_m)
        )
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

    # -- views and checkpoints ------------------------------------------------------------------
    def planned_exit(self, seq: int) -> int | None:
        """The exit now planned for report ``seq`` (the simulated driver follows it)."""
        for a in self.ahead:
            if a.seq == seq and a.decision is not None:
                return a.decision.exit_index
        return None

    def next_ahead(self, odometer_m: float) -> tuple[Decision | None, float | None]:
        """The decision for the next intersection still ahead and its distance (None: unknown)."""
        _i, a = announce_target(self.ahead, odometer_m)
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
            "last_said": self.announcer.last_said,
        }

    def restore(self, snap: Mapping[str, object]) -> None:
        ahead = snap.get("ahead", [])
        if not isinstance(ahead, list) or len(ahead) > MAX_AHEAD:
            raise ValueError(f"guide.ahead must be a list of at most {MAX_AHEAD}")
        self.ahead = [Ahead.from_dict(a) for a in ahead if isinstance(a, dict)]
        self.history.restore(snap.get("history", []))
        self.reports = integer(snap.get("reports", 0), "guide.reports")
        self.last_seq = integer(snap.get("last_seq", 0), "guide.last_seq")
        self.announcer.last_said = str(snap.get("last_said", ""))[:40]
        self._undo = None  # a cancel withdraws only what was reported since
        decided = [a.decision for a in self.ahead if a.decision is not None]
        self.last_decision = decided[-1] if decided else None
