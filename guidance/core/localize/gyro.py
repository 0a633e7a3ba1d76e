"""The car's gyro: the stability control's yaw-rate sensor as the car model's turn (issue 38).

Every car with stability control (mandatory in the US since 2012, the EU since 2014) has a
yaw-rate sensor whose reading is on its CAN bus. Its error is not a wheel's: a **bias** in
rad/s that turns the heading by ``bias x time`` (stops included) and that the sensor shows
while the car stands still, a **scale** error on every turn, and white noise (angle random
walk). With ``[vehicle] yaw_source = "gyro"`` the heading change of each odometry step is the
gyro's, the distance the wheels'; the wheels' left/right difference then turns nothing.

State layout (after the car model's seven, ``guidance.core.model``):

* ``STATE_GYRO_BIAS`` (rad/s): the gyro reads ``omega_true / (1 + kg) + bg``;
* ``STATE_GYRO_SCALE`` (a fraction ``kg``): the true heading change is the gyro's, its bias
  removed, times ``1 + kg``.

The bias walks with **time** (``GyroConfig.bias_walk_deg2_per_s3``); while the wheels say the
car stands still, each reading measures the bias (a zero-velocity update) and no heading is
integrated from it. The priors and their data-sheet sources are in docs/estimation.md
("The car's gyro").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guidance.core import model
from guidance.core.messages import WheelOdometry, YawRate

STATE_GYRO_BIAS = model.N_STATE_CAR
"""The gyro's bias, rad/s: it reads ``omega_true / (1 + kg) + bg``."""
STATE_GYRO_SCALE = model.N_STATE_CAR + 1
"""The gyro's scale error ``kg``: the true heading change is ``(gyro angle - bg dt)(1 + kg)``."""
N_STATE_GYRO = model.N_STATE_CAR + 2
"""The car model's state with the gyro's two (a car whose yaw comes from its gyro)."""

MAX_RATE_RAD_S = 5.0
"""About 290 deg/s, beyond the measuring range of ESC yaw-rate sensors (100-300 deg/s): a
larger reading is a unit mistake or a damaged frame, refused."""

YAW_SOURCES = ("wheels", "gyro", "both")
"""``[vehicle] yaw_source``: where the heading change comes from: the wheels' left/right
difference, the gyro, or both, each a measurement of the turn the filter weighs
(``guidance.core.localize.turn_fusion``)."""


