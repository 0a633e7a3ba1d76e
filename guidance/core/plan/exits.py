"""The exit taken at each intersection ahead, from what the car did (pure).

An intersection is resolved from the car's heading through it (the turn detector on the
estimated heading), with the distance where it is known: a turn once the car is near it, or
``straight_after_m`` past it with no turn. With no distance, never by distance alone: by a
detected turn, a co-driver's turn report, or, once the co-driver has reported the next
intersection, ``PASSED_STRAIGHT_M`` of steady heading after that. After a CAN gap the places
it leaves unplaced are dropped (or, one alone with a turn on the compass, resolved there). Only
then is the intersection remembered for the tabu law, at the estimate where the car got to it,
with the exit it really took (``Navigator.commit``).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np

from guidance.core.messages import EstimateState, ExitTaken, TurnCompleted
from guidance.core.model import wrap_angle
from guidance.core.plan.announce import heading_cannot_tell, heading_sd
from guidance.core.plan.config import PlannerConfig
from guidance.core.plan.navigator import Navigator
from guidance.core.plan.road import Ahead, RoadHistory, pose_covariance, unplaced_after_gap
from guidance.core.stages import Outputs

PASSED_STRAIGHT_M = 10.0
"""No distance: once the next intersection is reported (so the car is at or in this one), a
heading that has not turned over this much travel means the car went straight on (a car that
turns at a corner a few metres ahead has turned by half within it)."""


class ExitResolver:
    """Which exit the car took at the first intersection ahead, and when it is behind (see
    the module doc); the guide hands it its queue at each call."""

    def __init__(
        self,
        config: PlannerConfig,
        navigator: Navigator,
        counts: Counter[str],
        history: RoadHistory,
    ) -> None:
        self.config = config
        self.navigator = navigator
        self.counts = counts
        self.history = history
        self.last_exit_heading_rad: float | None = None
        """The exit the car took at the last intersection it went through (estimate frame)."""
        self.heading_before_gap = 0.0
        """The history's heading at the last odometry step (not dead-reckoned)."""

    def co_driver_turn(
        self, ahead: list[Ahead], turn: TurnCompleted, est: EstimateState, out: Outputs
    ) -> bool:
        """The co-driver says which way the car went: the first intersection ahead resolved
        with it. False when nothing was ahead."""
        if not ahead:
            return False
        first = ahead[0]
        base = first.approach_heading_rad
        heading = est.heading_rad if base is None else wrap_angle(base + turn.heading_change_rad)
        self._resolve(ahead, first, turn.t_s, heading, turn.source, est, out)
        return True

    def after_gap(
        self,
        ahead: list[Ahead],
        t_s: float,
        gap_from_s: float,
        placeable_s: float,
        est: EstimateState,
        out: Outputs,
    ) -> None:
        """The wheel speeds are back after a silence (``road.unplaced_after_gap``). One place
        no longer placed and a turn on the compass meanwhile: the turn was made there. Others
        cannot be told apart (passed straight, turned at, still ahead): dropped unsaid, never
        resolved by distance or credited with a later turn."""
        lost = unplaced_after_gap(ahead, gap_from_s, t_s, placeable_s)
        turned = abs(self.history.unwrapped_rad - self.heading_before_gap)
        if len(lost) == 1 and turned >= self.config.turn_detector.min_turn_rad:
            self._resolve(ahead, lost[0], t_s, est.heading_rad, "compass_gap", est, out)
            lost = []
        for a in lost:
            ahead.remove(a)
        self.counts["ahead_unplaced_after_gap"] += len(lost)

    def check(
        self,
        ahead: list[Ahead],
        t_s: float,
        est: EstimateState,
        turn: TurnCompleted | None,
        out: Outputs,
    ) -> None:
        """After a move of the estimate: whether the first intersection ahead is behind the
        car now (a turn near it, or well past it with none; with no distance, a turn, or
        steady past it once the next was reported), and by which exit."""
        a = ahead[0]
        cfg = self.config
        heading, odometer_m = est.heading_rad, est.odometer_m
        if a.at_odometer_m is not None:
            if a.reached is None and odometer_m >= a.at_odometer_m:
                a.reached = _reached(est)
            near = odometer_m >= a.at_odometer_m - cfg.turn_detector.window_m
            if turn is not None and near:
                self._resolve(ahead, a, t_s, heading, "detected", est, out)
            elif odometer_m >= a.at_odometer_m + cfg.straight_after_m and not est.reckoning:
                self._resolve(ahead, a, t_s, heading, "no_turn", est, out)
            return
        if turn is not None and a.approach_heading_rad is not None:
            self._resolve(ahead, a, t_s, heading, "detected", est, out)
        elif (
            a.passed_odometer_m is not None
            and a.passed_heading_rad is not None
            and odometer_m >= a.passed_odometer_m + PASSED_STRAIGHT_M
            and self.history.steady(odometer_m)
            and abs(wrap_angle(heading - a.passed_heading_rad))
            < 0.5 * cfg.turn_detector.min_turn_rad
        ):
            self._resolve(ahead, a, t_s, heading, "passed", est, out)

    def _resolve(
        self,
        ahead: list[Ahead],
        a: Ahead,
        t_s: float,
        heading: float,
        source: str,
        est: EstimateState,
        out: Outputs,
    ) -> None:
        """``a`` is behind the car, which left it with ``heading``: the exit taken, remembered."""
        ahead.remove(a)
        d = a.decision
        if d is None:  # never decided (its road never became known): nothing to remember
            self.counts["resolved_undecided"] += 1
            return
        best = min(d.options, key=lambda o: abs(wrap_angle(o.heading_rad - heading))).index
        blind = heading_cannot_tell(d, heading_sd(pose_covariance(est)))
        if best != d.exit_index and source != "co-driver" and blind:
            best = d.exit_index  # the heading cannot tell the exits apart: as advised
            self.counts["exit_assumed_followed"] += 1
        followed = best == d.exit_index
        if not followed:
            self.counts["advice_not_followed"] += 1
            # Intersections reported behind this one were on the road of the advised exit.
            dropped = [b for b in ahead if b.t_s <= t_s and b.at_odometer_m is not None
                       and not b.on_taken_road]  # fmt: skip
            for b in dropped:
                ahead.remove(b)
            self.counts["ahead_dropped"] += len(dropped)
        reached = a.reached
        if reached is None:  # distance unknown: where the turn began, else where it was passed
            back = self.config.turn_detector.settle_m + 5.0 if source == "detected" else 0.0
            odo = (a.passed_odometer_m if a.passed_odometer_m is not None and source != "detected"
                   else self.history.last_odometer_m - back)  # fmt: skip
            xy = self.history.at(odo)
            _x, _y, pxx, pxy, pyy = _reached(est)
            px, py = xy if xy is not None else (est.x_m, est.y_m)
            reached = (px, py, pxx, pxy, pyy)
        rx, ry, pxx, pxy, pyy = reached
        Pm = np.array([[pxx, pxy], [pxy, pyy]])
        k = self.navigator.commit((rx, ry), Pm, d.options[best].heading_rad)
        nxt = ahead[0] if ahead else None
        if nxt is not None and nxt.relative and nxt.approach_heading_rad is None:
            nxt.approach_heading_rad = d.options[best].heading_rad  # the road it is typed on
        self.last_exit_heading_rad = d.options[best].heading_rad
        out.exits_taken.append(
            ExitTaken(t_s, replace(d, intersection_id=k), best, followed, source)
        )


def _reached(est: EstimateState) -> tuple[float, float, float, float, float]:
    """Where the car is, with its x-y covariance (pxx, pxy, pyy): an intersection reached."""
    c = est.covariance
    return est.x_m, est.y_m, c[0][0], c[0][1], c[1][1]
