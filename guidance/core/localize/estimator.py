"""Pose estimator: an extended Kalman filter on filterpy (SPEC section 2).

One entry point, ``process(msg)``: a timestamped input in, what happened out. No I/O, no
clock reads (time comes from the messages: live, simulated and replayed drives run the same
code). ``PoseEstimator`` holds the filter and is the only code that moves its x and P; it adds
time ordering, counters, health and resets, and runs the filter's roles, each in its module
(as filterpy splits ``predict`` from ``update``):

* ``motion``: the predict of an odometry step (``F``, ``Q``, the control; the gyro's turn);
* ``gates``: whether a measurement may update the filter (bounds, chi-square gates, the
  compass's interference judge); the update is filterpy's with ``measurements``' h and H;
* ``covariance_edits``: the edits outside predict and update (a pose put in place, the
  heading forgotten or taken from the compass, the position widened, learned values adopted,
  the relocalisation, the "lost" reset); dead reckoning through a gap is
  ``guidance.core.odometry_gap``'s;
* ``gyro``: a gyro car's readings gathered between steps, its standstill update.

The math is ``guidance.core.model``'s (shared with the study engine). The settings,
``EstimatorConfig``, are ``estimator_config``'s (imported here, where callers find them)."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from guidance.core import model
from guidance.core.localize import covariance_edits, gates, motion, state_limits, turn_fusion
from guidance.core.localize import gyro as gyro_model
from guidance.core.localize.estimator_config import EstimatorConfig
from guidance.core.localize.measurements import (
    H_heading,
    H_position,
    ekf_class,
    h_heading,
    h_position,
    heading_residual,
)
from guidance.core.messages import (
    Ellipse,
    EstimateState,
    HeadingFix,
    LandmarkFix,
    WheelOdometry,
    YawRate,
)
from guidance.core.odometry_gap import dead_reckon
from guidance.core.stages import RELOCALISED

__all__ = ["REANCHOR_AFTER", "EstimatorConfig", "EstimatorInput", "PoseEstimator", "StepResult"]

EstimatorInput = WheelOdometry | HeadingFix | LandmarkFix | YawRate
REANCHOR_AFTER = 10
"""Out-of-order inputs in a row after which the inputs' time base wins (about 0.1-0.5 s of
odometry): an estimate stamped in the future by a glitch never freezes for good."""


@dataclass(frozen=True, slots=True)
class StepResult:
    """What one input did to the estimate."""

    kind: str
    accepted: bool
    reason: str | None = None
    mahalanobis_sq: float | None = None


class PoseEstimator:
    """EKF over (x, y, theta) of the rear-axle centre (and the car model's error states)."""

    def __init__(
        self,
        config: EstimatorConfig | None = None,
        x_m: float = 0.0,
        y_m: float = 0.0,
        heading_rad: float = 0.0,
    ) -> None:
        self.config = config or EstimatorConfig()
        self.n = self.config.n_state
        self._kf = ekf_class()(dim_x=self.n, dim_z=1)
        self._kf.x = np.zeros(self.n)
        self.rejections: Counter[str] = Counter()
        self.accepted: Counter[str] = Counter()
        self.resets = 0
        self.healthy = True
        self._last_t: float | None = None
        self._turn_rad = 0.0
        """Heading change not yet counted toward the compass bias's growth (``motion``)."""
        self._gyro = gyro_model.GyroIntegrator()
        self.out_of_order_run = 0
        """Inputs rejected in a row for being older than the estimate (a clock that stepped)."""
        self._interference = gates.Interference()
        self.set_pose(x_m, y_m, heading_rad)

    # -- state: put in place, and the edits outside predict and update ------------------------
    def set_pose(
        self,
        x_m: float,
        y_m: float,
        heading_rad: float,
        covariance: np.ndarray | None = None,
    ) -> None:
        """Put the car at a known pose (start, or a checkpoint) with the given covariance
        (the whole state's, or the pose's: ``covariance_edits.of_pose``)."""
        x = np.array(self._kf.x, dtype=float)
        x[0], x[1], x[2] = x_m, y_m, model.wrap_angle(heading_rad)
        self._kf.x = x
        self._kf.P = covariance_edits.of_pose(self.config, covariance)

    def prior_covariance(self) -> np.ndarray:
        """The starting covariance of every state (``covariance_edits.prior``)."""
        return covariance_edits.prior(self.config)

    def set_state(self, x: np.ndarray, P: np.ndarray) -> None:
        """Restore a whole state (a checkpoint); a pose-only (3-state) one is embedded."""
        x = np.asarray(x, dtype=float).ravel()
        P = np.asarray(P, dtype=float)
        if x.shape[0] == self.n and P.shape == (self.n, self.n):
            self._kf.x = x.copy()
            self._kf.x[2] = model.wrap_angle(float(x[2]))
            self._kf.P = P.copy()
            return
        if x.shape[0] < 3 or P.shape[0] < 3 or P.shape[0] != P.shape[1]:
            raise ValueError(f"state of size {x.shape[0]} cannot fill a {self.n}-state filter")
        self.set_pose(float(x[0]), float(x[1]), float(x[2]), P[:3, :3])

    def restore(self, x: np.ndarray, P: np.ndarray, last_t_s: float | None) -> None:
        """A checkpoint's state, and its time order when the clock is the same one."""
        self.set_state(x, P)
        if last_t_s is not None:
            self._last_t = float(last_t_s)

    def forget_heading(self) -> None:
        """No heading known (the first compass reading gives it: ``heading_from_compass``)."""
        x = self._kf.x
        self.set_pose(float(x[0]), float(x[1]), 0.0, covariance_edits.heading_forgotten(self._kf.P))

    def inflate_position(self, spread_m: float) -> None:
        """Widen the position by ``spread_m`` (a 2-sigma distance, both axes: a restart, where
        nothing is known of what the car did meanwhile); nothing for a non-finite or <= 0."""
        if not (math.isfinite(spread_m) and spread_m > 0):
            return
        x, P = self._kf.x, covariance_edits.position_widened(self._kf.P, spread_m)
        self.set_pose(float(x[0]), float(x[1]), float(x[2]), P)

    def heading_from_compass(self, theta_rad: float, compass_var: float) -> None:
        """Take the heading from a compass reading (no heading known yet; the bias's
        uncertainty goes with it: ``covariance_edits.heading_from_compass``)."""
        x = self._kf.x
        theta, P = covariance_edits.heading_from_compass(x, self._kf.P, theta_rad, compass_var)
        self.set_pose(float(x[0]), float(x[1]), theta, P)

    def coast(self, speed_mps: float, gap_from_s: float, gap_to_s: float) -> None:
        """Odometry overdue: move on at ``speed_mps`` along the heading from ``gap_from_s`` to
        ``gap_to_s`` seconds into the gap, widened along the road and in heading
        (``guidance.core.odometry_gap.dead_reckon``, the one definition of that step)."""
        x, P = dead_reckon(self._kf.x, self._kf.P, speed_mps, gap_from_s, gap_to_s)
        self._kf.x = x
        self._kf.x[2] = model.wrap_angle(float(x[2]))
        self._kf.P = P

    def adopt(self, states: Sequence[tuple[int, float, float]]) -> None:
        """Start error states from known values (a car's learned parameters): each (index,
        mean, sigma) set, its correlations with the other states cleared."""
        self.set_state(*covariance_edits.adopted(self._kf.x, self._kf.P, states))

    # -- reads ------------------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        return np.array(self._kf.x, dtype=float)

    @property
    def P(self) -> np.ndarray:
        return np.array(self._kf.P, dtype=float)

    @property
    def heading_rad(self) -> float:
        """The estimated heading (counter-clockwise from east), ``x[model.STATE_THETA]``."""
        return float(self._kf.x[model.STATE_THETA])

    @property
    def last_t_s(self) -> float | None:
        return self._last_t

    @property
    def interference(self) -> bool:
        """True while compass readings are judged magnetically disturbed (and rejected)."""
        return self._interference.on

    def state_problem(self) -> str | None:
        """Why this state is not valid (``state_limits``, as a checkpoint is judged), or None."""
        prior = np.diag(self.prior_covariance()).tolist()
        return state_limits.state_problem(list(self._kf.x), self.P, prior)

    def ellipse(self) -> Ellipse:
        P = self._kf.P
        a, b, ang = model.ellipse_axes(P[0, 0], P[0, 1], P[1, 1], model.CHI2_2D_2SIGMA)
        return Ellipse(a, b, ang, 2.0 * a)

    @property
    def major_axis_m(self) -> float:
        return float(model.major_axis_m(self._kf.P))

    @property
    def lost(self) -> bool:
        return self.major_axis_m > self.config.lost_major_axis_m

    def state(
        self,
        odometer_m: float = 0.0,
        speed_mps: float = 0.0,
        heading_known: bool = True,
        reckoning: bool = False,
    ) -> EstimateState:
        """The estimate as a value, with what the localizer reads it with (``EstimateState``)."""
        x = self._kf.x
        c = self._kf.P[:3, :3].tolist()
        ellipse = self.ellipse()
        return EstimateState(
            t_s=self._last_t if self._last_t is not None else 0.0,
            x_m=float(x[0]),
            y_m=float(x[1]),
            heading_rad=float(x[2]),
            covariance=(tuple(c[0]), tuple(c[1]), tuple(c[2])),
            ellipse=ellipse,
            lost=ellipse.major_axis_m > self.config.lost_major_axis_m,
            healthy=self.healthy,
            odometer_m=odometer_m,
            speed_mps=speed_mps,
            heading_known=heading_known,
            reckoning=reckoning,
        )

    # -- the one entry point ------------------------------------------------------------------
    def process(self, msg: EstimatorInput) -> StepResult:
        """Apply one timestamped input; out-of-order and bad inputs are rejected and counted."""
        kind = type(msg).__name__
        if not math.isfinite(msg.t_s):
            return self._reject(kind, "non_finite_time")
        lag = 0.0 if self._last_t is None else self._last_t - msg.t_s
        late = lag > 0.0
        if lag > self.config.reorder_window_s:
            self.out_of_order_run += 1
            if self.out_of_order_run < REANCHOR_AFTER:
                return self._reject(kind, "out_of_order")
            # This many inputs in a row from before the estimate's time: the inputs' clock
            # stepped back (or the estimate's time came from a glitch). Follow the inputs.
            self.rejections["time_reanchored"] += 1
            self._last_t = None
            late = False
        x_before, P_before = self._kf.x.copy(), self._kf.P.copy()
        if isinstance(msg, WheelOdometry):
            result = self._predict(msg)
        elif isinstance(msg, HeadingFix):
            result = self._update_heading(msg)
        elif isinstance(msg, LandmarkFix):
            result = self._update_landmark(msg)
        elif isinstance(msg, YawRate):
            return self._gyro_reading(msg)  # gathered for the next step: moves no state, no time
        else:  # pragma: no cover - typing forbids it
            return self._reject(kind, "unknown_input")
        if result.accepted:
            self.out_of_order_run = 0
            if not late:  # a late input (inside the reorder window) never moves time back
                self._last_t = msg.t_s
            else:
                self.accepted["late_in_window"] += 1
            self.accepted[kind] += 1
            if not self._check_finite(x_before, P_before):
                return StepResult(kind, False, "non_finite_state_reset", result.mahalanobis_sq)
            if kind != "WheelOdometry":
                self.healthy = True  # an absolute measurement re-anchored the estimate
        return result

    # -- predict (``motion``) and update (``gates``, then filterpy's) --------------------------
    def _reject(self, kind: str, reason: str, d2: float | None = None) -> StepResult:
        self.rejections[reason] += 1
        return StepResult(kind, False, reason, d2)

    def _predict(self, msg: WheelOdometry) -> StepResult:
        cfg, kind = self.config, "WheelOdometry"
        why = gates.odometry_refusal(cfg, msg)
        if why is not None:
            return self._reject(kind, why)
        turned = self._gyro_step(msg) if cfg.gyro is not None else None
        dt = 0.0 if self._last_t is None else max(0.0, msg.t_s - self._last_t)
        step = motion.transition(
            cfg, self._kf.x, self._kf.P, (msg.d_left_m, msg.d_right_m, dt), turned, self._turn_rad
        )
        self._turn_rad = step.turn_rad
        if step.counted is not None:  # the wheels' turn used or gated ("both")
            counter = self.accepted if step.counted == turn_fusion.USED else self.rejections
            counter[step.counted] += 1
        self._kf.F, self._kf.Q = step.F, step.Q
        second = cfg.heading_second_order
        before = motion.lever_sq(self._kf.P) if second > 0.0 else 0.0
        self._kf.predict(u=step.u)
        if second > 0.0:
            motion.widen_along_lever(self._kf.P, before, second)
        return StepResult(kind, True)

    def _gyro_reading(self, msg: YawRate) -> StepResult:
        """A yaw-rate reading, gathered until the next odometry step (``gyro.take_reading``)."""
        cfg = self.config.gyro
        why = "no_gyro_configured" if cfg is None else gyro_model.take_reading(
            self._gyro, self._kf.P, msg, cfg)  # fmt: skip
        if why is not None:
            return self._reject("YawRate", why)
        self.accepted["YawRate"] += 1
        return StepResult("YawRate", True)

    def _gyro_step(self, msg: WheelOdometry) -> tuple[float, float, float] | None:
        """Before a step: the standstill readings' bias update, the gyro's angle or None."""
        assert self.config.gyro is not None
        out = gyro_model.before_step(self._gyro, self._kf.x, self._kf.P, msg, self.config.gyro)
        self._kf.x[2] = model.wrap_angle(float(self._kf.x[2]))
        self.accepted["gyro_standstill"] += out.standstill
        self.rejections["gyro_standstill_gate"] += out.gated
        self.accepted["gyro_stale_wheel_turn"] += out.turned is None
        return out.turned

    def _update_heading(self, msg: HeadingFix) -> StepResult:
        kind = "HeadingFix"
        v = gates.heading_verdict(
            self.config, self._kf.x, self._kf.P, msg.theta_rad, self._interference
        )
        if v.reason is not None:
            return self._reject(kind, v.reason, v.d2)
        self._kf.update(np.array([msg.theta_rad]), H_heading, h_heading,
                        R=np.array([[v.var]]), residual=heading_residual)  # fmt: skip
        self._kf.x[2] = model.wrap_angle(float(self._kf.x[2]))
        return StepResult(kind, True, None, v.d2)

    def _update_landmark(self, msg: LandmarkFix) -> StepResult:
        kind = "LandmarkFix"
        v = gates.landmark_verdict(self.config, self._kf.x, self._kf.P, msg)
        if v.reason == RELOCALISED:  # the position restarts there
            self._kf.x, self._kf.P = covariance_edits.relocalised(
                self._kf.x, self._kf.P, msg.x_m, msg.y_m, v.var
            )
            self.accepted["relocalisations"] += 1
            return StepResult(kind, True, RELOCALISED, v.d2)
        if v.reason is not None:
            return self._reject(kind, v.reason, v.d2)
        z = np.array([msg.x_m, msg.y_m])
        self._kf.update(z, H_position, h_position, R=np.eye(2) * v.var)
        self._kf.x[2] = model.wrap_angle(float(self._kf.x[2]))
        return StepResult(kind, True, None, v.d2)

    def _check_finite(self, x_before: np.ndarray, P_before: np.ndarray) -> bool:
        """After a non-finite result, go back to the last finite pose with a "lost" covariance."""
        if np.all(np.isfinite(self._kf.x)) and np.all(np.isfinite(self._kf.P)):
            return True
        cov = covariance_edits.lost(self.config, P_before)
        self.set_pose(float(x_before[0]), float(x_before[1]), float(x_before[2]), cov)
        self.resets += 1
        self.healthy = False
        self.rejections["non_finite_state_reset"] += 1
        return False
