"""Pose estimator: an extended Kalman filter on filterpy (SPEC section 2).

One entry point, ``process(msg)``: a timestamped input in, what happened out. No I/O, no
clock reads (time comes from the messages: live, simulated and replayed drives run the same
code). The math is ``guidance.core.model``'s (shared with the study engine); this module
adds time ordering, gates, counters, health, resets."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from guidance.config_tables import rule
from guidance.core import model
from guidance.core.localize import gyro as gyro_model
from guidance.core.localize import state_limits, turn_fusion
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
from guidance.core.stages import LOST_HYSTERESIS, RELOCALISED

EstimatorInput = WheelOdometry | HeadingFix | LandmarkFix | YawRate
_CAR = rule(lo=0.0, group="car")  # a setting of the car model ([estimator] model = "car")
_FIXED_POSITIVE = rule(positive=True, read=False)  # > 0; recorded, not offered in [estimator]


@dataclass(frozen=True, slots=True)
class EstimatorConfig:
    """Sensor noise and gate settings, each with its config ``rule``. Defaults: the 2007 Tahoe."""

    track_m: float = field(default=1.72, metadata=rule(positive=True, read=False))
    """Rear track width, m (Tahoe GMT900: 1.72 m)."""
    wheel_quantum_m: float = field(default=0.02, metadata=rule(lo=0.0))
    """Distance resolution of one wheel increment, m (one encoder count)."""
    wheel_slip_frac: float = field(default=0.01, metadata=rule(lo=0.0))
    """1-sigma slip as a fraction of each wheel increment."""
    compass_two_sigma_deg: float | None = field(default=30.0, metadata=rule(positive=True))
    """Compass 2-sigma error, degrees; None when no compass is fitted."""
    compass_gate_chi2: float = field(default=model.CHI2_1D_P999, metadata=_FIXED_POSITIVE)
    """Heading gate: residual d^2 above this (1 dof, P = 0.999) is rejected."""
    landmark_gate_chi2: float = field(default=model.CHI2_2D_P99, metadata=_FIXED_POSITIVE)
    """Landmark gate: d^2 above this (2 dof, P = 0.99) is rejected."""
    lost_major_axis_m: float = field(default=100.0, metadata=rule(positive=True))
    """Lost when the full 2-sigma major axis exceeds this (about one city block)."""
    initial_position_sigma_m: float = field(default=1.0, metadata=rule(positive=True))
    initial_heading_sigma_deg: float = field(default=1.0, metadata=rule(positive=True))
    max_wheel_step_m: float = field(default=20.0, metadata=rule(positive=True))
    """Sanity limit: a single odometry increment above this is rejected."""
    reorder_window_s: float = field(default=1.0, metadata=rule(lo=0.0, read=False))
    """An input up to this much older than the estimate is applied where it arrives (sources
    race each other and clocks jitter; a sub-second clock step must not freeze the estimate).
    Older inputs are rejected, until ``REANCHOR_AFTER`` in a row make the estimate follow."""
    interference_detection: bool = field(default=True, metadata=rule(read=False))
    """Reject compass readings while their innovations say the field is disturbed.

    Inflating their variance instead was tried: the heading still converges to
    the biased field over a block (docs/reliability.md has the comparison)."""
    interference_alpha: float = field(default=0.15, metadata=rule(lo=0.0, hi=1.0, read=False))
    """Weight of each reading in the NIS level (about 7 readings of memory)."""
    interference_on_nis: float = field(default=4.0, metadata=_FIXED_POSITIVE)
    """Level above which the compass is considered disturbed (modelled value: 1)."""
    interference_off_nis: float = field(default=2.0, metadata=_FIXED_POSITIVE)
    """Level below which it is trusted again."""
    # -- the car model (docs/estimation.md); all zero = the paper's white-noise model ----------
    wheel_walk_var_m2_per_m: float = field(default=0.0, metadata=_CAR)
    """Variance per metre of each wheel's distance (a random walk: independent of the rate)."""
    scale_sigma: float = field(default=0.0, metadata=_CAR)
    """Prior 1-sigma of the common wheel-speed scale error, a fraction (a state when > 0)."""
    diff_sigma: float = field(default=0.0, metadata=_CAR)
    """Prior 1-sigma of the right-minus-left wheel scale difference, a fraction."""
    diff_walk_var_per_m: float = field(default=0.0, metadata=_CAR)
    """Random-walk variance of that difference per metre: 0 in the car model, whose difference
    changes from street to street but stays bounded (``camber_diff_sigma``)."""
    camber_diff_sigma: float = field(default=0.0, metadata=_CAR)
    """1-sigma of the part of the left/right difference that changes from street to street
    (road camber, tyre temperature), a fraction: a Gauss-Markov process of correlation length
    ``camber_length_m``, whose heading is a walk in distance (``model.camber_heading_var``):
    0.016 % in the car model, the same change per street as a walk of 1e-10 per metre over
    250 m, but bounded (docs/estimation.md)."""
    camber_length_m: float = field(default=250.0, metadata=_CAR)
    """That process's correlation length: a street between junctions, a few hundred metres."""
    turn_scale_sigma: float = field(default=0.0, metadata=_CAR)
    """Prior 1-sigma of the turn scale error, a fraction: the true heading change is the
    wheels' (or the gyro's) x (1 + kt) (effective track; a gyro's sensitivity)."""
    compass_bias_sigma_deg: float = field(default=0.0, metadata=_CAR)
    """Prior 1-sigma of the compass bias (uncalibrated: large; calibrated: the fit residual)."""
    compass_bias_walk_deg2_per_s: float = field(default=0.0, metadata=_CAR)
    """Random-walk variance of the compass bias per second (drift of the car's own field)."""
    compass_bias_turn_deg2_per_rad: float = field(default=0.0, metadata=_CAR)
    """Bias variance added per radian of heading change (the deviation curve left after
    calibration changes with heading)."""
    heading_second_order: float = field(default=0.0, metadata=_CAR)
    """The second-order term of a heading error, which a linearised filter leaves out: a
    position lever ``r`` turned by an error ``delta`` also moves ``-r delta^2 / 2`` along
    itself, ``|r| sigma^2 = |P_xy,theta|``. Its second moment about the (uncorrected) estimate
    is ``3/4 |P_xy,theta|^2`` (``E[delta^4] = 3 sigma^4``): this factor times
    ``|P_xy,theta|^2`` is added along the lever as it grows (0.75 in the car model; 0, the
    paper's linear filter). docs/estimation.md, "The second-order heading term"."""
    gyro: gyro_model.GyroConfig | None = None
    """The car's yaw-rate sensor turns the heading (``[vehicle] yaw_source = "gyro"`` or
    "both"), its bias and scale states (``localize.gyro``); None: the wheels do."""

    @property
    def car_model(self) -> bool:
        """True when the persistent errors are states (7-state filter, 9 with a gyro)."""
        return (
            self.scale_sigma > 0.0
            or self.diff_sigma > 0.0
            or self.compass_bias_sigma_deg > 0.0
            or self.turn_scale_sigma > 0.0
            or self.gyro is not None
        )

    @property
    def n_state(self) -> int:
        if self.gyro is not None:
            return gyro_model.N_STATE_GYRO
        return model.N_STATE_CAR if self.car_model else model.N_STATE


