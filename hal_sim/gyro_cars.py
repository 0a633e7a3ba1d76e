"""Gyro cars and stops for the population (issue 38, item 2; ``hal_sim.population``).

A gyro car turns its heading by its yaw-rate sensor's reading (``[vehicle] yaw_source =
"gyro"``), so its errors are the sensor's: drawn heavier-tailed than the filter's priors
(``guidance.core.localize.gyro.GyroConfig``, whose sources are in docs/estimation.md):

* bias: t4 x 0.18 deg/s (sd 0.25 deg/s; the prior is 0.3), within +-3.75 deg/s (the ESC
  sensor sheet's offset over life and temperature);
* the bias's walk with time: the filter's own 1e-5 (deg/s)^2 per s (temperature);
* scale: t4 x 1.2 % (sd 1.7 %; the prior is 2 %), within +-8 %;
* white noise: the filter's own 0.015 deg/s per root Hz over a 50 Hz band.

``car_errors.draw_gyro`` draws them; ``car_errors.draw_matched_gyro`` from the filter's own
Gaussian priors (the yardstick).

Stops: a time-grown error needs time standing still as well as driving. At each intersection
a car stops with probability ``STOP_PROBABILITY`` for a time uniform in ``STOP_S``: urban
signals run 60-120 s cycles with about half of it red for a given approach, and a car that
arrives at a random moment waits a uniform part of the red (0-60 s); most intersections of a
grid are signalised or yield. While it stands, its wheels read zero and its gyro reads its
bias plus noise. A drive with stops also starts from a parked car (the operator sets the start
where the car stands), for a time drawn from the same range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

STOP_PROBABILITY = 0.3
STOP_S = (5.0, 60.0)
GYRO_BIAS_T4 = (0.18, 3.75)
"""(t4 scale, limit) of the population's gyro bias, deg/s."""
GYRO_SCALE_T4 = (0.012, 0.08)
GYRO_WALK_DEG2_PER_S3 = 1e-5
GYRO_NOISE_DEG_RT_S = 0.015
GYRO_BANDWIDTH_HZ = 50.0


@dataclass(frozen=True, slots=True)
class GyroErrors:
    """One car's yaw-rate sensor."""

    bias_deg_s: float
    scale: float
    """The sensor reads the true rate / (1 + scale) (the filter's ``kg``)."""
    walk_deg2_per_s3: float = GYRO_WALK_DEG2_PER_S3
    noise_deg_rt_s: float = GYRO_NOISE_DEG_RT_S


class GyroSim:
    """The sensor's readings from the true motion: each reading the mean rate over the step,
    divided by ``1 + scale``, plus the bias (walking with time) and white noise of the
    sensor's band."""

    def __init__(self, errors: GyroErrors, rng: np.random.Generator) -> None:
        self.errors = errors
        self.rng = rng
        self.bias = math.radians(errors.bias_deg_s)

    def reading(self, true_turn_rad: float, dt_s: float) -> float:
        e = self.errors
        self.bias += (
            float(self.rng.normal()) * math.radians(1.0) * math.sqrt(e.walk_deg2_per_s3 * dt_s)
        )
        # a reading samples the sensor's band (``gyro.reading_var``: the filter's own account)
        band = max(GYRO_BANDWIDTH_HZ, 1.0 / dt_s)
        noise = float(self.rng.normal()) * math.radians(e.noise_deg_rt_s) * math.sqrt(band)
        return true_turn_rad / dt_s / (1.0 + e.scale) + self.bias + noise


def stop_for(rng: np.random.Generator) -> float:
    """Seconds this car stands at the intersection it reached (0: it drives on)."""
    if rng.uniform() >= STOP_PROBABILITY:
        return 0.0
    return float(rng.uniform(*STOP_S))
