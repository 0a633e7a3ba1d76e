"""The car model's defaults (``[estimator] model = "car"``): the persistent errors of a real
car as states of the filter, and what a compass with or without a deviation card adds."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from guidance.core.localize.estimator_config import EstimatorConfig

CAR_MODEL: dict[str, float] = {
    "wheel_quantum_m": 0.0,
    "wheel_slip_frac": 0.0,
    "wheel_walk_var_m2_per_m": 5e-6,
    "scale_sigma": 0.02,
    "diff_sigma": 3e-4,
    "camber_diff_sigma": 1.6e-4,
    "camber_length_m": 250.0,
    "turn_scale_sigma": 0.02,
    "compass_bias_walk_deg2_per_s": 0.15,
    "initial_position_sigma_m": 3.0,
    "heading_second_order": 0.75,
}
"""The car model's defaults (``[estimator] model = "car"``); each value's reason and the
real-drive figures behind it are in docs/estimation.md. Wheel speeds on CAN are speeds, not
tick counts, so there is no per-increment quantisation; the random part of the wheel noise is
a walk in distance (2.2 mm per sqrt(m) per wheel); a common scale error of 2 % for a car nobody
calibrated (tyre wear takes up to 2.2 % off the rolling radius over a tyre's life, tyres of one
size differ by up to 1.5 %, pressure, load and speed 0.5 %, and the speed signal carries
whatever scaling its maker chose: issue 21) and a left/right difference of 0.03 % (0.1 mm of
rolling radius) are states, the difference also changing from street to street by 0.016 %
(road camber, tyre temperature: a bounded Gauss-Markov process over 250 m, not a walk); the
compass bias drifts 3 degrees a minute (real RAV4: about 3
degrees after the first 20 s); the operator's start is a point picked on a map, 3 m (1 sigma)."""
PROFILE_TRACK_TURN_SIGMA = 0.04
"""The turn scale's prior when the track is a vehicle profile's (no ``[vehicle] track_m``):
the profile's is one reference car's rear track for every model sharing its DBC (Toyota's
run from about 1.53 to 1.72 m against 1.62: about 3.4 % 1-sigma), on top of the 2 % of the
effective track against a spec (load transfer, the tyres' lateral deflection):
sqrt(2^2 + 3.4^2) = 4 % (docs/estimation.md, "The effective track")."""
CAR_COMPASS_UNCALIBRATED = {"compass_bias_sigma_deg": 60.0, "compass_bias_turn_deg2_per_rad": 250.0}
"""No deviation card: real in-car magnetometers read 40-90 degrees off, and the uncorrected
deviation changes by about 20 degrees over a quarter turn."""
CAR_COMPASS_CALIBRATED = {"compass_bias_sigma_deg": 5.0, "compass_bias_turn_deg2_per_rad": 16.0}
"""With a deviation card from ``guidance calibrate``: about the fit's residual (2-5 degrees)."""


def car_model(base: EstimatorConfig, *, calibrated: bool, **overrides: float) -> EstimatorConfig:
    """``base`` with the car model's defaults, then the config's own values (``overrides``)."""
    values: dict[str, Any] = dict(CAR_MODEL)
    if base.compass_two_sigma_deg is not None:
        values.update(CAR_COMPASS_CALIBRATED if calibrated else CAR_COMPASS_UNCALIBRATED)
    values.update(overrides)
    return replace(base, **values)