@dataclass(frozen=True, slots=True)
class GyroConfig:
    """The gyro's error model; each default's source is in docs/estimation.md."""

    bias_sigma_deg_s: float = 0.3
    """Prior 1-sigma of the bias as it reaches the CAN bus. The sensor's own zero-rate offset
    is specified at up to +-3.75 deg/s over life and temperature (a Hyundai/Kia ESC yaw-rate
    and lateral-g sensor's sheet), +-1-3 deg/s typical for MEMS gyros (BMI055 +-1 deg/s
    typical, BMI160 +-3); the stability control trims it at every standstill and while
    driving straight (it judges under- and oversteer from the yaw rate to a few tenths of a
    degree per second), so what reaches the bus is that compensation's residual plus what
    moved since (below): 0.3 deg/s (1-sigma), a judgement from how the ESC uses the signal,
    not a measured distribution. A car that starts from standstill learns it in its first
    seconds; one that starts moving carries it as heading uncertainty growing with time."""
    bias_walk_deg2_per_s3: float = 1e-5
    """The bias's random walk, (deg/s)^2 per second: its temperature coefficient (BMI055
    0.015 deg/s per K, ICM-20602 0.01) times the 10 K an ECU warms in the first 20 minutes
    gives 0.1-0.15 deg/s over 1200 s: (0.1)^2 / 1000 s. The in-run bias instability (BMI055
    1.6 deg/h typical, BMI160 6: 0.0005-0.003 deg/s) is far below it."""
    noise_density_deg_rt_s: float = 0.015
    """White rate noise, deg/s per root Hz: MEMS gyros of the ESC generation specify
    0.004-0.014 (ICM-42688 0.0028, ASM330LHH 0.005, BMI160 0.008, BMI055 0.014): the
    largest, rounded up for the car's vibration. With the whole 50 Hz band in each reading
    (``reading_var``) that is 0.11 deg/s per reading."""
    scale_sigma: float = 0.02
    """Prior 1-sigma of the scale error: ESC sensors specify non-linearity within +-1 % and
    MEMS sensitivity tolerances of +-1-3 %; a sensor tilted 5 degrees reads cos(5) = 0.4 %
    low: 2 %."""
    bandwidth_hz: float = 50.0
    """The sensor's bandwidth (ESC sensors: 45-60 Hz upper cut-off): readings closer than
    1 / (2 x this) apart are not independent (``zupt_var``)."""
    max_hold_s: float = 0.5
    """A reading older than this does not turn the heading: the step falls back to the
    wheels' left/right difference (counted), as before the first reading."""
    gate_chi2: float = model.CHI2_1D_P999
    """A standstill reading further than this (d^2, 1 dof, P = 0.999) from the bias is not
    used: the car was turning while its wheels read zero."""
    with_wheels: bool = False
    """``yaw_source = "both"``: the gyro turns the heading and each step's wheel difference
    measures the same turn (``turn_fusion``), gated at ``gate_chi2`` (a wheel that slips)."""

    def __post_init__(self) -> None:
        for name in ("bias_sigma_deg_s", "scale_sigma", "noise_density_deg_rt_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"gyro {name} must be a finite number > 0, not {v!r}")
        for name in ("bias_walk_deg2_per_s3", "bandwidth_hz", "max_hold_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"gyro {name} must be a finite number >= 0, not {v!r}")

    @property
    def bias_var(self) -> float:
        return math.radians(self.bias_sigma_deg_s) ** 2

    @property
    def walk_var_per_s(self) -> float:
        """The bias's walk, (rad/s)^2 per second."""
        return math.radians(1.0) ** 2 * self.bias_walk_deg2_per_s3

    @property
    def noise_var_per_s(self) -> float:
        """The heading's angle random walk, rad^2 per second of integration."""
        return math.radians(self.noise_density_deg_rt_s) ** 2


def reading_var(cfg: GyroConfig, dt_s: float) -> float:
    """Variance (rad/s)^2 of one reading's noise, ``dt_s`` after the previous one. A CAN yaw
    rate is either the mean over its period (variance N^2 / dt for white noise of density N)
    or a sample of the sensor's output (its whole band: N^2 x bandwidth); which one a car
    sends is not written down, so the larger: N^2 x max(bandwidth, 1 / dt). Readings closer
    than the sensor's correlation time are then not counted as independent (a stop teaches
    the bias as much at 100 Hz as at 1 / (2 x bandwidth))."""
    return cfg.noise_var_per_s * max(cfg.bandwidth_hz, 1.0 / max(dt_s, 1e-3))


MAX_PENDING = 256
"""Readings kept while waiting for the wheels to say whether the car stood still around them
(a wheel step confirms or drops them; wheels that stop arriving cannot make this grow)."""


class GyroIntegrator:
    """The gyro's angle between two odometry steps (the readings and the wheels arrive at their
    own rates): each reading closes the interval since the previous one (trapezoid rule, as
    the wheel decoder integrates speeds); a step takes what was gathered.

    It also says which readings were taken standing still: those the wheels read zero on
    both sides of (``wheel_step``). The last reading before the wheels move and the first
    after they stop are not: below the wheel sensors' lowest speed (about 1 km/h) a car
    pulling away can already turn."""

    __slots__ = (
        "angle", "angle_var", "last_rate", "last_t", "last_wheel_t", "pending", "span_s",
        "standing", "zero_since",
    )  # fmt: skip

    def __init__(self) -> None:
        self.last_t: float | None = None
        self.last_rate = 0.0
        self.angle = 0.0
        """Integrated reading since the last step, rad (bias included)."""
        self.span_s = 0.0
        """The time that angle covers, s (what the bias turned it by is ``bg x span_s``)."""
        self.angle_var = 0.0
        """The noise variance of that angle, rad^2 (each reading's variance x its interval^2)."""
        self.standing = False
        """The last wheel step read zero: nothing is integrated."""
        self.last_wheel_t: float | None = None
        self.zero_since: float | None = None
        """Start of the wheels' current run of zero steps."""
        self.pending: list[tuple[float, float, float]] = []
        """(time, rate, variance) of readings the wheels have not judged yet."""

    def reading(self, t_s: float, rate_rad_s: float, cfg: GyroConfig) -> None:
        """Take one reading. While the car stands still nothing is integrated: the reading is
        the bias. A reading after a gap of more than ``cfg.max_hold_s`` starts over."""
        dt = 0.0 if self.last_t is None else t_s - self.last_t
        if self.last_t is not None and 0.0 < dt <= cfg.max_hold_s:
            var = reading_var(cfg, dt)
            if not self.standing:
                self.angle += 0.5 * (self.last_rate + rate_rad_s) * dt
                self.span_s += dt
                self.angle_var += var * dt * dt
            self.pending.append((t_s, rate_rad_s, var))
            del self.pending[:-MAX_PENDING]
        self.last_t, self.last_rate = t_s, rate_rad_s

    def fresh(self, t_s: float, max_age_s: float) -> bool:
        return self.last_t is not None and abs(t_s - self.last_t) <= max_age_s

    def wheel_step(self, t_s: float, zero: bool) -> list[tuple[float, float]]:
        """The wheels' step ending at ``t_s`` (``zero``: both read nothing): the (rate,
        variance) of the readings it confirms were taken standing still, strictly inside the
        run of zero steps; the readings it shows were not are dropped."""
        start, self.last_wheel_t = self.last_wheel_t, t_s
        self.standing = zero
        if not zero:
            self.zero_since = None
            self.pending = [r for r in self.pending if r[0] > t_s]
            return []
        if self.zero_since is None:
            self.zero_since = start if start is not None else t_s
        since = self.zero_since
        out = [(r, v) for (t, r, v) in self.pending if since <= t < t_s]
        self.pending = [q for q in self.pending if q[0] >= t_s]
        return out

    def take(self) -> tuple[float, float, float]:
        """The angle gathered since the last step, the time it covers and its noise variance;
        starts over."""
        out = (self.angle, self.span_s, self.angle_var)
        self.angle = self.span_s = self.angle_var = 0.0
        return out


def gyro_turn(angle_rad: float, span_s: float, bias: float, scale: float) -> float:
    """The heading change a gyro angle says, its bias removed and its scale applied."""
    return (angle_rad - bias * span_s) * (1.0 + scale)


def fill_gyro_step(
    x: np.ndarray,
    d_raw_m: float,
    d_diff_raw_m: float,
    d_m: float,
    dtheta: float,
    angle_rad: float,
    span_s: float,
    angle_var: float,
    var_d_m2: float,
    F: np.ndarray,
    Q: np.ndarray,
) -> None:
    """Fill the state Jacobian ``F`` (identity on entry) and process noise ``Q`` (zeros on
    entry) of one odometry step whose turn is the gyro's (``gyro_turn``) and whose distance
    is the wheels' (``d_m`` corrected, ``d_raw_m`` their raw mean, ``d_diff_raw_m`` raw
    right minus left). The position follows the chord at the mid-point heading
    (``model.motion_predict``); ``angle_var`` is the gyro angle's noise variance
    (``GyroIntegrator``), ``var_d_m2`` the distance's (the two wheels' walks over four).
    The bias's time walk is not here: it is added for every interval of time, driving or
    not (``bias_walk``)."""
    theta = float(x[model.STATE_THETA])
    mid = theta + 0.5 * dtheta
    c, s = math.cos(mid), math.sin(mid)
    bias, scale = float(x[STATE_GYRO_BIAS]), float(x[STATE_GYRO_SCALE])
    F[0, model.STATE_THETA] = -d_m * s
    F[1, model.STATE_THETA] = d_m * c
    # the distance's scale states (true distance = raw x (1 + k) -/+ kd / 2 per wheel)
    F[0, model.STATE_SCALE] = c * d_raw_m
    F[1, model.STATE_SCALE] = s * d_raw_m
    F[0, model.STATE_DIFF] = 0.25 * c * d_diff_raw_m
    F[1, model.STATE_DIFF] = 0.25 * s * d_diff_raw_m
    # the turn's: d(dtheta)/d(bg) and d(dtheta)/d(kg); the chord moves with half of it
    dbg = -span_s * (1.0 + scale)
    dkg = angle_rad - bias * span_s
    for j, g in ((STATE_GYRO_BIAS, dbg), (STATE_GYRO_SCALE, dkg)):
        F[0, j] = -d_m * s * 0.5 * g
        F[1, j] = d_m * c * 0.5 * g
        F[model.STATE_THETA, j] = g
    # noise: the distance along the chord; the gyro's white noise turns the heading and,
    # through the mid-point, the chord
    var_th = angle_var * (1.0 + scale) ** 2
    gd = (c, s, 0.0)
    gt = (-0.5 * d_m * s, 0.5 * d_m * c, 1.0)
    for i in range(3):
        for j in range(3):
            Q[i, j] = gd[i] * gd[j] * var_d_m2 + gt[i] * gt[j] * var_th


def bias_walk(P: np.ndarray, cfg: GyroConfig, dt_s: float) -> None:
    """The bias's random walk over ``dt_s`` of time (stops included), in place."""
    if dt_s > 0.0:
        P[STATE_GYRO_BIAS, STATE_GYRO_BIAS] += cfg.walk_var_per_s * dt_s


def zupt_update(
    x: np.ndarray, P: np.ndarray, rate_rad_s: float, var: float, gate_chi2: float
) -> float | None:
    """A standstill reading as a measurement of the bias (h(x) = bg: the true rate is 0), in
    place, Joseph form. Returns its d^2, or None when gated out (the car was turning while
    the wheels read zero: creeping below the wheel sensors' lowest speed)."""
    b = STATE_GYRO_BIAS
    y = rate_rad_s - float(x[b])
    S = float(P[b, b]) + var
    d2 = y * y / S
    if d2 > gate_chi2:
        return None
    k = P[:, b] / S
    x += k * y
    n = P.shape[0]
    A = np.eye(n)
    A[:, b] -= k
    P[:, :] = A @ P @ A.T + var * np.outer(k, k)
    return d2


def take_reading(g: GyroIntegrator, P: np.ndarray, msg: YawRate, cfg: GyroConfig) -> str | None:
    """One reading into ``g`` (the bias walks in ``P`` with the time since the previous
    one); returns why it was refused, or None."""
    rate = msg.yaw_rate_rad_s
    if not math.isfinite(rate):
        return "non_finite_input"
    if abs(rate) > MAX_RATE_RAD_S:
        return "implausible_yaw_rate"
    if g.last_t is not None and msg.t_s <= g.last_t:  # the integral runs forward only
        return "gyro_out_of_order"
    before = g.last_t
    g.reading(msg.t_s, rate, cfg)
    if before is not None and msg.t_s > before:
        bias_walk(P, cfg, msg.t_s - before)
    return None


@dataclass(frozen=True, slots=True)
class BeforeStep:
    turned: tuple[float, float, float] | None
    """(angle, span, variance) the gyro gathered; None: no fresh reading, the wheels turn."""
    standstill: int
    """Standstill readings that updated the bias."""
    gated: int
    """Standstill readings refused by the gate."""


def before_step(
    g: GyroIntegrator, x: np.ndarray, P: np.ndarray, msg: WheelOdometry, cfg: GyroConfig
) -> BeforeStep:
    """Before an odometry step: the standstill readings its wheels confirm update the bias
    (``zupt_update``, in place), then what the gyro gathered for the step."""
    zero = msg.d_left_m == 0.0 and msg.d_right_m == 0.0
    used = gated = 0
    for rate, var in g.wheel_step(msg.t_s, zero):
        if zupt_update(x, P, rate, var, cfg.gate_chi2) is None:
            gated += 1
        else:
            used += 1
    turned = g.take()
    return BeforeStep(turned if g.fresh(msg.t_s, cfg.max_hold_s) else None, used, gated)


def gyro_step(
    x: np.ndarray,
    raw_l_m: float,
    raw_r_m: float,
    d_m: float,
    turned: tuple[float, float, float],
    var_wheels_m2: float,
) -> tuple[float, np.ndarray, np.ndarray]:
    """The heading change, state Jacobian and process noise of an odometry step turned by the
    gyro (``turned``: ``GyroIntegrator.take``), its distance ``d_m`` the wheels' (corrected;
    ``var_wheels_m2`` the two wheels' variances summed)."""
    angle, span, angle_var = turned
    n = x.shape[0]
    dth = gyro_turn(angle, span, float(x[STATE_GYRO_BIAS]), float(x[STATE_GYRO_SCALE]))
    F, Q = np.eye(n), np.zeros((n, n))
    fill_gyro_step(x, 0.5 * (raw_l_m + raw_r_m), raw_r_m - raw_l_m, d_m, dth, angle, span,
                   angle_var, 0.25 * var_wheels_m2, F, Q[:3, :3])  # fmt: skip
    return dth, F, Q
