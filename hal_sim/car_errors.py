"""One simulated car's sensor errors: what they are, how a population draws them, and the
car's sensors that count them (issue 37, item 4; docs/layout.md "One simulated car").

``hal_sim.car`` holds the model's math (compiled, shared with the world's encoders and
compass); this module holds one car's persistent errors (``CarErrors``), their draws and
``CarSensors``, which reads a car's true motion step by step through that math with the car's
own errors. ``hal_sim.population`` drives such cars; ``hal_sim.gyro_cars`` is a gyro car's
yaw-rate sensor.

The car errors, with heavier tails than the filter's priors (Student t, 4 degrees of freedom;
``draw_car``):

* wheel-speed scale: t4 x 1.2 % (standard deviation 1.7 %; the filter's prior is 2 %), within
  +-8 % (beyond that a wrong DBC scale, not a tyre);
* right-minus-left scale difference: t4 x 0.02 % (sd 0.028 %; the prior is 0.03 %), within
  +-0.3 % (a flat tyre);
* turn scale (the effective track over the configured one, or a gyro's sensitivity): t4 x
  1.2 % (sd 1.7 %; the prior is 2 %), within +-8 %;
* each wheel's random walk: the filter's own 2.2 mm per root metre;
* compass: a mounting offset N(0, 40 deg), a hard-iron field of r x the earth's horizontal
  field (r uniform 0-0.4, direction uniform) giving the heading-dependent deviation
  atan2(r sin(h - phi), 1 + r cos(h - phi)), a bias drift of 0.1 deg^2/s, white noise 3 deg;
* start: the operator's heading N(0, 1 deg) off, the position N(0, 3 m) off per axis;
* gyro cars (``draw_gyro``, ``hal_sim.gyro_cars``): the yaw-rate sensor's bias, its walk with
  time, its scale and noise.

``draw_matched_car`` and ``draw_matched_gyro`` draw from the filter's own Gaussian priors
instead (the yardstick of a perfectly matched filter); ``with_camber`` adds a car's
street-to-street left/right process.

This module is not compiled: ``hal_sim.car`` is (numba's cache key, ``NUMBA_SOURCES``), and
a change to the draws here does not recompile the world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from guidance.core.localize.gyro import GyroConfig
from hal_sim.car import compass_reading, hard_iron_rad, wheel_travel
from hal_sim.gyro_cars import GYRO_BIAS_T4, GYRO_SCALE_T4, GyroErrors


@dataclass(frozen=True, slots=True)
class CarErrors:
    """One car's persistent sensor errors (module doc)."""

    scale: float
    diff: float
    walk_m2_per_m: float
    compass_offset_deg: float
    hard_iron_ratio: float
    hard_iron_dir_rad: float
    compass_drift_deg2_per_s: float
    compass_noise_deg: float
    start_heading_deg: float
    start_dx_m: float
    start_dy_m: float
    diff_walk_var_per_m: float = 0.0
    """The left/right difference's random walk along the road (road camber from street to
    street, tyre temperature): 0 keeps it constant."""
    turn_scale: float = 0.0
    """The car's effective track over the track the filter is configured with, minus 1 (tyre
    scrub and load transfer in turns, a profile's track for another model): every turn's
    left/right distance difference, so its heading change, is this much larger than the
    filter's. 0: none. The car model's state ``kt`` (docs/estimation.md)."""
    camber_sigma: float = 0.0
    """1-sigma of the part of the left/right difference that changes from street to street
    (road camber, each side's tyre temperature): a Gauss-Markov process of correlation length
    ``camber_length_m`` added to ``diff`` (``with_camber``). 0: none."""
    camber_length_m: float = 250.0
    gyro: GyroErrors | None = None
    """A gyro car's yaw-rate sensor (its filter then turns the heading by it); None: a car
    whose heading comes from its wheels."""

    def deviation_rad(self, heading_rad: float) -> float:
        """The compass error at a true heading: the offset plus the hard-iron curve."""
        curve = hard_iron_rad(self.hard_iron_ratio, self.hard_iron_dir_rad, heading_rad)
        return math.radians(self.compass_offset_deg) + curve


HARD_IRON = (0.0, 0.4)
"""The population's hard-iron ratio, uniform between these (module doc). A compass on a
dashboard near steel, speakers or wiring can see a car field of 0.8-0.9 of the earth's
horizontal field (issue 21's circle drive): ``draw_car(rng, hard_iron=(0.6, 0.9))`` draws such
cars, whose deviation curve no bias walk can follow (docs/estimation.md)."""


def draw_car(rng: np.random.Generator, *, hard_iron: tuple[float, float] = HARD_IRON) -> CarErrors:
    """One car's persistent errors (module doc); ``hard_iron``: the range of its hard-iron
    ratio (the same draws otherwise)."""
    return CarErrors(
        scale=t4_draw(rng, 0.012, 0.08),
        diff=t4_draw(rng, 0.0002, 0.003),
        walk_m2_per_m=5e-6,
        compass_offset_deg=float(rng.normal(0.0, 40.0)),
        hard_iron_ratio=float(rng.uniform(*hard_iron)),
        hard_iron_dir_rad=float(rng.uniform(-math.pi, math.pi)),
        compass_drift_deg2_per_s=0.1,
        compass_noise_deg=3.0,
        start_heading_deg=float(rng.normal(0.0, 1.0)),
        start_dx_m=float(rng.normal(0.0, 3.0)),
        start_dy_m=float(rng.normal(0.0, 3.0)),
        turn_scale=t4_draw(rng, 0.012, 0.08),
    )


