"""What a valid estimator state is: one definition (issue 23, items 6 and 13).

Used where a state comes from outside the filter: a checkpoint (``snapshot_check``), the car's
learned-parameter file (``guidance.core.localize.learned``), and by the estimator itself
(``PoseEstimator.state_problem``), so the three can never disagree.

* **The car model's persistent states** have a physical range: the wheel-speed scale error
  ``k`` and the left/right difference ``kd`` are fractions a tyre or a DBC can plausibly be
  off by, the compass bias an angle. A scale of 1e6 (100 m read as 100,000 km) or -1 (the
  estimate frozen) is a damaged file, never a state. Their 1-sigma is bounded the same way.
* **The covariance** must be symmetric and positive-definite, except that a state whose prior
  variance is zero by design (the compass bias of a car without a compass, before the first
  odometry input gives it its random walk) may have a zero variance, with a zero row and
  column: that is the filter's own state, not a fault.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from guidance.core import model
from guidance.core.localize import gyro

MAX_ABS_SCALE = 0.10
"""Wheel-speed scale error, a fraction: beyond 10 % the DBC or the tyre size is wrong."""
MAX_ABS_DIFF = 0.005
"""Right-minus-left wheel scale difference: 0.5 % is a flat tyre."""
MAX_ABS_BIAS_DEG = 180.0
"""Compass bias: any angle, but an angle (the filter does not wrap it)."""
MAX_ABS_TURN = 0.25
"""Turn scale error: a track a quarter off is the wrong vehicle profile, not a tyre."""
MAX_SCALE_SIGMA = 1.0
MAX_DIFF_SIGMA = 0.1
MAX_BIAS_SIGMA_DEG = 180.0
MAX_TURN_SIGMA = 1.0
"""1-sigma bounds of the four (wider than any prior: a sigma beyond them is no knowledge)."""

MIN_SCALE_SIGMA = 1e-4
"""The smallest 1-sigma a learned wheel scale may claim (issue 40, defect 3): what the longest
drive can teach. The scale is learned from how far the car went between two places it knows:
a surveyed 10 km stretch, with the car's own position known to 1 m at either end (it is a
4.5 m object; no landmark fix or map pin is better), teaches it to 1 m / 10 km = 1e-4; and the
quantity itself moves by more within one drive (a tyre warming up gains about 0.2 bar, about
0.1-0.2 % of its rolling radius). A file claiming 1e-6 (100 m known to 0.1 mm) is not a drive's
knowledge: it is refused, and the car never saves less than this."""
MIN_DIFF_SIGMA = 1e-5
"""The left/right difference's: the two rolling radii differ with the two tyres' pressures; a
tyre gauge resolves 0.05-0.1 bar, about 0.05-0.1 % of the radius, and the pressures of two
tyres, one in the sun, drift apart by more in a drive: a tenth of a gauge's step, 1e-5
(0.001 %), is below anything a drive's heading can tell (drives reach 1-2e-4)."""
MIN_BIAS_SIGMA_DEG = 0.1
"""The compass bias's, degrees: the compasses a car carries resolve 0.1 degrees and repeat to
0.5-1 degree, and the car's own field moves with its electrical loads; no drive knows the bias
closer than the instrument's resolution."""
MIN_TURN_SIGMA = 1e-4
"""The turn scale's: learned from the heading a compass sees after a turn; 10,000 right-angle
turns (weeks of town driving) against a 1-degree compass teach it to 1 / (90 x 100) = 1.1e-4."""
FUTURE_TOLERANCE_S = 86400.0
"""A learned file saved later than this after the reader's clock is refused (defect 3): its
age, which widens it, would be taken as zero for ever. A clock set by hand or off by a time
zone is within a day, and a day's widening is (0.1 %)^2 / 30 of variance: nothing lost."""

