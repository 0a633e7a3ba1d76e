"""The in-car core as a pure, message-driven object: timestamped messages in, outputs out.

``Pipeline.feed(msg)`` takes one input (wheel odometry, compass reading, heading fix,
landmark fix, intersection scene, turn report, new goal) and returns what it caused:
decisions, prompts, landmark updates, turns, health changes, and the state when it is due.
No I/O, no clock reads, no asyncio: the time is the message's ``t_s``. The live app
(``guidance.app``), the accelerated simulation (``hal_sim.drive``), replay
(``guidance.replay``) and the tests all drive this same object, so they compute the same thing.

The order of work inside one input follows the reference trial (``hal_sim.reference``):
estimator step, navigator mode update, lost / arrival checks, then a decision if the input
was an intersection. ``snapshot``/``restore`` give the whole state as plain data (checkpoints).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import asdict

import numpy as np

from guidance.core import speech
from guidance.core.health import (
    BAD_STATUSES,
    CompassJudge,
    DeviceStatus,
    HealthMonitor,
)
from guidance.core.localize.compass_cal import CompassCalibration, compass_heading_to_theta
from guidance.core.localize.estimator import LOST_HYSTERESIS, RELOCALISED, PoseEstimator
from guidance.core.localize.odometry_gap import placeable_s
from guidance.core.messages import (
    Approach,
    CancelReport,
    CompassHeading,
    EstimateState,
    GoalUpdate,
    HeadingFix,
    Health,
    IntersectionScene,
    LandmarkFix,
    Priority,
    Prompt,
    Say,
    Speech,
    Target,
    TurnCompleted,
    WheelOdometry,
)
from guidance.core.pipeline_config import INPUT_KINDS, Input, Outputs, PipelineConfig
from guidance.core.pipeline_state import PipelineState, Transient
from guidance.core.plan.chance import ChanceWatch, shipped_or_none
from guidance.core.plan.guide import SAME_PLACE_M, Guide
from guidance.core.plan.navigator import Decision, Navigator
from guidance.core.plan.turns import TurnDetector
from guidance.core.snapshot_check import check_snapshot, integer

log = logging.getLogger(__name__)


UNCERTAIN_HYSTERESIS = LOST_HYSTERESIS
"""The uncertainty warning re-arms once the major axis is back below this fraction of it."""
HEALTH_EVAL_PERIOD_S = 0.25
"""Health is re-evaluated at most this often on the message clock."""


# ----------------------------------------------------------------------------- the pipeline


LANDMARK_REPEAT_S = 30.0
"""A landmark confirmed again within this time (the same pass) is not announced again."""

GAP_HOLD_S = 5.0
"""An odometry increment this long after the previous one waits for the next to confirm its
time (a glitch stamping one frame far ahead must not widen the estimate by hours of driving)."""

DR_AFTER_S = 0.1
DR_AFTER_PERIODS = 3.0
"""Odometry this late (the larger of the two: 0.1 s, three frames) is dead-reckoned over until
it comes: a stale estimate with a tight ellipse would put the truth outside it."""


UNKNOWN_START_SIGMA_M = 10_000.0
"""A car that starts anywhere (``PipelineConfig.start_unknown``) is somewhere in a city 20 km
across (the 2-sigma circle): lost from the first step, and any landmark it finds is inside."""


class Pipeline:
    """Estimator + navigator + turn detector + health, driven by messages (see module doc)."""

    def __init__(self, config: PipelineConfig) -> None:
        self.config = config
        heading = config.start_heading_rad
        self.estimator = PoseEstimator(
            config.estimator, config.start_xy_m[0], config.start_xy_m[1], heading or 0.0
        )
        self.st = PipelineState(heading_known=heading is not None)
        self.tr = Transient()
        if not self.st.heading_known:
            self.estimator.forget_heading()
        if config.start_unknown:
            self.st.placed = False
            self.estimator.inflate_position(2.0 * UNKNOWN_START_SIGMA_M)
        self.navigator = Navigator(config.goal_xy_m, config.navigator, config.landmarks)
        self.chance = ChanceWatch(
            config.chance,
            shipped_or_none() if config.chance.enabled else None,
            config.navigator.method.value,
        )
        self.chance.set_trip(self._landmarks_xy(), config.start_xy_m, config.goal_xy_m)
        self.turns = TurnDetector(config.turn_detector)
        self.health = HealthMonitor(config.expected_rates_hz, config.health)
        dev = config.compass_deviation_deg
        self._deviation = CompassCalibration(*dev) if any(dev) else None
        self.compass_judge = CompassJudge(
            config.compass_unusable_after_s,
            calibrated=self._deviation is not None or config.mounting_offset_deg != 0.0,
        )
        self.counts: Counter[str] = Counter()
        self.guide = Guide(
            config, self.navigator, self._say, self.counts, lambda: self.st.speed_mps,
            lambda: self.tr.dr_to_t is not None,  # the distance is being dead-reckoned
        )  # fmt: skip

    # -- the one entry point ----------------------------------------------------------------
    def feed(self, msg: Input) -> Outputs:
        """Apply one timestamped input and return what it caused."""
        out = Outputs()
        t = msg.t_s
        if not math.isfinite(t):
            out.accepted, out.reason = False, "non_finite_time"
            self.counts["rejected"] += 1
            return out
        kind = INPUT_KINDS.get(type(msg), "other")
        self.counts[type(msg).__name__] += 1
        self.health.observe(kind, t)
        if self.tr.last_t is None or t > self.tr.last_t:
            self.tr.last_t = t
        if isinstance(msg, CompassHeading | HeadingFix) and not self.st.finished:
            self._dead_reckon(t, out)
        if isinstance(msg, GoalUpdate):
            self._set_goal(msg, out)
        elif self.st.finished:
            out.accepted, out.reason = False, "finished"
        elif isinstance(msg, WheelOdometry):
            self._odometry(msg, out)
        elif isinstance(msg, CompassHeading):
            self._heading(self.compass_fix(msg), out)
        elif isinstance(msg, HeadingFix):
            self._heading(msg, out)
        elif isinstance(msg, LandmarkFix):
            self._landmark(msg, out)
        elif isinstance(msg, IntersectionScene):
            self._intersection(msg, out)
        elif isinstance(msg, TurnCompleted):
            self._turn(msg, out)
        elif isinstance(msg, CancelReport):
            self._cancel(msg, out)
        elif isinstance(msg, Approach):
            self._approach(msg, out)
        elif isinstance(msg, DeviceStatus):
            self._device_status(msg, out)
        self._health(t, out, force=False)
        return out

    def tick(self, t_s: float) -> Outputs:
        """Time passes with no input (a silent car): health only; the estimate is untouched."""
        out = Outputs()
        if math.isfinite(t_s):
            self._health(t_s, out, force=True)
        return out

    def update_source_counts(self, name: str, read: int, rejected: int) -> None:
        """Feed a source's cumulative read/rejected counts (garbled-input detection)."""
        self.health.update_counts(name, read, rejected)

    # -- inputs -------------------------------------------------------------------------------
    def compass_fix(self, msg: CompassHeading) -> HeadingFix:
        """A compass reading as a filter heading: card, mounting offset, declination unless true."""
        cfg = self.config
        theta = compass_heading_to_theta(
            msg, cfg.declination_deg, cfg.mounting_offset_deg, self._deviation
        )
        return HeadingFix(msg.t_s, theta)

    def _odometry(self, msg: WheelOdometry, out: Outputs) -> None:
        held, self.tr.held_odometry = self.tr.held_odometry, None
        gap = None if self.tr.last_odo_t is None else msg.t_s - self.tr.last_odo_t
        if held is not None:
            if msg.t_s >= held.t_s:  # the new time base holds: the gap was real
                self._odometry_step(held, held.t_s - (self.tr.last_odo_t or held.t_s), out)
                gap = msg.t_s - held.t_s
            else:  # back before it: the frame ahead was a clock glitch, not a gap
                self.counts["time_glitch_dropped"] += 1
                log.warning("odometry stamped %.1f s ahead was a glitch: dropped",
                            held.t_s - msg.t_s)  # fmt: skip
        elif gap is not None and gap > max(GAP_HOLD_S, self.health.timeout_s("odometry")):
            # After a long silence, wait for the next increment to confirm the new time
            # (an adapter glitch stamps a frame an hour ahead): one increment of latency.
            self.tr.held_odometry = msg
            out.accepted, out.reason = False, "held_after_gap"
            return
        self._odometry_step(msg, gap, out)

    def _odometry_step(self, msg: WheelOdometry, gap: float | None, out: Outputs) -> None:
        est = self.estimator
        timeout = self.health.timeout_s("odometry")
        d_wheels = 0.5 * (msg.d_left_m + msg.d_right_m)
        # Beyond the dead-input timeout (>= 1 s, the decoder's longest bridged gap) the distance
        # driven meanwhile was not integrated: it is dead-reckoned at the speed *before* the gap
        # (the increment after it covers one frame, not the gap). Within it, the increment
        # covers the gap, so what dead reckoning already moved comes off it.
        long_gap = self.config.resume_gap_inflation and gap is not None and gap > timeout
        ahead_m = self.tr.dr_m
        if long_gap:
            self._dead_reckon(msg.t_s, None)
        elif ahead_m > 0.0:
            msg = WheelOdometry(msg.t_s, msg.d_left_m - ahead_m, msg.d_right_m - ahead_m)
        r = est.process(msg)
        out.accepted, out.reason = r.accepted, r.reason
        self._judge_time("odometry", r.reason)
        if not r.accepted:
            return
        if gap is not None and gap > 0:
            if long_gap:
                log.warning("odometry resumed after %.1f s: dead-reckoned %.0f m at %.1f m/s",
                            gap, self.tr.dr_m, self.st.speed_mps)  # fmt: skip
                self.counts["odometry_gaps"] += 1
                self.turns.reset()  # the heading across the gap is judged once, just below
                placeable = placeable_s(SAME_PLACE_M)  # the gap's bound within "same place"
                self.guide.after_gap(msg.t_s, msg.t_s - gap, placeable, est, out)
            else:
                self.st.speed_mps = abs(d_wheels) / gap
        if not long_gap:
            self.st.odometer_m = max(0.0, self.st.odometer_m - ahead_m)
        self.tr.dr_to_t, self.tr.dr_m = None, 0.0
        self.tr.last_odo_t = msg.t_s
        self.st.odometer_m += abs(d_wheels)
        turn = self.turns.update(msg.t_s, est.heading_rad, self.st.odometer_m)
        if turn is not None:
            out.turns.append(turn)
        self.guide.step(msg.t_s, est, self.st.odometer_m, turn, out)
        self._after_step(msg.t_s, out)

    def _dead_reckon(self, t: float, out: Outputs | None) -> None:
        """Odometry overdue (a CAN dropout, or a frame late) while the heading is known: the
        estimate moves on at the last speed along its heading, widened along the road by what
        the car could have gained or lost (``guidance.core.localize.odometry_gap``), up to
        ``t``. Called at each compass reading in the silence and when odometry resumes."""
        last = self.tr.last_odo_t
        rate = self.health.expected.get("odometry")
        if last is None or not rate or not self.config.resume_gap_inflation:
            return
        if not self.st.heading_known or t - last <= max(DR_AFTER_S, DR_AFTER_PERIODS / rate):
            return
        start = last if self.tr.dr_to_t is None else self.tr.dr_to_t
        if t <= start:
            return
        est = self.estimator
        est.coast(self.st.speed_mps, start - last, t - last)
        moved = abs(self.st.speed_mps) * (t - start)
        self.st.odometer_m += moved
        self.tr.dr_m += moved
        self.tr.dr_to_t = t
        if out is not None:  # the intersections ahead move on with it (turns detected)
            self.guide.step(t, est, self.st.odometer_m, None, out)

    def _heading(self, fix: HeadingFix, out: Outputs) -> None:
        est = self.estimator
        if not self.st.heading_known and est.config.compass_two_sigma_deg is not None:
            est.heading_from_compass(
                fix.theta_rad, math.radians(est.config.compass_two_sigma_deg / 2.0) ** 2
            )
            self.st.heading_known = True
            self.turns.reset()
            log.info("initial heading from the compass: %.0f deg", math.degrees(fix.theta_rad))
            self._after_step(fix.t_s, out)
            return
        r = est.process(fix)
        out.accepted, out.reason = r.accepted, r.reason
        self._judge_time("compass", r.reason)
        if r.reason == "out_of_order":  # a time problem, not the compass's data
            self._after_step(fix.t_s, out)
            return
        self.compass_judge.add(fix.t_s, r.accepted, r.reason)
        self.health.judge("compass", *self.compass_judge.verdict(fix.t_s))
        self._after_step(fix.t_s, out)

    def _landmark(self, fix: LandmarkFix, out: Outputs) -> None:
        was_lost = self.st.lost_said
        r = self.estimator.process(fix)
        out.accepted, out.reason = r.accepted, r.reason
        if r.accepted:
            self.st.landmark_updates += 1
            out.landmark_updates.append(fix)
            self.navigator.on_landmark_fix(fix.landmark_id, self.estimator.major_axis_m)
            name = next((lm.name for lm in self.config.landmarks if lm.id == fix.landmark_id), "")
            last = self.st.landmark_said.get(str(fix.landmark_id), -math.inf)
            if r.reason == RELOCALISED or was_lost:  # found again: said by the place's name
                self.counts["relocalisations"] += 1
                first, self.st.placed = not self.st.placed, True
                # found: a reset's ellipse (80 m across for a 20 m sight) sits on the lost
                # hysteresis, so the episode is closed here, not by the axis
                self.st.lost_said = False
                self.st.landmark_said[str(fix.landmark_id)] = fix.t_s
                self.turns.reset()  # the heading history before the jump says nothing now
                how = "reset there" if r.reason == RELOCALISED else "inside the lost ellipse"
                log.warning("position found again near landmark %d %r (%s)",
                            fix.landmark_id, name, how)  # fmt: skip
                say = Say(Speech.FOUND, name=name, again=not first)
                self._say(out, fix.t_s, say, Priority.SAFETY)
            elif fix.t_s - last >= LANDMARK_REPEAT_S:  # a second fix from the same pass: silent
                self.st.landmark_said[str(fix.landmark_id)] = fix.t_s
                self._say(out, fix.t_s, Say(Speech.LANDMARK, name=name), Priority.INFO)
            self._after_step(fix.t_s, out, mode_done=True)
            self.guide.replan(fix.t_s, self.estimator, self.st.odometer_m, out)
        else:
            out.landmark_rejections.append((fix, r.reason or "rejected"))
            self._after_step(fix.t_s, out)

    def _intersection(self, scene: IntersectionScene, out: Outputs) -> None:
        if not scene.exit_headings_rad:
            out.accepted, out.reason = False, "no_exits"
            return
        if not self.st.placed:  # started anywhere, no place found yet: no advice
            out.accepted, out.reason = False, "position_unknown"
            self.counts["advice_withheld"] += 1
            return
        if not self.st.heading_known:  # no advice out of a heading the car does not have
            out.accepted, out.reason = False, "heading_unknown"
            self.counts["advice_withheld"] += 1
            if not self.st.waiting_said:
                self.st.waiting_said = True
                self._say(out, scene.t_s, Say(Speech.WAITING_FOR_HEADING), Priority.SAFETY)
            return
        self.guide.report(scene, self.estimator, self.st.odometer_m, out)

    def _approach(self, msg: Approach, out: Outputs) -> None:
        if not self.st.placed:
            return
        self.guide.approach(msg, self.estimator, self.st.odometer_m, out)

    def _turn(self, turn: TurnCompleted, out: Outputs) -> None:
        out.turns.append(turn)
        if not self.guide.co_driver_turn(turn, self.estimator, out):
            log.info("turn of %.0f deg reported with no intersection ahead",
                     math.degrees(turn.heading_change_rad))  # fmt: skip
        self.turns.reset()  # the co-driver's report replaces what the heading would show

    def _cancel(self, msg: CancelReport, out: Outputs) -> None:
        """The co-driver takes the last report back: withdrawn while the car has not reached
        it ("The last report is cancelled."), else "Nothing to cancel."."""
        done = self.guide.cancel(self.st.odometer_m)
        if not done:
            out.accepted, out.reason = False, "nothing_to_cancel"
        speech_ = Speech.REPORT_CANCELLED if done else Speech.CANNOT_CANCEL
        self._say(out, msg.t_s, Say(speech_), Priority.GUIDANCE)

    def _set_goal(self, goal: GoalUpdate, out: Outputs) -> None:
        if not (math.isfinite(goal.x_m) and math.isfinite(goal.y_m)):
            out.accepted, out.reason = False, "non_finite_goal"
            return
        self.navigator.set_goal((goal.x_m, goal.y_m))
        est_xy = (float(self.estimator.x[0]), float(self.estimator.x[1]))
        self.chance.set_trip(self._landmarks_xy(), est_xy, (goal.x_m, goal.y_m))
        self.st.arrived = False
        self.st.finished = False
        self.st.chance_said = False
        # a goal from the network is said as such: the driver hears who changed the route
        say = Say(Speech.NEW_DESTINATION, remote=goal.source == "remote")
        self._say(out, goal.t_s, say, Priority.INFO)
        self.guide.replan(goal.t_s, self.estimator, self.st.odometer_m, out)

    # -- after every estimator step -------------------------------------------------------------
    def _after_step(self, t: float, out: Outputs, mode_done: bool = False) -> None:
        est = self.estimator
        major = est.major_axis_m
        lost = major > est.config.lost_major_axis_m  # the estimator's lost, axis computed once
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
        elif self.st.lost_said and major < LOST_HYSTERESIS * est.config.lost_major_axis_m:
            self.st.lost_said = False
        if not lost and not self.st.arrived and self.navigator.arrived(est.x):
            self.st.arrived = True
            out.arrived = True
            self._say(out, t, Say(Speech.ARRIVED), Priority.GUIDANCE)
            if self.config.stop_at_arrival:
                self.st.finished = True
        if t >= self.tr.next_state_t:
            self.tr.next_state_t = t + self.config.state_period_s
            out.state = est.state()
            self._chance(t, out, major)

    def _chance(self, t: float, out: Outputs, major: float) -> None:
        """The chance of reaching the goal, at each state publication; said once when low."""
        est = self.estimator
        goal = self.navigator.goal
        to_go = math.hypot(goal[0] - float(est.x[0]), goal[1] - float(est.x[1]))
        sigma = est.config.compass_two_sigma_deg
        if self.compass_judge.unusable:
            sigma = None  # the compass is not helping: the table's no-compass slice
        quiet = self.st.lost_said or self.st.arrived or self.st.finished
        say, self.st.chance_said = self.chance.update(
            to_go, major, est.config.lost_major_axis_m, sigma,
            said=self.st.chance_said, quiet=quiet,
        )  # fmt: skip
        out.chance = self.chance.value
        if say is not None:
            self._say(out, t, say, Priority.INFO)

    def _landmarks_xy(self) -> list[tuple[float, float]]:
        return [(lm.x_m, lm.y_m) for lm in self.navigator.landmarks]

    def _device_status(self, msg: DeviceStatus, out: Outputs) -> None:
        """A driver's status flip: the input's sentence for that status is what the driver
        hears ("Wheel speed bus disconnected. Position is getting less certain."), once per
        episode, whether the driver or the pipeline's clock noticed first."""
        went_bad = self.health.report(msg)
        if went_bad and msg.input not in self.st.warned:
            self.st.warned.append(msg.input)
            say = Say(Speech.SENSOR, input=msg.input, status=msg.health.status)
            self._say(out, msg.t_s, say, Priority.SAFETY)
        self._health(msg.t_s, out, force=True)

    def _judge_time(self, name: str, reason: str | None) -> None:
        """Inputs the estimator cannot place in time make their input invalid (a frozen
        estimate while inputs are alive is a fault, never silent)."""
        self.health.judge(
            name, reason != "out_of_order", "time: stamped before the estimate", aspect="time"
        )

    def _say(self, out: Outputs, t: float, say: Say, priority: Priority, text: str = "") -> None:
        """One prompt: its words made here (``speech.words``, ``[navigation] units``) unless
        the guide made them already to compare with what it said last."""
        self.st.prompt_count += 1
        text = text or speech.words(say, self.config.units)
        out.prompts.append(Prompt(t, text, priority, speech.kind(say), say))

    def _health(self, t: float, out: Outputs, force: bool) -> None:
        if not force and t < self.tr.next_health_t:
            return
        self.tr.next_health_t = t + HEALTH_EVAL_PERIOD_S
        for change in self.health.evaluate(t):
            out.health.append(change)
            st = change.status
            if st.alive and st.valid:
                if st.name in self.st.warned:
                    self.st.warned.remove(st.name)
                log.warning("%s is back (%.1f Hz)", st.name, st.rate_hz)
                continue
            problem = "is silent" if not st.alive else "sends bad data"
            bad = "silent" if not st.alive else "invalid"
            status = st.status if st.status in BAD_STATUSES else bad
            judged = st.name == "compass" and st.alive and self.compass_judge.unusable
            if judged:  # its readings arrive and parse; the filter rejects most of them
                log.warning("compass is unusable (%s): the filter rejected most of its "
                            "readings over the last %.0f s; steering without it",
                            self.compass_judge.reason, self.compass_judge.window_s)  # fmt: skip
            else:
                log.warning("%s %s: %s", st.name, problem, st.detail)
            if st.name in self.st.warned:
                continue  # one warning per input and episode (its driver may have said it)
            self.st.warned.append(st.name)
            say = Say(Speech.SENSOR, input=st.name, status=status)
            if judged:
                say = Say(Speech.COMPASS_UNUSABLE, status=self.compass_judge.reason)
            self._say(out, t, say, Priority.SAFETY)

    # -- views ----------------------------------------------------------------------------------
    @property
    def t_s(self) -> float | None:
        return self.tr.last_t

    def state(self) -> EstimateState:
        return self.estimator.state()

    @property
    def searching(self) -> bool:
        """The car is lost and can find itself again (``PipelineConfig.relocalise``): a place
        recognised now is a whole-database find (``LandmarkFix.relocalised``)."""
        return self.config.relocalise and self.st.lost_said

    def target(self) -> Target:
        return self.navigator.target(self.estimator.x)

    @property
    def last_decision(self) -> Decision | None:
        """The latest decision made (for any intersection ahead)."""
        return self.guide.last_decision

    @property
    def reports(self) -> int:
        """Intersection reports taken so far (each ``Ahead.seq``)."""
        return self.guide.reports

    @property
    def last_report_seq(self) -> int:
        """The report number of the intersection the last report was about."""
        return self.guide.last_seq

    def planned_exit(self, seq: int) -> int | None:
        """The exit planned now for intersection report ``seq`` (None: not decided yet)."""
        return self.guide.planned_exit(seq)

    def statuses(self, t_s: float) -> dict[str, Health]:
        """Each input's health now (the health message carries them as they are)."""
        return self.health.statuses(t_s)

    # -- checkpoints ----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, object]:
        """The whole state as JSON-able data (estimator, navigator memory, bookkeeping)."""
        est = self.estimator
        return {
            "x": est.x.tolist(),
            "P": est.P.tolist(),
            "last_t_s": est.last_t_s,
            "navigator": self.navigator.memory(),
            "turns": self.turns.snapshot(),
            "decisions": self.navigator.decisions,
            "guide": self.guide.snapshot(),
            **asdict(self.st),
            "counts": dict(self.counts),
        }

    def restore(self, snap: Mapping[str, object], *, same_clock: bool = True) -> None:
        """Put the pipeline back where ``snapshot`` left it (after a crash).

        ``same_clock``: the message clock continues from the snapshot's (the simulation, a
        restart within one boot); False for the car in general, where the monotonic clock
        may have restarted with the laptop, so the snapshot's times are not carried over.
        Every value is checked first (``snapshot_check``): a bad one raises ``SnapshotError``
        and nothing is changed.
        """
        nav_cfg = self.navigator.config
        check_snapshot(
            snap,
            n_state=self.estimator.n,
            start_xy=self.config.start_xy_m,
            n_landmarks=len(self.navigator.landmarks),
            mem_capacity=nav_cfg.max_intersections,
            mem_width=nav_cfg.max_exits,
            prior_variances=np.diag(self.estimator.prior_covariance()).tolist(),
        )
        st = PipelineState.from_snapshot(snap)  # checked too, before anything changes
        last = snap.get("last_t_s") if same_clock else None
        same_t = float(last) if isinstance(last, int | float) else None
        self.estimator.restore(  # the estimator's time order survives a same-clock restart
            np.asarray(snap["x"], dtype=float), np.asarray(snap["P"], dtype=float), same_t
        )
        if not same_clock:
            st.landmark_said.clear()  # message times of another clock
        self.st = st
        self.tr = Transient()
        nav = snap["navigator"]
        assert isinstance(nav, dict)
        self.navigator.restore(nav)
        self.navigator.decisions = integer(snap.get("decisions", 0), "decisions")
        turns = snap.get("turns")
        if isinstance(turns, dict):
            self.turns.restore(turns)
        counts = snap.get("counts", {})
        if isinstance(counts, dict):  # in place: the guide counts into the same table
            self.counts.clear()
            self.counts.update({str(k): int(v) for k, v in counts.items()})
        guide = snap.get("guide")
        if isinstance(guide, dict):
            self.guide.restore(guide)
        if isinstance(last, int | float):
            self.tr.last_t = float(last)
            self.tr.last_odo_t = float(last)
