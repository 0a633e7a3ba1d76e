"""The filter's settings (``EstimatorConfig``): sensor noise, gates, the car model's error
states and a gyro's, each with its config ``rule``. Defaults: the 2007 Tahoe (the paper's
3-state filter); ``car_model`` gives the car model's. Read by the filter's parts
(``estimator``, ``motion``, ``gates``, ``covariance``) and by the car's configuration
(``guidance.core.pipeline_config``), which imports it from ``estimator`` as before."""

from __future__ import annotations

from dataclasses import dataclass, field

from guidance.config_tables import rule
from guidance.core import model
from guidance.core.localize import gyro as gyro_model

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