MAX_ABS_GYRO_BIAS_DEG_S = 5.0
"""A gyro's bias: the ESC sensor sheets' worst offset over life and temperature is 3.75 deg/s;
beyond 5 deg/s the signal or its unit is wrong, not the sensor."""
MAX_GYRO_BIAS_SIGMA_DEG_S = 10.0
MAX_ABS_GYRO_SCALE = 0.25
"""A gyro's scale error: a quarter off is a wrong DBC factor or unit, not a sensor's
sensitivity (+-1-3 %)."""
MAX_GYRO_SCALE_SIGMA = 1.0
MIN_GYRO_BIAS_SIGMA_DEG_S = 0.001
"""The smallest 1-sigma a learned gyro bias may claim: the sensor's own in-run instability
(1.6-10 deg/h, 0.0005-0.003 deg/s) moves it by that much while the car drives."""
MIN_GYRO_SCALE_SIGMA = 1e-4
"""A gyro's scale, like the turn scale: 10,000 right-angle turns against a 1-degree reference."""

LEARNED_STATES: tuple[tuple[int, str, float, float], ...] = (
    (model.STATE_SCALE, "wheel scale", MAX_ABS_SCALE, MAX_SCALE_SIGMA),
    (model.STATE_DIFF, "left/right difference", MAX_ABS_DIFF, MAX_DIFF_SIGMA),
    (model.STATE_BIAS, "compass bias (rad)", math.radians(MAX_ABS_BIAS_DEG),
     math.radians(MAX_BIAS_SIGMA_DEG)),
    (model.STATE_TURN, "turn scale", MAX_ABS_TURN, MAX_TURN_SIGMA),
    (gyro.STATE_GYRO_BIAS, "gyro bias (rad/s)", math.radians(MAX_ABS_GYRO_BIAS_DEG_S),
     math.radians(MAX_GYRO_BIAS_SIGMA_DEG_S)),
    (gyro.STATE_GYRO_SCALE, "gyro scale", MAX_ABS_GYRO_SCALE, MAX_GYRO_SCALE_SIGMA),
)  # fmt: skip
"""(state index, name, largest magnitude, largest 1-sigma) of the car model's learned states,
in the filter's units."""


def learned_state_problem(x: Sequence[float], P: np.ndarray) -> str | None:
    """Why the learned states of a car-model state ``x`` (with covariance ``P``) are outside
    their physical range, or None (also for a pose-only state, which has none)."""
    if len(x) <= model.N_STATE:
        return None
    for i, name, max_abs, max_sigma in LEARNED_STATES:
        if i >= len(x):  # a car without a gyro: the last two are not its states
            break
        if not abs(float(x[i])) <= max_abs:
            return f"x[{i}] ({name}) = {float(x[i]):.6g} is outside +-{max_abs:.6g}"
        var = float(P[i, i])
        if var > max_sigma * max_sigma:
            return f"P[{i}][{i}] ({name}): a 1-sigma of {math.sqrt(var):.6g}, above {max_sigma:.6g}"
    return None


def covariance_problem(P: np.ndarray, prior_variances: Sequence[float] | None = None) -> str | None:
    """Why ``P`` is no covariance of this filter, or None. ``prior_variances``: the filter's
    starting variances (``PoseEstimator.prior_covariance``); a state whose prior is zero may
    have a zero variance (with a zero row and column). None: every state must be uncertain."""
    n = P.shape[0]
    if P.shape != (n, n) or not np.all(np.isfinite(P)):
        return "P is not a finite square matrix"
    if not np.allclose(P, P.T, rtol=1e-6, atol=1e-9):
        return "P is not symmetric"
    diag = np.diag(P)
    fixed = np.zeros(n, dtype=bool)
    if prior_variances is not None:
        prior = np.asarray(prior_variances, dtype=float)[:n]
        fixed[: prior.size] = prior == 0.0
    zero = fixed & (diag == 0.0)
    if np.any(zero):
        rows = P[zero]
        if np.any(rows != 0.0):
            i = int(np.flatnonzero(zero)[0])
            return f"P: state {i} has no variance but is correlated with others"
    free = ~zero
    try:
        np.linalg.cholesky(P[np.ix_(free, free)])
    except np.linalg.LinAlgError:
        return "P is not positive-definite"
    return None


def state_problem(
    x: Sequence[float], P: np.ndarray, prior_variances: Sequence[float] | None = None
) -> str | None:
    """Why ``(x, P)`` is not a valid state, or None: the covariance, then the learned states'
    ranges (see the module docstring). ``x`` is assumed finite (checked by the caller)."""
    return covariance_problem(P, prior_variances) or learned_state_problem(x, P)
