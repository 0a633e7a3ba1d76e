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

from guidance.core import prompts
from guidance.core.announce import due_announcements
from guidance.core.compass_cal import CompassCalibration, compass_heading_to_theta
from guidance.core.estimator import PoseEstimator
from guidance.core.health import (
    CompassJudge,
    DeviceStatus,
    HealthMonitor,
)
from guidance.core.messages import (
    Approach,
    CompassHeading,
    EstimateState,
    ExitTaken,
    GoalUpdate,
    HeadingFix,
    Health,
    IntersectionScene,
    LandmarkFix,
    Priority,
    Prompt,
    Target,
    TurnCompleted,
    WheelOdometry,
)
from guidance.core.model import wrap_angle
from guidance.core.navigator import Decision, Navigator
from guidance.core.pipeline_config import INPUT_KINDS, Input, Outputs, PipelineConfig
from guidance.core.pipeline_state import Pending, PipelineState, _InState
from guidance.core.snapshot_check import check_snapshot, integer
from guidance.core.turns import TurnDetector

log = logging.getLogger(__name__)


UNCERTAIN_HYSTERESIS = 0.8
"""The uncertainty warning re-arms once the major axis is back below this fraction of it."""
HEALTH_EVAL_PERIOD_S = 0.25
"""Health is re-evaluated at most this often on the message clock."""


# ----------------------------------------------------------------------------- the pipeline


LANDMARK_REPEAT_S = 30.0
"""A landmark confirmed again within this time (the same pass) is not announced again."""

GAP_HOLD_S = 5.0
"""An odometry increment this long after the previous one waits for the next to confirm its
time (a glitch stamping one frame far ahead must not widen the estimate by hours of driving)."""

GAP_ACCEL_MPS2 = 3.0
"""The most a car gains in speed per second in town (0-100 km/h in 9 s): bounds what it may
have driven beyond its last speed during an odometry gap."""


def gap_spread_m(speed_before_mps: float, gap_s: float) -> float:
    """2-sigma widening after an odometry gap: the last speed over the gap, plus what the car
    could have gained meanwhile (1/2 a t^2). 11 m/s for 5 s: 55 m + 37.5 m."""
    return speed_before_mps * gap_s + 0.5 * GAP_ACCEL_MPS2 * gap_s * gap_s


