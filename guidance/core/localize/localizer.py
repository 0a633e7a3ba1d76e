"""Stage 1 of the core ("locationd"): sensor inputs in, the estimate out.

``Localizer.handle(msg)`` takes one input (wheel odometry, a compass reading, a heading fix, a
landmark fix; anything else passes through untouched) and returns a ``LocalizeStep``: every
estimate the input produced, in order (``moves``: an odometry step, or the estimate carried on
through a CAN gap), the verdict on the input, and the estimate after it. It owns the filter
(``PoseEstimator``): nothing else moves x and P. It also keeps what the estimate is read with:
the distance driven, the speed, whether the heading is known, and the dead reckoning through an
odometry gap (``guidance.core.odometry_gap``).

The planner (``guidance.core.plan.planner``) reads the estimates as values; the pipeline
(``guidance.core.pipeline``) runs one then the other. Callers that need only the estimate
(replay of raw logs, the population study, the latency benchmark) use a ``Localizer`` alone.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from guidance.core.health import CompassJudge, HealthConfig, HealthMonitor
from guidance.core.localize.compass_cal import CompassCalibration, compass_heading_to_theta
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.localize.learned import LearnedParams
from guidance.core.messages import (
    CompassHeading,
    EstimateState,
    HeadingFix,
    LandmarkFix,
    WheelOdometry,
    YawRate,
)
from guidance.core.pipeline_config import Input, PipelineConfig
from guidance.core.pipeline_state import LocalizeState, Transient
from guidance.core.stages import RELOCALISED, LocalizeStep, Move

log = logging.getLogger(__name__)

GAP_HOLD_S = 5.0
"""An odometry increment this long after the previous one waits for the next to confirm its
time (a glitch stamping one frame far ahead must not widen the estimate by hours of driving)."""

UNKNOWN_START_SIGMA_M = 10_000.0
"""A car that starts anywhere (``PipelineConfig.start_unknown``) is somewhere in a city 20 km
across (the 2-sigma circle): lost from the first step, and any landmark it finds is inside."""

DR_AFTER_S = 0.1
DR_AFTER_PERIODS = 3.0
"""Odometry this late (the larger of the two: 0.1 s, three frames) is dead-reckoned over until
it comes: a stale estimate with a tight ellipse would put the truth outside it."""


@dataclass(frozen=True, slots=True)
class LocalizerConfig:
    """What the first stage needs: the filter, the start, the compass's corrections and the
    inputs' rates (no goal, no navigator). ``of`` takes it from the car's ``PipelineConfig``."""

    estimator: EstimatorConfig
    start_xy_m: tuple[float, float]
    start_heading_rad: float | None = None
    """None: taken from the first compass reading."""
    declination_deg: float = 0.0
    mounting_offset_deg: float = 0.0
    compass_deviation_deg: tuple[float, ...] = ()
    compass_unusable_after_s: float = 20.0
    expected_rates_hz: Mapping[str, float | None] = field(default_factory=dict)
    health: HealthConfig = field(default_factory=HealthConfig)
    start_unknown: bool = False
    """``[start]`` gives no position: the estimate starts ``UNKNOWN_START_SIGMA_M`` wide."""
    resume_gap_inflation: bool = True

    @classmethod
    def of(cls, config: PipelineConfig) -> LocalizerConfig:
        """The car's settings for the first stage (each field of the same name)."""
        return cls(**{f.name: getattr(config, f.name) for f in fields(cls)})


