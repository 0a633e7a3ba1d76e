"""The simulated car's sensors: one sensor-error model (issue 37, item 4; docs/layout.md
"Simulated car").

What a wheel-speed sensor and a compass report for the car's true motion, written once:

* ``wheel_travel``: one wheel's distance as its sensor counts it over a step: the true
  distance times ``1 + scale`` (the tyre's radius error, and each side's half of the
  left/right difference) plus the step's random part;
* ``slip_noise``: the paper's random part (uniform wheel slip, a fraction of the distance);
  a population car's is a random walk (``CarSensors``: Gaussian, variance per metre);
* ``quantise``: whole counts of an ABS ring (the distance reported is whole counts);
* ``compass_reading``: the true heading plus the compass's error at that heading (its
  mounting offset, hard-iron curve and drift) plus white noise.

The compiled world (``hal_sim.world._encoder`` and its compass, inlined in the study engine's
step and in ``world_step``, which ``SimDrive`` and ``guided`` step) computes the paper's car
with these functions; ``CarSensors`` computes a population car's (``hal_sim.population``:
scale, left/right difference, road camber, turn scale, wheel walk, compass offset, hard iron,
drift, noise) with the same functions, called from Python.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from numba import njit

from guidance.core.model import wrap_angle

SQRT12 = math.sqrt(12.0)
"""A uniform draw in [-0.5, 0.5) times this has unit variance."""


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def wheel_travel(d_true: float, scale: float, noise: float) -> float:
    """One wheel's travel as its sensor counts it: ``d_true (1 + scale) + noise``."""
    return d_true * (1.0 + scale) + noise


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def slip_noise(u: float, slip_frac: float, d_true: float) -> float:
    """The paper's slip over a step: uniform (from the uniform draw ``u`` in [0, 1)) with a
    standard deviation of ``slip_frac`` of the distance. A uniform draw costs a fifth of a
    normal one; over the hundreds of steps of a block the sum is Gaussian anyway, and the
    filter models only the variance."""
    return (u - 0.5) * SQRT12 * slip_frac * abs(d_true)


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def quantise(travelled: float, counted: float, inv_q: float, q: float) -> tuple[float, float]:
    """Whole counts of a ring of quantum ``q`` (``inv_q`` = 1 / q, a product where a division
    would hold up the world step's chain): (the count now, the distance of the counts since
    ``counted``). The count is a float: no round trip through an integer."""
    count = np.floor(travelled * inv_q)
    return count, (count - counted) * q


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def compass_reading(heading: float, error_rad: float, gauss: float, sigma: float) -> float:
    """A compass reading at the true ``heading``: plus its error there (offset, hard-iron
    curve, drift; 0 for the paper's compass) plus ``gauss`` (a standard normal draw) times
    its noise ``sigma``, wrapped to (-pi, pi]."""
    return wrap_angle((heading + error_rad) + gauss * sigma)


def hard_iron_rad(ratio: float, direction_rad: float, heading_rad: float) -> float:
    """The heading-dependent deviation of a car field ``ratio`` times the earth's horizontal
    field pointing ``direction_rad`` from the car's axis: atan2(r sin(h - phi), 1 + r cos(h -
    phi))."""
    r, phi = ratio, direction_rad
    return math.atan2(r * math.sin(heading_rad - phi), 1.0 + r * math.cos(heading_rad - phi))


class SensorErrors(Protocol):
    """What ``CarSensors`` reads of a car's persistent errors (``population.CarErrors``)."""

    @property
    def scale(self) -> float: ...
    @property
    def diff(self) -> float: ...
    @property
    def walk_m2_per_m(self) -> float: ...
    @property
    def compass_drift_deg2_per_s(self) -> float: ...
    @property
    def compass_noise_deg(self) -> float: ...
    @property
    def diff_walk_var_per_m(self) -> float: ...
    @property
    def turn_scale(self) -> float: ...
    @property
    def camber_sigma(self) -> float: ...
    @property
    def camber_length_m(self) -> float: ...

    def deviation_rad(self, heading_rad: float) -> float: ...


class CarSensors:
    """One population car's wheel sensors and compass, from its true motion step by step.

    Draws, in order, from ``rng`` (shared with the caller's other draws: the random route's
    exits): per wheel step the left/right difference's walk (when it walks), then each
    wheel's walk; per compass reading the bias drift, then the noise. The road camber draws
    from ``camber_rng``, a stream of its own (so the cars' other draws stay the same with
    and without it)."""

    def __init__(
        self,
        errors: SensorErrors,
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
