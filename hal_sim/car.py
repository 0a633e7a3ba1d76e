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
with these functions; ``hal_sim.car_errors.CarSensors`` computes a population car's (its
``CarErrors``: scale, left/right difference, road camber, turn scale, wheel walk, compass
offset, hard iron, drift, noise) with the same functions, called from Python.
``hard_iron_rad`` is the compass deviation a car field gives (Python: the population's
compass curve).
"""

from __future__ import annotations

import math

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