class Pipeline:
    """Estimator + navigator + turn detector + health, driven by messages (see module doc)."""

    heading_known = _InState[bool]()
    odometer_m = _InState[float]()
    speed_mps = _InState[float]()
    landmark_updates = _InState[int]()
    prompt_count = _InState[int]()
    arrived = _InState[bool]()
    finished = _InState[bool]()

    def __init__(self, config: PipelineConfig) -> None:
        self.config = config
        heading = config.start_heading_rad
        self.estimator = PoseEstimator(
            config.estimator, config.start_xy_m[0], config.start_xy_m[1], heading or 0.0
        )
        self.st = PipelineState(heading_known=heading is not None)
        self._waiting_said = False
        self._warned: set[str] = set()
        self._landmark_said: dict[int, float] = {}
        """Inputs the driver has been warned about (by the pipeline or in the driver's words)."""
        self._held_odometry: WheelOdometry | None = None
        self._last_manoeuvre = ""
        if not self.st.heading_known:
            P = self.estimator.P
            P[2, 2] = math.pi**2
            P[0, 2] = P[2, 0] = P[1, 2] = P[2, 1] = 0.0
            x = self.estimator.x
            self.estimator.set_pose(float(x[0]), float(x[1]), 0.0, P)
        self.navigator = Navigator(config.goal_xy_m, config.navigator, config.landmarks)
        self.turns = TurnDetector(config.turn_detector)
        self.health = HealthMonitor(config.expected_rates_hz, config.health)
        dev = config.compass_deviation_deg
        self._deviation = CompassCalibration(*dev) if any(dev) else None
        self.compass_judge = CompassJudge(
            config.compass_unusable_after_s,
            calibrated=self._deviation is not None or config.mounting_offset_deg != 0.0,
        )
        self.counts: Counter[str] = Counter()
        self.last_decision: Decision | None = None
        self._pending: Pending | None = None
        self._last_t: float | None = None
        self._last_odo_t: float | None = None
        self._next_state_t = -math.inf
        self._next_health_t = -math.inf

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
        if self._last_t is None or t > self._last_t:
            self._last_t = t
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
        held, self._held_odometry = self._held_odometry, None
        gap = None if self._last_odo_t is None else msg.t_s - self._last_odo_t
        if held is not None:
            if msg.t_s >= held.t_s:  # the new time base holds: the gap was real
                self._odometry_step(held, held.t_s - (self._last_odo_t or held.t_s), out)
                gap = msg.t_s - held.t_s
            else:  # back before it: the frame ahead was a clock glitch, not a gap
                self.counts["time_glitch_dropped"] += 1
                log.warning("odometry stamped %.1f s ahead was a glitch: dropped",
                            held.t_s - msg.t_s)  # fmt: skip
        elif gap is not None and gap > max(GAP_HOLD_S, self.health.timeout_s("odometry")):
            # After a long silence, wait for the next increment to confirm the new time
            # (an adapter glitch stamps a frame an hour ahead): one increment of latency.
            self._held_odometry = msg
            out.accepted, out.reason = False, "held_after_gap"
            return
        self._odometry_step(msg, gap, out)

    def _odometry_step(self, msg: WheelOdometry, gap: float | None, out: Outputs) -> None:
        est = self.estimator
        r = est.process(msg)
        out.accepted, out.reason = r.accepted, r.reason
        self._judge_time("odometry", r.reason)
        if not r.accepted:
            return
        d = 0.5 * (msg.d_left_m + msg.d_right_m)
        if gap is not None and gap > 0:
            # Beyond the dead-input timeout (>= 1 s, the decoder's longest bridged gap) the
            # distance driven meanwhile was not integrated: widen the estimate for it, by the
            # speed *before* the gap (the increment after it covers one frame, not the gap).
            if self.config.resume_gap_inflation and gap > self.health.timeout_s("odometry"):
                self._inflate_after_gap(gap, out)
            else:
                self.st.speed_mps = abs(d) / gap
        self._last_odo_t = msg.t_s
        self.st.odometer_m += abs(d)
        x = est.x
        turn = self.turns.update(msg.t_s, float(x[2]), self.st.odometer_m)
        if turn is not None:
            out.turns.append(turn)
            pending = self._pending
            if pending is None or self.st.odometer_m >= pending.reach_odometer_m:
                self._resolve(turn.t_s, turn.heading_change_rad, "detected", out)
        self._after_step(msg.t_s, out)

    def _inflate_after_gap(self, gap_s: float, out: Outputs) -> None:
        """Odometry came back after a silence: the car may have moved meanwhile (issue 7)."""
        spread = gap_spread_m(self.st.speed_mps, gap_s)
        self.inflate_position(spread)
        log.warning("odometry resumed after %.1f s: position inflated by %.0f m", gap_s, spread)
        self.counts["gap_inflations"] += 1

    def inflate_position(self, spread_m: float) -> None:
        """Widen the position uncertainty by ``spread_m`` (a 2-sigma distance, both axes)."""
        if not (math.isfinite(spread_m) and spread_m > 0):
            return
        est = self.estimator
        P = est.P
        var = (spread_m / 2.0) ** 2
        P[0, 0] += var
        P[1, 1] += var
        x = est.x
        est.set_pose(float(x[0]), float(x[1]), float(x[2]), P)

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
        r = self.estimator.process(fix)
        out.accepted, out.reason = r.accepted, r.reason
        if r.accepted:
            self.st.landmark_updates += 1
            out.landmark_updates.append(fix)
            self.navigator.on_landmark_fix(fix.landmark_id, self.estimator.major_axis_m)
            name = next((lm.name for lm in self.config.landmarks if lm.id == fix.landmark_id), "")
            last = self._landmark_said.get(fix.landmark_id, -math.inf)
            if fix.t_s - last >= LANDMARK_REPEAT_S:  # a second fix from the same pass: silent
                self._landmark_said[fix.landmark_id] = fix.t_s
                self._say(out, fix.t_s, prompts.landmark_confirmed(name), Priority.INFO, "landmark")
            self._after_step(fix.t_s, out, mode_done=True)
        else:
            out.landmark_rejections.append((fix, r.reason or "rejected"))
            self._after_step(fix.t_s, out)

    def _intersection(self, scene: IntersectionScene, out: Outputs) -> None:
        if not scene.exit_headings_rad:
            out.accepted, out.reason = False, "no_exits"
            return
        if not self.st.heading_known:  # no advice out of a heading the car does not have
            out.accepted, out.reason = False, "heading_unknown"
            self.counts["advice_withheld"] += 1
            if not self._waiting_said:
                self._waiting_said = True
                self._say(out, scene.t_s, prompts.waiting_for_heading(), Priority.SAFETY, "info")
            return
        est = self.estimator
        x = est.x
        heading = float(x[2])
        if self._pending is not None:  # a new intersection before the old one resolved
            self._resolve(scene.t_s, None, "superseded", out)
        to_b = scene.distance_m
        if to_b is not None and math.isfinite(to_b):
            at = np.array([x[0] + to_b * math.cos(x[2]), x[1] + to_b * math.sin(x[2]), x[2]])
        else:
            to_b = None
            at = x
        decision = self.navigator.decide(scene.t_s, at, est.P, scene.exit_headings_rad)
        self.last_decision = decision
        out.decisions.append(decision)
        ahead = to_b or 0.0
        self._pending = Pending(
            decision,
            heading,
            self.st.odometer_m + ahead + self.config.straight_after_m,
            reach_odometer_m=self.st.odometer_m + ahead - self.config.turn_detector.window_m,
        )
        if to_b is None:  # in the car: say it now, right after the exits are known
            self._pending.announced.add("now")
            text = prompts.decision_prompt(decision, None, self.config.units)
            self._say(out, scene.t_s, text, Priority.GUIDANCE, "turn")
        else:
            self._announce(scene.t_s, to_b, out)

    def _approach(self, msg: Approach, out: Outputs) -> None:
        if self._pending is not None and math.isfinite(msg.distance_m):
            self._announce(msg.t_s, msg.distance_m, out)

    def _announce(self, t: float, distance_m: float, out: Outputs) -> None:
        """Early and just-before announcements, scaled by speed (``guidance.voice``'s Organic
        Maps timing). A "continue straight" gets one announcement only."""

        pending = self._pending
        assert pending is not None
        d = pending.decision
        due = due_announcements(distance_m, self.st.speed_mps, pending.announced)
        if not due:
            return
        kind = due[0]
        straight = prompts.manoeuvre(d.turn_rad) == "continue straight"
        pending.announced.add(kind)
        if straight and kind == "early":
            return  # straight through needs no early warning (OsmAnd, Organic Maps)
        if straight and self._last_manoeuvre == "continue straight":
            self.counts["straight_not_repeated"] += 1  # says nothing new at the next one
            return
        self._last_manoeuvre = prompts.manoeuvre(d.turn_rad)
        text = prompts.decision_prompt(d, max(0.0, distance_m), self.config.units)
        self._say(out, t, text, Priority.GUIDANCE, "turn")

    def _turn(self, turn: TurnCompleted, out: Outputs) -> None:
        out.turns.append(turn)
        self._resolve(turn.t_s, turn.heading_change_rad, turn.source, out)
        self.turns.reset()  # the co-driver's report replaces what the heading would show

    def _set_goal(self, goal: GoalUpdate, out: Outputs) -> None:
        if not (math.isfinite(goal.x_m) and math.isfinite(goal.y_m)):
            out.accepted, out.reason = False, "non_finite_goal"
            return
        self.navigator.set_goal((goal.x_m, goal.y_m))
        self.st.arrived = False
        self.st.finished = False
        self._say(out, goal.t_s, "New destination set", Priority.INFO, "info")

    # -- after every estimator step -------------------------------------------------------------
    def _after_step(self, t: float, out: Outputs, mode_done: bool = False) -> None:
        est = self.estimator
        major = est.major_axis_m
        lost = major > est.config.lost_major_axis_m  # the estimator's lost, axis computed once
        if not mode_done:
            self.navigator.update_mode(major)
        if self._pending is not None and self.st.odometer_m >= self._pending.resolve_at_odometer_m:
            self._resolve(t, 0.0, "no_turn", out)
        warn = self.config.uncertain_warn_m
        if not self.st.uncertain_said and major > warn and not lost:
            self.st.uncertain_said = True
            self._say(out, t, prompts.position_uncertain(major, self.config.units), Priority.SAFETY,
                      "uncertain")  # fmt: skip
        elif self.st.uncertain_said and major < UNCERTAIN_HYSTERESIS * warn:
            self.st.uncertain_said = False
        if lost:
            out.lost = True
            if not self.st.lost_said:
                self.st.lost_said = True
                self._say(out, t, prompts.lost(), Priority.SAFETY, "lost")
                if self.config.stop_at_arrival:
                    self.st.finished = True
        elif self.st.lost_said and major < UNCERTAIN_HYSTERESIS * est.config.lost_major_axis_m:
            self.st.lost_said = False
        if not lost and not self.st.arrived and self.navigator.arrived(est.x):
            self.st.arrived = True
            out.arrived = True
            self._say(out, t, prompts.arrived(), Priority.GUIDANCE, "arrived")
            if self.config.stop_at_arrival:
                self.st.finished = True
        if t >= self._next_state_t:
            self._next_state_t = t + self.config.state_period_s
            out.state = est.state()

    def _resolve(self, t: float, change_rad: float | None, source: str, out: Outputs) -> None:
        """Which exit did the driver take? Correct the navigator's memory if not the advised one."""
        pending = self._pending
        if pending is None:
            if source != "no_turn":
                log.info(
                    "turn of %.0f deg with no intersection announced", math.degrees(change_rad or 0)
                )
            return
        self._pending = None
        d = pending.decision
        if change_rad is None:  # superseded: assume the advice was followed
            out.exits_taken.append(ExitTaken(t, d, d.exit_index, True, source))
            return
        actual_heading = wrap_angle(pending.heading_before_rad + change_rad)
        if source == "detected":  # the heading now: right even when decided mid-turn
            actual_heading = float(self.estimator.x[2])
        best = min(d.options, key=lambda o: abs(wrap_angle(o.heading_rad - actual_heading))).index
        followed = best == d.exit_index
        out.exits_taken.append(ExitTaken(t, d, best, followed, source))
        if not followed:
            self.counts["advice_not_followed"] += 1
            log.info(
                "driver took exit %d, not the advised %d (%s): memory corrected",
                best,
                d.exit_index,
                source,
            )
            self.navigator.move_exit_use(
                d.intersection_id, d.exit_heading_rad, d.options[best].heading_rad
            )

    def _device_status(self, msg: DeviceStatus, out: Outputs) -> None:
        """A driver's status flip: its own sentence is what the driver hears ("Wheel speed bus
        disconnected. Position is getting less certain."), once per flip to bad."""
        went_bad = self.health.report(msg)
        if went_bad and msg.health.warning and msg.input not in self._warned:
            self._warned.add(msg.input)
            self._say(out, msg.t_s, msg.health.warning, Priority.SAFETY, "sensor")
        self._health(msg.t_s, out, force=True)

    def _judge_time(self, name: str, reason: str | None) -> None:
        """Inputs the estimator cannot place in time make their input invalid (a frozen
        estimate while inputs are alive is a fault, never silent)."""
        self.health.judge(
            name, reason != "out_of_order", "time: stamped before the estimate", aspect="time"
        )

    def _say(self, out: Outputs, t: float, text: str, priority: int, kind: str) -> None:
        self.st.prompt_count += 1
        out.prompts.append(Prompt(t, text, priority, kind))

    def _health(self, t: float, out: Outputs, force: bool) -> None:
        if not force and t < self._next_health_t:
            return
        self._next_health_t = t + HEALTH_EVAL_PERIOD_S
        for change in self.health.evaluate(t):
            out.health.append(change)
            st = change.status
            if st.alive and st.valid:
                self._warned.discard(st.name)
                log.warning("%s is back (%.1f Hz)", st.name, st.rate_hz)
                continue
            problem = "is silent" if not st.alive else "sends garbage"
            log.warning("%s %s: %s", st.name, problem, st.detail)
            if st.name in self._warned:
                continue  # one warning per input and episode (its driver may have said it)
            self._warned.add(st.name)
            text = prompts.sensor_warning(st.name, problem)
            if st.name == "compass" and st.alive and self.compass_judge.unusable:
                text = prompts.compass_unusable(self.compass_judge.reason)
            self._say(out, t, text, Priority.SAFETY, "sensor")

    # -- views ----------------------------------------------------------------------------------
    @property
    def t_s(self) -> float | None:
        return self._last_t

    def state(self) -> EstimateState:
        return self.estimator.state()

    def target(self) -> Target:
        return self.navigator.target(self.estimator.x)

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
            "pending": None if self._pending is None else self._pending.to_dict(),
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
        )
        st = PipelineState.from_snapshot(snap)  # checked too, before anything changes
        est = self.estimator
        est.set_state(np.asarray(snap["x"], dtype=float), np.asarray(snap["P"], dtype=float))
        last = snap.get("last_t_s") if same_clock else None
        if isinstance(last, int | float):
            est._last_t = float(last)  # the estimator's time order survives the restart
        self.st = st
        nav = snap["navigator"]
        assert isinstance(nav, dict)
        self.navigator.restore(nav)
        self.navigator.decisions = integer(snap.get("decisions", 0), "decisions")
        turns = snap.get("turns")
        if isinstance(turns, dict):
            self.turns.restore(turns)
        counts = snap.get("counts", {})
        if isinstance(counts, dict):
            self.counts = Counter({str(k): int(v) for k, v in counts.items()})
        pending = snap.get("pending")
        self._pending = Pending.from_dict(pending) if isinstance(pending, dict) else None
        if self._pending is not None:
            self.last_decision = self._pending.decision
        if isinstance(last, int | float):
            self._last_t = float(last)
            self._last_odo_t = float(last)
