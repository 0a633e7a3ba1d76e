"""Stage 2 of the core ("plannerd"): the estimate and the scene in, decisions and prompts out.

``Planner.handle(msg, step)`` takes one input with what the first stage made of it (a
``LocalizeStep``: the estimates it produced, as values) and returns what it decided and says:
a ``PlanStep``. In the order of the reference trial (``hal_sim.reference``): after each move
of the estimate, the turn detector, the road ahead (``Guide.step``), the navigator's mode, the
uncertain / lost / arrival checks and the state publication with the chance of reaching the
goal; then the scene inputs (intersections, approaches, co-driver turns and cancels, goals).
It takes its own ``PlannerConfig`` and never imports the estimator (``tests/test_layers.py``).
With no goal (``PlannerConfig.goal_xy_m`` None) it publishes the state and says the
uncertainty and the loss as ever, and decides nothing: a report is refused (``no_goal``), no
chance, no arrival, until a ``GoalUpdate``.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import asdict

from guidance.core import speech
from guidance.core.messages import (
    Approach,
    CancelReport,
    CompassHeading,
    EstimateState,
    GoalUpdate,
    HeadingFix,
    IntersectionScene,
    LandmarkFix,
    Priority,
    Prompt,
    Say,
    Speech,
    Target,
    TurnCompleted,
)
from guidance.core.odometry_gap import placeable_s
from guidance.core.pipeline_state import PlanState
from guidance.core.plan.chance import ChanceWatch, shipped_or_none
from guidance.core.plan.config import PlannerConfig
from guidance.core.plan.guide import SAME_PLACE_M, Guide
from guidance.core.plan.navigator import Navigator
from guidance.core.plan.turns import TurnDetector
from guidance.core.snapshot_check import integer
from guidance.core.stages import LOST_HYSTERESIS, Input, LocalizeStep, Outputs

log = logging.getLogger(__name__)

PlanStep = Outputs
"""What the planner returns for one input: its decisions, exits taken, turns, prompts, arrival
and loss, the state when due, and its verdict on a scene input (``accepted``, ``reason``)."""

UNCERTAIN_HYSTERESIS = LOST_HYSTERESIS
"""The uncertainty warning re-arms once the major axis is back below this fraction of it."""
LANDMARK_REPEAT_S = 30.0
"""A landmark confirmed again within this time (the same pass) is not announced again."""


class Planner:
    """Navigator + guide + turn detector + chance, driven by estimates and scene inputs."""

    def __init__(self, config: PlannerConfig, counts: Counter[str] | None = None) -> None:
        self.config = config
        self.counts: Counter[str] = Counter() if counts is None else counts
        self.st = PlanState(placed=not config.start_unknown)
        self.next_state_t = -math.inf
        self.navigator = Navigator(config.goal_xy_m, config.navigator, config.landmarks)
        self.chance = ChanceWatch(
            config.chance,
            shipped_or_none() if config.chance.enabled else None,
            config.navigator.method.value,
        )
        if config.goal_xy_m is not None:  # else: counted when a goal comes (``_set_goal``)
            self.chance.set_trip(self._landmarks_xy(), config.start_xy_m, config.goal_xy_m)
        self.turns = TurnDetector(config.turn_detector)
        self.guide = Guide(config, self.navigator, self.counts)
        self.guide.silent = not self.st.placed  # kept, undecided and unsaid, until placed

    # -- the one entry point ----------------------------------------------------------------
    def handle(self, msg: Input, step: LocalizeStep) -> PlanStep:
        """Plan on ``step``'s estimates, then on ``msg`` if it is a scene input."""
        out = Outputs()
        est = step.estimate
        assert est is not None, "Localizer.handle sets the estimate"
        for move in step.moves:
            if move.gap_from_s is not None:  # the places ahead after a silence, judged once
                self.turns.reset()  # the heading across the gap is judged there, not again
                placeable = placeable_s(SAME_PLACE_M)  # the gap's bound within "same place"
                self.guide.after_gap(move.t_s, move.gap_from_s, placeable, move.estimate, out)
            if move.odometry:
                turn = self.turns.update(move.t_s, move.estimate.heading_rad,
                                         move.estimate.odometer_m)  # fmt: skip
                if turn is not None:
                    out.turns.append(turn)
                self.guide.step(move.t_s, move.estimate, turn, out)
                self._after_step(move.t_s, move.estimate, step, out)
            else:  # dead reckoning: the intersections ahead move on with it (turns detected)
                self.guide.step(move.t_s, move.estimate, None, out)
        if isinstance(msg, CompassHeading | HeadingFix):  # taken or not, the checks follow
            if step.heading_found:
                self.turns.reset()  # the heading history before it says nothing
            self._after_step(msg.t_s, est, step, out)
        elif isinstance(msg, LandmarkFix):
            self._landmark(msg, est, step, out)
        elif isinstance(msg, GoalUpdate):
            self._set_goal(msg, est, out)
        elif isinstance(msg, IntersectionScene):
            self._intersection(msg, est, out)
        elif isinstance(msg, TurnCompleted):
            self._turn(msg, est, out)
        elif isinstance(msg, CancelReport):
            self._cancel(msg, est, out)
        elif isinstance(msg, Approach):
            self.guide.approach(msg, est, out)
        return out

    # -- inputs -------------------------------------------------------------------------------
    def _landmark(
        self, fix: LandmarkFix, est: EstimateState, step: LocalizeStep, out: Outputs
    ) -> None:
        was_lost = self.st.lost_said
        if not step.accepted:
            out.landmark_rejections.append((fix, step.reason or "rejected"))
            self._after_step(fix.t_s, est, step, out)
            return
        out.landmark_updates.append(fix)
        self.navigator.on_landmark_fix(fix.landmark_id, est.ellipse.major_axis_m)
        name = next((lm.name for lm in self.config.landmarks if lm.id == fix.landmark_id), "")
        last = self.st.landmark_said.get(str(fix.landmark_id), -math.inf)
        still_lost = est.ellipse.major_axis_m > self.config.lost_major_axis_m
        if (step.relocalised or was_lost) and still_lost:
            # a reset as wide as lost itself (a sighting range over a quarter of the lost
            # axis: ``landmark_warnings``) finds nothing the driver can use: no "found"
            self.counts["relocalisations_still_lost"] += 1
            log.warning("landmark %d found while lost, but its reset is %.0f m across: "
                        "still lost", fix.landmark_id, est.ellipse.major_axis_m)  # fmt: skip
        elif step.relocalised or was_lost:  # found again: said by the place's name
            self.counts["relocalisations"] += 1
            first, self.st.placed = not self.st.placed, True
            self.guide.silent = False
            # found: a reset's ellipse (80 m across for a 20 m sight) sits on the lost
            # hysteresis, so the episode is closed here, not by the axis
            self.st.lost_said = False
            self.st.landmark_said[str(fix.landmark_id)] = fix.t_s
            self.turns.reset()  # the heading history before the jump says nothing now
            how = "reset there" if step.relocalised else "inside the lost ellipse"
            log.warning("position found again near landmark %d %r (%s)",
                        fix.landmark_id, name, how)  # fmt: skip
            say = Say(Speech.FOUND, name=name, again=not first)
            self._say(out, fix.t_s, say, Priority.SAFETY)
        elif fix.t_s - last >= LANDMARK_REPEAT_S:  # a second fix from the same pass: silent
            self.st.landmark_said[str(fix.landmark_id)] = fix.t_s
            self._say(out, fix.t_s, Say(Speech.LANDMARK, name=name), Priority.INFO)
        self._after_step(fix.t_s, est, step, out, mode_done=True)
        self.guide.replan(fix.t_s, est, out)

    def _intersection(self, scene: IntersectionScene, est: EstimateState, out: Outputs) -> None:
        if not scene.exit_headings_rad:
            out.accepted, out.reason = False, "no_exits"
            return
        if self.navigator.goal is None:  # nowhere to go: nothing to decide until a goal comes
            out.accepted, out.reason = False, "no_goal"
            self.counts["reports_without_goal"] += 1
            return
        if not est.heading_known:  # no advice out of a heading the car does not have
            out.accepted, out.reason = False, "heading_unknown"
            self.counts["advice_withheld"] += 1
            if not self.st.waiting_said:
                self.st.waiting_said = True
                self._say(out, scene.t_s, Say(Speech.WAITING_FOR_HEADING), Priority.SAFETY)
            return
        self.guide.report(scene, est, out)

    def _turn(self, turn: TurnCompleted, est: EstimateState, out: Outputs) -> None:
        out.turns.append(turn)
        if not self.guide.co_driver_turn(turn, est, out):
            log.info("turn of %.0f deg reported with no intersection ahead",
                     math.degrees(turn.heading_change_rad))  # fmt: skip
        self.turns.reset()  # the co-driver's report replaces what the heading would show

    def _cancel(self, msg: CancelReport, est: EstimateState, out: Outputs) -> None:
        """The co-driver takes the last report back: withdrawn while the car has not reached
        it ("The last report is cancelled."), else "Nothing to cancel."."""
        done = self.guide.cancel(est.odometer_m)
        if not done:
            out.accepted, out.reason = False, "nothing_to_cancel"
        said = Speech.REPORT_CANCELLED if done else Speech.CANNOT_CANCEL
        self._say(out, msg.t_s, Say(said), Priority.GUIDANCE)

    def _set_goal(self, goal: GoalUpdate, est: EstimateState, out: Outputs) -> None:
        if not (math.isfinite(goal.x_m) and math.isfinite(goal.y_m)):
            out.accepted, out.reason = False, "non_finite_goal"
            return
        self.navigator.set_goal((goal.x_m, goal.y_m))
        self.chance.set_trip(self._landmarks_xy(), (est.x_m, est.y_m), (goal.x_m, goal.y_m))
        self.st.arrived = False
        self.st.finished = False
        self.st.chance_said = False
        # a goal from the network is said as such: the driver hears who changed the route
        say = Say(Speech.NEW_DESTINATION, remote=goal.source == "remote")
        self._say(out, goal.t_s, say, Priority.INFO)
        self.guide.replan(goal.t_s, est, out)

    # -- after every estimator step -------------------------------------------------------------
    def _after_step(
        self,
        t: float,
        est: EstimateState,
        step: LocalizeStep,
        out: Outputs,
        mode_done: bool = False,
    ) -> None:
        major = est.ellipse.major_axis_m
        lost_axis = self.config.lost_major_axis_m
        lost = major > lost_axis  # the estimator's lost, axis computed once
        if not mode_done:
            self.navigator.update_mode(major)
        warn = self.config.uncertain_warn_m
        if not self.st.uncertain_said and major > warn and not lost:
            self.st.uncertain_said = True
            self._say(out, t, Say(Speech.UNCERTAIN, distance_m=major), Priority.SAFETY)
        elif self.st.uncertain_said and major < UNCERTAIN_HYSTERESIS * warn:
            self.st.uncertain_said = False
        if lost:
            out.lost = True
            if not self.st.lost_said and not self.st.placed:  # started anywhere: not lost
                self.st.lost_said = True
                self._say(out, t, Say(Speech.POSITION_UNKNOWN), Priority.SAFETY)
            elif not self.st.lost_said:
                self.st.lost_said = True
                self.counts["lost_episodes"] += 1
                searching = self.config.relocalise
                self._say(out, t, Say(Speech.LOST, searching=searching), Priority.SAFETY)
                if self.config.stop_at_arrival and not searching:
                    self.st.finished = True
        elif self.st.lost_said and major < LOST_HYSTERESIS * lost_axis:
            self.st.lost_said = False
        if not lost and not self.st.arrived and self.navigator.arrived((est.x_m, est.y_m)):
            self.st.arrived = True
            out.arrived = True
            self._say(out, t, Say(Speech.ARRIVED), Priority.GUIDANCE)
            if self.config.stop_at_arrival:
                self.st.finished = True
        if t >= self.next_state_t:
            self.next_state_t = t + self.config.state_period_s
            out.state = est
            self._chance(t, est, step.compass_unusable, out, major)

    def _chance(
        self, t: float, est: EstimateState, compass_unusable: bool, out: Outputs, major: float
    ) -> None:
        """The chance of reaching the goal, at each state publication; said once when low.
        With no goal there is none (the state's ``chance`` is null)."""
        goal = self.navigator.goal
        if goal is None:
            return
        to_go = math.hypot(goal[0] - est.x_m, goal[1] - est.y_m)
        sigma = self.config.compass_two_sigma_deg
        if compass_unusable:
            sigma = None  # the compass is not helping: the table's no-compass slice
        quiet = self.st.lost_said or self.st.arrived or self.st.finished
        say, self.st.chance_said = self.chance.update(
            to_go, major, self.config.lost_major_axis_m, sigma,
            said=self.st.chance_said, quiet=quiet,
        )  # fmt: skip
        out.chance = self.chance.value
        if say is not None:
            self._say(out, t, say, Priority.INFO)

    def _landmarks_xy(self) -> list[tuple[float, float]]:
        return [(lm.x_m, lm.y_m) for lm in self.navigator.landmarks]

    def _say(self, out: Outputs, t: float, say: Say, priority: Priority) -> None:
        """One prompt, its words made by the table (``speech.words``, ``[navigation] units``)."""
        text = speech.words(say, self.config.units)
        out.prompts.append(Prompt(t, text, priority, speech.kind(say), say))

    # -- views ----------------------------------------------------------------------------------
    def target(self, est: EstimateState) -> Target | None:
        """What the car aims at now (the goal, or a landmark on the way); None: no goal."""
        if self.navigator.goal is None:
            return None
        return self.navigator.target((est.x_m, est.y_m))

    # -- checkpoints ----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, object]:
        return {
            "navigator": self.navigator.memory(),
            "turns": self.turns.snapshot(),
            "decisions": self.navigator.decisions,
            "guide": self.guide.snapshot(),
            **asdict(self.st),
        }

    def restore(self, snap: Mapping[str, object], st: PlanState) -> None:
        """The navigator's memory, the turn detector and the road ahead from ``snap`` (checked
        by the caller), and the planner's bookkeeping ``st``."""
        self.st = st
        self.next_state_t = -math.inf
        nav = snap["navigator"]
        assert isinstance(nav, dict)
        self.navigator.restore(nav)
        self.navigator.decisions = integer(snap.get("decisions", 0), "decisions")
        turns = snap.get("turns")
        if isinstance(turns, dict):
            self.turns.restore(turns)
        guide = snap.get("guide")
        if isinstance(guide, dict):
            self.guide.restore(guide)
        self.guide.silent = not self.st.placed