CAMBER_SIGMA = (5e-5, 3e-4)
"""The street-to-street part of the left/right difference: its 1-sigma log-uniform between
0.005 % and 0.03 % (road cross slope from street to street and each side's tyre temperature,
docs/estimation.md; rms 0.016 %, the filter's own), its correlation length uniform 150-400 m
(a street between junctions)."""


def with_camber(car: CarErrors, rng: np.random.Generator) -> CarErrors:
    """``car`` with its own street-to-street left/right process (``CAMBER_SIGMA``), drawn from
    ``rng`` (a stream of its own, so the cars' other draws stay those of ``draw_car``)."""
    lo, hi = CAMBER_SIGMA
    sigma = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    return replace(car, camber_sigma=sigma, camber_length_m=float(rng.uniform(150.0, 400.0)))


def draw_matched_car(rng: np.random.Generator) -> CarErrors:
    """A car whose wheel errors are drawn from the filter's own Gaussian priors (scale 2 %,
    left/right 0.03 %, turn scale 2 %; the start and the wheel walk are the filter's already):
    the yardstick of a perfectly matched filter for the per-car figures (docs/estimation.md)."""
    car = draw_car(rng)
    return replace(
        car,
        scale=float(rng.normal(0.0, 0.02)),
        diff=float(rng.normal(0.0, 3e-4)),
        turn_scale=float(rng.normal(0.0, 0.02)),
    )


def draw_gyro(car: CarErrors, rng: np.random.Generator) -> CarErrors:
    """``car`` as a gyro car, its sensor heavier-tailed than the filter's priors
    (``hal_sim.gyro_cars``), drawn from ``rng`` (a stream of its own)."""
    return replace(car, gyro=GyroErrors(t4_draw(rng, *GYRO_BIAS_T4), t4_draw(rng, *GYRO_SCALE_T4)))


def draw_matched_gyro(car: CarErrors, rng: np.random.Generator) -> CarErrors:
    """``car`` as a gyro car whose sensor is drawn from the filter's own priors."""
    g = GyroConfig()
    errors = GyroErrors(
        float(rng.normal(0.0, g.bias_sigma_deg_s)),
        float(rng.normal(0.0, g.scale_sigma)),
        g.bias_walk_deg2_per_s3,
        g.noise_density_deg_rt_s,
    )
    return replace(car, gyro=errors)


def t4_draw(rng: np.random.Generator, scale: float, limit: float) -> float:
    """A Student-t (4 dof) draw times ``scale``, redrawn beyond ``limit`` (a wheel scale 25 %
    off is a wrong DBC, not a tyre)."""
    while True:
        v = scale * float(rng.standard_t(4))
        if abs(v) <= limit:
            return v


class CarSensors:
    """One population car's wheel sensors and compass, from its true motion step by step.

    Draws, in order, from ``rng`` (shared with the caller's other draws: the random route's
    exits): per wheel step the left/right difference's walk (when it walks), then each
    wheel's walk; per compass reading the bias drift, then the noise. The road camber draws
    from ``camber_rng``, a stream of its own (so the cars' other draws stay the same with
    and without it)."""

    def __init__(
        self,
        errors: CarErrors,
        rng: np.random.Generator,
        camber_rng: np.random.Generator,
        track_m: float,
    ) -> None:
        self.errors = errors
        self.rng = rng
        self.camber_rng = camber_rng
        self.track_m = track_m
        self.diff = errors.diff
        self.camber = 0.0
        if errors.camber_sigma > 0.0:
            self.camber = errors.camber_sigma * float(camber_rng.normal())
        self.drift_deg = 0.0

    def wheels(self, d_m: float, dth_rad: float) -> tuple[float, float]:
        """The left and right wheels' distances for a step of ``d_m`` along the path turning
        ``dth_rad``: each wheel's true travel over the car's effective track (``turn_scale``)
        counted with its side's scale (``scale`` and half the left/right difference, road
        camber included) and its own walk."""
        e, rng = self.errors, self.rng
        if e.diff_walk_var_per_m > 0.0:
            self.diff += float(rng.normal()) * math.sqrt(e.diff_walk_var_per_m * d_m)
        if e.camber_sigma > 0.0:  # exact Gauss-Markov step over d
            a = math.exp(-d_m / e.camber_length_m)
            self.camber = a * self.camber + e.camber_sigma * math.sqrt(1.0 - a * a) * float(
                self.camber_rng.normal()
            )
        out = [0.0, 0.0]
        for side, sign in ((0, -1.0), (1, 1.0)):
            true = d_m + sign * 0.5 * self.track_m * (1.0 + e.turn_scale) * dth_rad
            walk = float(rng.normal()) * math.sqrt(e.walk_m2_per_m * abs(true))
            out[side] = float(
                wheel_travel(true, e.scale + sign * 0.5 * (self.diff + self.camber), walk)
            )
        return out[0], out[1]

    def compass(self, heading_rad: float, since_s: float) -> float:
        """The compass's reading at the true heading, ``since_s`` after its last one (its
        bias drifts by a random walk over that time)."""
        e, rng = self.errors, self.rng
        self.drift_deg += float(rng.normal()) * math.sqrt(e.compass_drift_deg2_per_s * since_s)
        error = e.deviation_rad(heading_rad) + math.radians(self.drift_deg)
        return float(
            compass_reading(
                heading_rad, error, float(rng.normal()), math.radians(e.compass_noise_deg)
            )
        )
