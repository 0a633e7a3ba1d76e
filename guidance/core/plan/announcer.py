"""What is said of the intersections ahead, and when (pure): the guide's announcements.

The ``Guide`` keeps the queue of intersections ahead and decides their exits; the
``Announcer`` says them: the next intersection still ahead once the car is past the one before
(``road.announce_target``), at the distances ``announce.due_announcements`` names, with its
"then" when the next one follows closely, never a straight twice, never the same words twice
within ``REPEAT_S``, and nothing for an intersection the car arrives before
(``announce.arrives_before``) or while the distance is dead-reckoned.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

from guidance.core import speech
from guidance.core.messages import EstimateState, Priority, Prompt, Say, Speech
from guidance.core.plan.announce import (
    WORD_SIGMAS,
    arrives_before,
    due_announcements,
    heading_sd,
    heads_along,
    too_late,
)
from guidance.core.plan.config import PlannerConfig
from guidance.core.plan.navigator import Navigator
from guidance.core.plan.road import Ahead, announce_target, pose_covariance, predicted_xy
from guidance.core.stages import Outputs

REPEAT_S = 5.0
"""The same sentence is not said twice within this time (unless it says a change)."""


class Announcer:
    """What is said of the intersections ahead (see the module doc); the guide hands it its
    queue at each call."""

    def __init__(self, config: PlannerConfig, navigator: Navigator, counts: Counter[str]) -> None:
        self.config = config
        self.navigator = navigator
        self.counts = counts
        self.last_said = ""
        """The last turn manoeuvre said (a straight after a straight is not repeated)."""
        self._said_at: dict[str, float] = {}

    def announce(self, ahead: list[Ahead], t_s: float, est: EstimateState, out: Outputs) -> None:
        """What is due for the next intersection still ahead of the car."""
        odometer_m = est.odometer_m
        i, a = announce_target(ahead, odometer_m)
        if a is None or a.decision is None:
            return
        if self._arrives_before(ahead, a, est):
            self.counts["goal_intersection_not_said"] += 1  # "You have arrived" comes first
            a.said_exit = a.decision.exit_index  # held as if said: no silent swapping
            return
        if est.reckoning and a.at_odometer_m is not None:
            self.counts["words_withheld_gap"] += 1  # said once the wheels speak again
            return
        if self._turning_off(a, est):
            self.counts["words_withheld_turning"] += 1  # its road is not known yet
            return
        d = a.decision
        band = WORD_SIGMAS * heading_sd(pose_covariance(est)) if a.approach_estimated else 0.0
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
            then = self._then(ahead, i, a, est)
            say = Say(Speech.TURN, d.turn_rad, None, *then, band, d.exit_heading_rad, changed)
            self._speak(ahead, a, out, t_s, say, action)
            return
        distance = max(0.0, a.at_odometer_m - odometer_m)
        if a.said_exit < 0 and too_late(distance, est.speed_mps):  # (a decision just made)
            self.counts["too_late_not_said"] += 1  # the driver cannot act on it any more
            a.said_exit, a.frozen = d.exit_index, True  # held as if said, never changed
            a.announced.update(("early", "before"))
            return
        due = due_announcements(distance, est.speed_mps, a.announced)
        if not due and not changed:
            return
        if due:
            a.announced.add(due[0])
            if due[0] == "before":
                a.frozen = True  # what the driver hears just before is what the car does
        unsure = est.ellipse.major_axis_m > self.config.uncertain_warn_m  # a fix may change it
        if (straight or unsure) and not changed and (not due or due[0] == "early"):
            return  # straight through needs no early warning (OsmAnd, Organic Maps)
        if straight and not changed and self.last_said == "continue straight":
            self.counts["straight_not_repeated"] += 1
            a.said, a.said_exit = action, d.exit_index
            return
        then = self._then(ahead, i, a, est)
        say = Say(Speech.TURN, d.turn_rad, distance, *then, band, d.exit_heading_rad, changed)
        self._speak(ahead, a, out, t_s, say, action)

    def _turning_off(self, a: Ahead, est: EstimateState) -> bool:
        """The road ``a`` is approached on was taken from the car's own heading, and the car
        has left that heading by more than the heading's noise explains (the turn detector's
        tolerance, or ``WORD_SIGMAS`` of the estimate): it is turning, e.g. at a corner the car
        could not place (after a CAN gap) or one reported short. The road it will approach on
        is the one it settles on: nothing is named against the old one (the guide sets the
        road again once the car is steady on it)."""
        if not a.approach_estimated or a.approach_heading_rad is None:
            return False
        sd = heading_sd(pose_covariance(est))
        tol = self.config.turn_detector.settle_tol_rad
        return not heads_along(est.heading_rad, a.approach_heading_rad, sd, tol)

    def _arrives_before(self, ahead: list[Ahead], a: Ahead, est: EstimateState) -> bool:
        """The car will be told it has arrived ``ARRIVE_MARGIN_M`` before it gets to ``a``:
        its road to ``a`` (from the car, or from the intersection before it) enters the arrival
        circle that far before ``a`` (a turn made before arriving is announced as any other)."""
        goal = self.navigator.goal
        if a.at_odometer_m is None or a.approach_heading_rad is None or goal is None:
            return False
        odometer_m = est.odometer_m
        start, start_odo = (est.x_m, est.y_m), odometer_m
        i = ahead.index(a) if a in ahead else 0
        if i > 0:  # on the road from the intersection before it
            prev = ahead[i - 1]
            if prev.at_odometer_m is not None and prev.at_odometer_m > odometer_m:
                if self._arrives_before(ahead, prev, est):
                    return True
                start = predicted_xy(ahead, prev, est)
                start_odo = prev.at_odometer_m
        radius = self.navigator.config.arrival_radius_m
        to_go = a.at_odometer_m - start_odo
        return arrives_before(goal, radius, start, a.approach_heading_rad, to_go)

    def _then(
        self, ahead: list[Ahead], i: int, a: Ahead, est: EstimateState
    ) -> tuple[float | None, float | None]:
        if i + 1 >= len(ahead):
            return None, None
        if est.ellipse.major_axis_m > self.config.uncertain_warn_m:
            # Uncertain (or lost): the next fix may replan beyond the next intersection (a
            # "then" said and then changed is a wrong word); its own prompt comes when next.
            self.counts["then_withheld_uncertain"] += 1
            return None, None
        b = ahead[i + 1]
        if b.decision is None or a.at_odometer_m is None or b.at_odometer_m is None:
            return None, None
        if self._arrives_before(ahead, b, est):
            b.said_exit = b.decision.exit_index  # held as if said, but the car arrives first
            return None, None
        return b.decision.turn_rad, b.at_odometer_m - a.at_odometer_m

    def _speak(
        self, ahead: list[Ahead], a: Ahead, out: Outputs, t_s: float, say: Say, action: str
    ) -> None:
        """Say ``say`` (a turn; a change said as one, "again" for another intersection with
        the same words right after), worded here by the table to compare with what was said."""
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
        out.prompts.append(Prompt(t_s, text, Priority.GUIDANCE, speech.kind(say), say))
        i = ahead.index(a)
        if i + 1 < len(ahead) and ", then " in text:
            nxt = ahead[i + 1]
            if nxt.decision is not None:
                nxt.said = speech.manoeuvre(nxt.decision.turn_rad)
                nxt.said_exit = nxt.decision.exit_index