MIN_LANDMARK_SIGMA_M = 0.01
MAX_LANDMARK_SIGMA_M = 1000.0
"""A landmark fix claims its position to between a centimetre and a kilometre (1 sigma);
outside that it is a damaged record (1e200 squared overflows), not a measurement."""
MAX_COORDINATE_M = 1.0e7
"""Local metres: a quarter of the Earth's circumference from the start is not a city."""

REANCHOR_AFTER = 10
"""Out-of-order inputs in a row after which the inputs' time base wins (about 0.1-0.5 s of
odometry): an estimate stamped in the future by a glitch never freezes for good."""

BIAS_TURN_STEP_RAD = math.radians(10.0)
"""The bias grows with heading changes counted in steps of this size, so that the wiggles of a
straight drive (which cancel) do not add up as if they were turns."""


@dataclass(frozen=True, slots=True)
class StepResult:
    """What one input did to the estimate."""

    kind: str
    accepted: bool
    reason: str | None = None
    mahalanobis_sq: float | None = None


class PoseEstimator:
    """EKF over (x, y, theta) of the rear-axle centre."""

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
        self._gyro = gyro_model.GyroIntegrator()
        self.out_of_order_run = 0
        """Inputs rejected in a row for being older than the estimate (a clock that stepped)."""
        self.interference_level = 1.0
        self.interference = False
        """True while compass readings are judged magnetically disturbed (and rejected)."""
        self.set_pose(x_m, y_m, heading_rad)

    # -- state -------------------------------------------------------------
    def set_pose(
        self,
        x_m: float,
        y_m: float,
        heading_rad: float,
        covariance: np.ndarray | None = None,
    ) -> None:
        """Put the car at a known pose (start, or a checkpoint) with the given covariance."""
        cfg = self.config
        x = np.array(self._kf.x, dtype=float)
        x[0], x[1], x[2] = x_m, y_m, model.wrap_angle(heading_rad)
        self._kf.x = x
        if covariance is None:
            sp = cfg.initial_position_sigma_m
            sh = math.radians(cfg.initial_heading_sigma_deg)
            covariance = np.diag([sp * sp, sp * sp, sh * sh])
        cov = np.array(covariance, dtype=float)
        if cov.shape == (self.n, self.n):
            self._kf.P = cov
        else:  # a pose covariance for the car model: the error states keep their priors
            P = self.prior_covariance()
            P[:3, :3] = cov.reshape(3, 3)
            self._kf.P = P

    def prior_covariance(self) -> np.ndarray:
        """The starting covariance of every state (pose block: the initial sigmas)."""
        cfg = self.config
        sp = cfg.initial_position_sigma_m
        sh = math.radians(cfg.initial_heading_sigma_deg)
        diag = [sp * sp, sp * sp, sh * sh]
        if self.n > model.N_STATE:
            sb = math.radians(cfg.compass_bias_sigma_deg)
            diag += [cfg.scale_sigma**2, cfg.diff_sigma**2, sb * sb, cfg.turn_scale_sigma**2]
        if cfg.gyro is not None:
            diag += [cfg.gyro.bias_var, cfg.gyro.scale_sigma**2]
        return np.diag(diag)

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

    @property
    def heading_rad(self) -> float:
        """The estimated heading (counter-clockwise from east), ``x[model.STATE_THETA]``."""
        return float(self._kf.x[model.STATE_THETA])

    def restore(self, x: np.ndarray, P: np.ndarray, last_t_s: float | None) -> None:
        """A checkpoint's state, and its time order when the clock is the same one."""
        self.set_state(x, P)
        if last_t_s is not None:
            self._last_t = float(last_t_s)

    def forget_heading(self) -> None:
        """No heading known (the first compass reading gives it): its variance a full turn's,
        uncorrelated with the position."""
        P = self.P
        P[2, 2] = math.pi**2
        P[0, 2] = P[2, 0] = P[1, 2] = P[2, 1] = 0.0
        x = self.x
        self.set_pose(float(x[0]), float(x[1]), 0.0, P)

    def inflate_position(self, spread_m: float) -> None:
        """Widen the position by ``spread_m`` (a 2-sigma distance, both axes: a restart, where
        nothing is known of what the car did meanwhile); nothing for a non-finite or <= 0."""
        if not (math.isfinite(spread_m) and spread_m > 0):
            return
        P = self.P
        var = (spread_m / 2.0) ** 2
        P[0, 0] += var
        P[1, 1] += var
        x = self.x
        self.set_pose(float(x[0]), float(x[1]), float(x[2]), P)

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
        x, P = self.x, self.P
        for i, value, sigma in states:
            x[i] = value
            P[i, :] = 0.0
            P[:, i] = 0.0
            P[i, i] = sigma * sigma
        self.set_state(x, P)

    def state_problem(self) -> str | None:
        """Why this state is not valid (``state_limits``, as a checkpoint is judged), or None."""
        prior = np.diag(self.prior_covariance()).tolist()
        return state_limits.state_problem(list(self._kf.x), self.P, prior)

    def heading_from_compass(self, theta_rad: float, compass_var: float) -> None:
        """Take the heading from a compass reading (no heading known yet).

        The compass measures heading + bias, so the heading inherits the bias uncertainty and
        is anti-correlated with the bias state."""
        x, P = self.x, self.P
        if self.n > model.N_STATE:
            b = model.STATE_BIAS
            theta = model.wrap_angle(theta_rad - x[b])
            P[2, :] = 0.0
            P[:, 2] = 0.0
            P[2, 2] = compass_var + P[b, b]
            P[2, b] = P[b, 2] = -P[b, b]
        else:
            theta = theta_rad
            P[2, 2] = compass_var
        self.set_pose(float(x[0]), float(x[1]), theta, P)

    def reset(self, x_m: float = 0.0, y_m: float = 0.0, heading_rad: float = 0.0) -> None:
        """Start over at a known pose, forgetting time order and counters."""
        self.set_pose(x_m, y_m, heading_rad)
        self._last_t = None
        self.rejections.clear()
        self.accepted.clear()
        self.resets = 0
        self.healthy = True
        self.interference_level = 1.0
        self.interference = False

    @property
    def x(self) -> np.ndarray:
        return np.array(self._kf.x, dtype=float)

    @property
    def P(self) -> np.ndarray:
        return np.array(self._kf.P, dtype=float)

    @property
    def last_t_s(self) -> float | None:
        return self._last_t

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

    # -- the one entry point ------------------------------------------------
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

    # -- internals ------------------------------------------------------------
    def _reject(self, kind: str, reason: str, d2: float | None = None) -> StepResult:
        self.rejections[reason] += 1
        return StepResult(kind, False, reason, d2)

    def _predict(self, msg: WheelOdometry) -> StepResult:
        cfg = self.config
        dl, dr = msg.d_left_m, msg.d_right_m
        kind = "WheelOdometry"
        if not (math.isfinite(dl) and math.isfinite(dr)):
            return self._reject(kind, "non_finite_input")
        if abs(dl) > cfg.max_wheel_step_m or abs(dr) > cfg.max_wheel_step_m:
            return self._reject(kind, "implausible_odometry")
        car = self.n > model.N_STATE
        turned = self._gyro_step(msg) if cfg.gyro is not None else None
        x = self._kf.x
        raw_l, raw_r = dl, dr
        track = cfg.track_m
        if car:
            dl, dr = model.corrected_wheels(dl, dr, float(x[model.STATE_SCALE]),
                                            float(x[model.STATE_DIFF]))  # fmt: skip
            track = model.effective_track(track, float(x[model.STATE_TURN]))
        d, dth = model.odometry_increment(dl, dr, track)
        F, G, Q = np.empty((3, 3)), np.empty((3, 2)), np.empty((3, 3))
        model.motion_jacobians(float(x[2]), dl, dr, track, F, G)
        var_l = model.wheel_noise_var(dl, cfg.wheel_quantum_m, cfg.wheel_slip_frac)
        var_r = model.wheel_noise_var(dr, cfg.wheel_quantum_m, cfg.wheel_slip_frac)
        if cfg.wheel_walk_var_m2_per_m > 0.0:
            var_l += model.wheel_walk_var(dl, cfg.wheel_walk_var_m2_per_m)
            var_r += model.wheel_walk_var(dr, cfg.wheel_walk_var_m2_per_m)
        model.process_noise(G, var_l, var_r, Q)
        if car:
            Fc, Qc = np.eye(self.n), np.zeros((self.n, self.n))
            Fc[:3, :3] = F
            model.scale_jacobian(G, raw_l, raw_r, Fc)
            model.turn_jacobian(dl, dr, cfg.track_m, Fc)
            Qc[:3, :3] = Q
            Qc[model.STATE_DIFF, model.STATE_DIFF] = cfg.diff_walk_var_per_m * abs(d)
            Qc[model.STATE_THETA, model.STATE_THETA] += model.camber_heading_var(
                d, cfg.camber_diff_sigma, cfg.camber_length_m, cfg.track_m
            )
            if turned is not None and cfg.gyro is not None:  # the gyro turns ("both": measured)
                dth, Fc, Qc, what = turn_fusion.gyro_turn_step(
                    cfg.gyro, x, self._kf.P, (cfg.track_m, float(Qc[2, 2])), (raw_l, raw_r, d),
                    turned, var_l + var_r)  # fmt: skip
                if what is not None:  # the wheels' turn used or gated ("both")
                    (self.accepted if what == turn_fusion.USED else self.rejections)[what] += 1
            dt = 0.0 if self._last_t is None else max(0.0, msg.t_s - self._last_t)
            walk = cfg.compass_bias_walk_deg2_per_s * dt
            self._turn_rad += dth
            turn = 0.0
            if abs(self._turn_rad) >= BIAS_TURN_STEP_RAD:  # a heading change, not a wiggle
                turn = cfg.compass_bias_turn_deg2_per_rad * abs(self._turn_rad)
                self._turn_rad = 0.0
            Qc[model.STATE_BIAS, model.STATE_BIAS] = math.radians(1.0) ** 2 * (walk + turn)
            F, Q = Fc, Qc
        self._kf.F = F
        self._kf.Q = Q
        P, c0 = self._kf.P, 0.0
        if cfg.heading_second_order > 0.0:
            c0 = float(P[0, 2]) ** 2 + float(P[1, 2]) ** 2
        self._kf.predict(u=np.array([d, dth]))
        if cfg.heading_second_order > 0.0:
            P = self._kf.P
            cx, cy = float(P[0, 2]), float(P[1, 2])
            c1 = cx * cx + cy * cy
            if c1 > c0:  # along the lever (cy, -cx): perpendicular to dp/dtheta
                g = cfg.heading_second_order * (c1 - c0) / c1
                P[0, 0] += g * cy * cy
                P[1, 1] += g * cx * cx
                P[0, 1] -= g * cx * cy
                P[1, 0] -= g * cx * cy
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
        cfg = self.config
        kind = "HeadingFix"
        if cfg.compass_two_sigma_deg is None:
            return self._reject(kind, "no_compass_configured")
        if not math.isfinite(msg.theta_rad):
            return self._reject(kind, "non_finite_input")
        var = model.two_sigma_deg_to_var(cfg.compass_two_sigma_deg)
        R = np.array([[var]])
        y, S = model.heading_innovation(self._kf.x, self._kf.P, msg.theta_rad, var)
        d2 = y * y / S
        if cfg.interference_detection:
            self.interference_level, self.interference = model.interference_update(
                self.interference_level,
                self.interference,
                d2,
                cfg.interference_alpha,
                cfg.interference_on_nis,
                cfg.interference_off_nis,
            )
            if self.interference:
                return self._reject(kind, "magnetic_interference", d2)
        if d2 > cfg.compass_gate_chi2:
            return self._reject(kind, "compass_gate", d2)
        self._kf.update(
            np.array([msg.theta_rad]), H_heading, h_heading, R=R, residual=heading_residual
        )
        self._kf.x[2] = model.wrap_angle(float(self._kf.x[2]))
        return StepResult(kind, True, None, d2)

    def _update_landmark(self, msg: LandmarkFix) -> StepResult:
        cfg = self.config
        kind = "LandmarkFix"
        if not (math.isfinite(msg.x_m) and math.isfinite(msg.y_m)
                and math.isfinite(msg.sigma_m) and msg.sigma_m > 0.0):  # fmt: skip
            return self._reject(kind, "non_finite_input")
        if not (
            MIN_LANDMARK_SIGMA_M <= msg.sigma_m <= MAX_LANDMARK_SIGMA_M
            and max(abs(msg.x_m), abs(msg.y_m)) <= MAX_COORDINATE_M
        ):
            return self._reject(kind, "implausible_landmark")
        var = msg.sigma_m**2
        R = np.eye(2) * var
        z = np.array([msg.x_m, msg.y_m])
        y0, y1, s00, s01, s11 = model.position_innovation(
            self._kf.x, self._kf.P, msg.x_m, msg.y_m, var
        )
        d2 = model.mahalanobis_sq_2d(y0, y1, s00, s01, s11)
        if msg.relocalised and self.major_axis_m > LOST_HYSTERESIS * cfg.lost_major_axis_m:
            self._relocalise(msg.x_m, msg.y_m, var)
            return StepResult(kind, True, RELOCALISED, d2)
        if d2 > cfg.landmark_gate_chi2:
            return self._reject(kind, "landmark_gate", d2)
        self._kf.update(z, H_position, h_position, R=R)
        self._kf.x[2] = model.wrap_angle(float(self._kf.x[2]))
        return StepResult(kind, True, None, d2)

    def _relocalise(self, x_m: float, y_m: float, var: float) -> None:
        """A place found by a whole-database search while lost: the position restarts there with
        the fix's variance (its sigma: the sighting range plus the place's, so the 2-sigma
        ellipse holds every point it is seen from), uncorrelated with the rest; the heading and
        the error states keep theirs (an update would be gated out, or pulled by the lost mean)."""
        x = np.array(self._kf.x, dtype=float)
        P = np.array(self._kf.P, dtype=float)
        model.reset_position(x, P, x_m, y_m, var)
        self._kf.x = x
        self._kf.P = P
        self.accepted["relocalisations"] += 1

    def _check_finite(self, x_before: np.ndarray, P_before: np.ndarray) -> bool:
        """After a non-finite result, go back to the last finite pose with a "lost" covariance."""
        if np.all(np.isfinite(self._kf.x)) and np.all(np.isfinite(self._kf.P)):
            return True
        big = self.config.lost_major_axis_m**2
        cov = self.prior_covariance()
        cov[0, 0], cov[1, 1], cov[2, 2] = big, big, math.pi**2
        if np.all(np.isfinite(P_before)):
            cov = np.maximum(cov, P_before)
        self.set_pose(float(x_before[0]), float(x_before[1]), float(x_before[2]), cov)
        self.resets += 1
        self.healthy = False
        self.rejections["non_finite_state_reset"] += 1
        return False