class Localizer:
    """The estimator and what it is read with, driven by sensor inputs (see module doc).

    ``health`` is the pipeline's monitor (the localizer judges the compass and the inputs'
    time order there, and reads the odometry rate's timeout from it); alone, it keeps its own.
    ``counts`` is the table its events are counted in (the pipeline's, in a checkpoint)."""

    def __init__(
        self,
        config: LocalizerConfig,
        health: HealthMonitor | None = None,
        counts: Counter[str] | None = None,
    ) -> None:
        self.config = config
        heading = config.start_heading_rad
        self.estimator = PoseEstimator(
            config.estimator, config.start_xy_m[0], config.start_xy_m[1], heading or 0.0
        )
        self.st = LocalizeState(heading_known=heading is not None)
        self.tr = Transient()
        if not self.st.heading_known:
            self.estimator.forget_heading()
        if config.start_unknown:
            self.estimator.inflate_position(2.0 * UNKNOWN_START_SIGMA_M)
        self.health = health or HealthMonitor(config.expected_rates_hz, config.health)
        self.counts: Counter[str] = Counter() if counts is None else counts
        dev = config.compass_deviation_deg
        self._deviation = CompassCalibration(*dev) if any(dev) else None
        self.compass_judge = CompassJudge(
            config.compass_unusable_after_s,
            calibrated=self._deviation is not None or config.mounting_offset_deg != 0.0,
        )

    # -- the one entry point ----------------------------------------------------------------
    def handle(self, msg: Input) -> LocalizeStep:
        """Apply one input; a message that is not a sensor input changes nothing."""
        step = LocalizeStep()
        if isinstance(msg, CompassHeading | HeadingFix):
            self._dead_reckon(msg.t_s, step)
        if isinstance(msg, WheelOdometry):
            self._odometry(msg, step)
        elif isinstance(msg, CompassHeading):
            self._heading(self.compass_fix(msg), step)
        elif isinstance(msg, HeadingFix):
            self._heading(msg, step)
        elif isinstance(msg, LandmarkFix):
            self._landmark(msg, step)
        elif isinstance(msg, YawRate):  # a gyro car's: gathered for the next odometry step
            r = self.estimator.process(msg)
            step.accepted, step.reason = r.accepted, r.reason
        odometry_last = isinstance(msg, WheelOdometry) and step.accepted and step.moves
        # an accepted odometry step is the input's last change: its move's estimate is the one
        step.estimate = step.moves[-1].estimate if odometry_last else self.estimate()
        step.compass_unusable = self.compass_judge.unusable
        return step

    def estimate(self) -> EstimateState:
        """The estimate now, with what it is read with (one value)."""
        st, reckoning = self.st, self.tr.dr_to_t is not None
        return self.estimator.state(st.odometer_m, st.speed_mps, st.heading_known, reckoning)

    def compass_fix(self, msg: CompassHeading) -> HeadingFix:
        """A compass reading as a filter heading: card, mounting offset, declination unless true."""
        cfg = self.config
        theta = compass_heading_to_theta(
            msg, cfg.declination_deg, cfg.mounting_offset_deg, self._deviation
        )
        return HeadingFix(msg.t_s, theta)

    # -- inputs -------------------------------------------------------------------------------
    def _odometry(self, msg: WheelOdometry, step: LocalizeStep) -> None:
        held, self.tr.held_odometry = self.tr.held_odometry, None
        gap = None if self.tr.last_odo_t is None else msg.t_s - self.tr.last_odo_t
        if held is not None:
            if msg.t_s >= held.t_s:  # the new time base holds: the gap was real
                self._odometry_step(held, held.t_s - (self.tr.last_odo_t or held.t_s), step)
                gap = msg.t_s - held.t_s
            else:  # back before it: the frame ahead was a clock glitch, not a gap
                self.counts["time_glitch_dropped"] += 1
                log.warning("odometry stamped %.1f s ahead was a glitch: dropped",
                            held.t_s - msg.t_s)  # fmt: skip
        elif gap is not None and gap > max(GAP_HOLD_S, self.health.timeout_s("odometry")):
            # After a long silence, wait for the next increment to confirm the new time
            # (an adapter glitch stamps a frame an hour ahead): one increment of latency.
            self.tr.held_odometry = msg
            step.accepted, step.reason = False, "held_after_gap"
            return
        self._odometry_step(msg, gap, step)

    def _odometry_step(self, msg: WheelOdometry, gap: float | None, step: LocalizeStep) -> None:
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
        step.accepted, step.reason = r.accepted, r.reason
        self._judge_time("odometry", r.reason)
        if not r.accepted:
            return
        gap_from_s = None
        if gap is not None and gap > 0:
            if long_gap:
                log.warning("odometry resumed after %.1f s: dead-reckoned %.0f m at %.1f m/s",
                            gap, self.tr.dr_m, self.st.speed_mps)  # fmt: skip
                self.counts["odometry_gaps"] += 1
                gap_from_s = msg.t_s - gap
            else:
                self.st.speed_mps = abs(d_wheels) / gap
        if not long_gap:
            self.st.odometer_m = max(0.0, self.st.odometer_m - ahead_m)
        self.tr.dr_to_t, self.tr.dr_m = None, 0.0
        self.tr.last_odo_t = msg.t_s
        self.st.odometer_m += abs(d_wheels)
        step.moves.append(Move(msg.t_s, self.estimate(), odometry=True, gap_from_s=gap_from_s))

    def _dead_reckon(self, t: float, step: LocalizeStep | None) -> None:
        """Odometry overdue (a CAN dropout, or a frame late) while the heading is known: the
        estimate moves on at the last speed along its heading, widened along the road by what
        the car could have gained or lost (``guidance.core.odometry_gap``), up to
        ``t``. Done at each compass reading in the silence (a move of the step: the
        intersections ahead move on with it) and when odometry resumes."""
        last = self.tr.last_odo_t
        rate = self.health.expected.get("odometry")
        if last is None or not rate or not self.config.resume_gap_inflation:
            return
        if not self.st.heading_known or t - last <= max(DR_AFTER_S, DR_AFTER_PERIODS / rate):
            return
        start = last if self.tr.dr_to_t is None else self.tr.dr_to_t
        if t <= start:
            return
        self.estimator.coast(self.st.speed_mps, start - last, t - last)
        moved = abs(self.st.speed_mps) * (t - start)
        self.st.odometer_m += moved
        self.tr.dr_m += moved
        self.tr.dr_to_t = t
        if step is not None:
            step.moves.append(Move(t, self.estimate(), odometry=False))

    def _heading(self, fix: HeadingFix, step: LocalizeStep) -> None:
        est = self.estimator
        if not self.st.heading_known and est.config.compass_two_sigma_deg is not None:
            est.heading_from_compass(
                fix.theta_rad, math.radians(est.config.compass_two_sigma_deg / 2.0) ** 2
            )
            self.st.heading_known = True
            step.heading_found = True
            log.info("initial heading from the compass: %.0f deg", math.degrees(fix.theta_rad))
            return
        r = est.process(fix)
        step.accepted, step.reason = r.accepted, r.reason
        self._judge_time("compass", r.reason)
        if r.reason == "out_of_order":  # a time problem, not the compass's data
            return
        self.compass_judge.add(fix.t_s, r.accepted, r.reason)
        self.health.judge("compass", *self.compass_judge.verdict(fix.t_s))

    def _landmark(self, fix: LandmarkFix, step: LocalizeStep) -> None:
        r = self.estimator.process(fix)
        step.accepted, step.reason = r.accepted, r.reason
        if r.accepted:
            self.st.landmark_updates += 1
            step.relocalised = r.reason == RELOCALISED

    def _judge_time(self, name: str, reason: str | None) -> None:
        """Inputs the estimator cannot place in time make their input invalid (a frozen
        estimate while inputs are alive is a fault, never silent)."""
        self.health.judge(
            name, reason != "out_of_order", "time: stamped before the estimate", aspect="time"
        )

    # -- the filter's own account, for the health message and the learned parameters ------------
    def filter_health(self) -> dict[str, object]:
        """The filter's counters: healthy, its resets and rejections by reason."""
        est = self.estimator
        return {"healthy": est.healthy, "resets": est.resets, "rejections": dict(est.rejections)}

    def adopt(self, learned: LearnedParams) -> None:
        """Start the car's error states from what it learned on earlier drives."""
        learned.apply(self.estimator)

    def learned(
        self,
        vehicle_id: str,
        now_unix_s: float,
        driven_m: float,
        before: LearnedParams | None = None,
    ) -> LearnedParams | None:
        """What the filter knows now of the car's errors, to keep (None: the paper model)."""
        return LearnedParams.from_estimator(
            self.estimator, vehicle_id, now_unix_s, driven_m, before
        )

    @property
    def state_size(self) -> int:
        """The filter's number of states (3, or 7 for the car model)."""
        return self.estimator.n

    def prior_variances(self) -> list[float]:
        """Each state's starting variance (what a checkpoint's covariance is judged against)."""
        variances: list[float] = np.diag(self.estimator.prior_covariance()).tolist()
        return variances

    def widen(self, spread_m: float) -> None:
        """Widen the position by ``spread_m`` (2-sigma, both axes: a restart's unknown drive)."""
        self.estimator.inflate_position(spread_m)

    # -- checkpoints ----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, object]:
        est = self.estimator
        return {"x": est.x.tolist(), "P": est.P.tolist(), "last_t_s": est.last_t_s}

    def restore(
        self, snap: Mapping[str, object], st: LocalizeState, last_t_s: float | None
    ) -> None:
        """The filter's state (checked by the caller), its time order on the same clock, and
        its bookkeeping ``st``; what a restart forgets starts afresh."""
        self.estimator.restore(  # the estimator's time order survives a same-clock restart
            np.asarray(snap["x"], dtype=float), np.asarray(snap["P"], dtype=float), last_t_s
        )
        self.st = st
        self.tr = Transient()
        if last_t_s is not None:
            self.tr.last_odo_t = last_t_s
