"""Parameters each car learns and keeps (pure): the car model's persistent states across drives.

The car model estimates the wheel-speed scale ``k``, the left/right difference ``kd``, the
compass bias ``b`` and the turn scale ``kt`` as it drives (landmark fixes teach ``k`` along the
road; the compass and the turns teach ``b``, ``kd`` and ``kt``).
``LearnedParams.from_estimator`` takes them with their variances at the end of a drive; the
next drive starts from them (``apply``), their uncertainty widened with the time since
(``widened``): tyre pressure and wear move the scale and the difference between drives, and
whatever moved in the car moves the compass bias at the filter's own drift rate. Nothing is
ever more certain than it was measured, and nothing wider than the uncalibrated prior. A value
outside physical bounds (``guidance.core.localize.state_limits``, the ranges a checkpoint's
states are held to as well) is refused (``from_dict`` raises ``ValueError`` naming it), as openpilot
refuses a learned-parameter file that fails its sanity checks. The file itself (atomic,
versioned) is ``guidance.app.learned_file``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from guidance.core import model
from guidance.core.localize import compass_mount, gyro
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.localize.state_limits import (
    MAX_ABS_BIAS_DEG,
    MAX_ABS_DIFF,
    MAX_ABS_GYRO_BIAS_DEG_S,
    MAX_ABS_GYRO_SCALE,
    MAX_ABS_SCALE,
    MAX_ABS_TURN,
    MAX_BIAS_SIGMA_DEG,
    MAX_DIFF_SIGMA,
    MAX_GYRO_BIAS_SIGMA_DEG_S,
    MAX_GYRO_SCALE_SIGMA,
    MAX_SCALE_SIGMA,
    MAX_TURN_SIGMA,
    MIN_BIAS_SIGMA_DEG,
    MIN_DIFF_SIGMA,
    MIN_GYRO_BIAS_SIGMA_DEG_S,
    MIN_GYRO_SCALE_SIGMA,
    MIN_SCALE_SIGMA,
    MIN_TURN_SIGMA,
)

SCHEMA = "guidance.learned/4"
"""Version 2 adds the turn scale (``turn_scale``, ``turn_scale_sigma``, optional); version 1
files (without it) are read as they were, the turn scale then starting from its prior.
Version 3 adds a gyro car's gyro bias and scale (``gyro_*``, optional); version 4 the last
drives' compass end offsets (``compass_drives``, ``compass_mount``)."""
READ_SCHEMAS = ("guidance.learned/1", "guidance.learned/2", "guidance.learned/3", SCHEMA)
SCALE_VAR_PER_DAY = (0.001**2) / 30.0
"""Between drives the scale's variance grows by (0.1 %)^2 a month: tyres lose about 0.1 bar of
pressure a month and wear about 0.05 % of their rolling radius (2.2 % over a tyre's life)."""
DIFF_VAR_PER_DAY = (0.0001**2) / 30.0
"""The left/right difference's by (0.01 %)^2 a month (a pressure difference of ~0.05 bar)."""
TURN_VAR_PER_DAY = (0.001**2) / 30.0
"""The turn scale's by (0.1 %)^2 a month (tyre wear changes the contact patches; a gyro's
sensitivity ages)."""


@dataclass(frozen=True, slots=True)
class LearnedParams:
    """One car's learned persistent errors and their 1-sigma uncertainty."""

    vehicle_id: str
    saved_unix_s: float
    """When they were taken, on the drive's own clock (Unix seconds on a real car)."""
    distance_m: float
    """Distance driven on the drives that taught them."""
    scale: float
    scale_sigma: float
    diff: float
    diff_sigma: float
    compass_bias_deg: float | None = None
    compass_bias_sigma_deg: float | None = None
    turn_scale: float | None = None
    turn_scale_sigma: float | None = None
    """None in a version-1 file (learned before the turn scale was a state)."""
    gyro_bias_deg_s: float | None = None
    gyro_bias_sigma_deg_s: float | None = None
    gyro_scale: float | None = None
    gyro_scale_sigma: float | None = None
    """None for a car whose wheels turn its heading (``[vehicle] yaw_source = "wheels"``)."""
    compass_drives: tuple[tuple[float, float], ...] = ()
    """The compass offset (deg) and its 1-sigma at the end of each of the last drives
    (``compass_mount``: a compass whose offset keeps moving between drives is flagged)."""

    @classmethod
    def from_estimator(
        cls,
        est: PoseEstimator,
        vehicle_id: str,
        now_unix_s: float,
        distance_m: float,
        before: LearnedParams | None = None,
    ) -> LearnedParams | None:
        """The car model's states now (None for the paper model, which has none); the
        distance adds to that of ``before``, the drive's own starting values."""
        if est.n <= model.N_STATE:
            return None
        x, P = est.x, est.P

        def sd(i: int, floor: float) -> float:  # never below what a drive can know
            return max(floor, math.sqrt(max(0.0, float(P[i, i]))))

        bias = est.config.compass_two_sigma_deg is not None
        b_deg = math.degrees(float(x[model.STATE_BIAS]))
        b_sd = max(MIN_BIAS_SIGMA_DEG, math.degrees(sd(model.STATE_BIAS, 0.0)))
        earlier = before.compass_drives if before is not None else ()
        drives = compass_mount.with_drive(earlier, b_deg, b_sd) if bias else earlier
        return cls(
            vehicle_id=vehicle_id,
            saved_unix_s=float(now_unix_s),
            distance_m=float(distance_m) + (before.distance_m if before is not None else 0.0),
            scale=float(x[model.STATE_SCALE]),
            scale_sigma=sd(model.STATE_SCALE, MIN_SCALE_SIGMA),
            diff=float(x[model.STATE_DIFF]),
            diff_sigma=sd(model.STATE_DIFF, MIN_DIFF_SIGMA),
            compass_bias_deg=b_deg if bias else None,
            compass_bias_sigma_deg=b_sd if bias else None,
            compass_drives=drives,
            turn_scale=float(x[model.STATE_TURN]),
            turn_scale_sigma=sd(model.STATE_TURN, MIN_TURN_SIGMA),
            **(_gyro_learned(x, sd) if est.n >= gyro.N_STATE_GYRO else {}),
        )

    def widened(self, now_unix_s: float, config: EstimatorConfig) -> LearnedParams:
        """The uncertainty after the time since they were taken, never wider than ``config``'s
        own (uncalibrated) priors."""
        days = max(0.0, now_unix_s - self.saved_unix_s) / 86400.0
        scale = math.sqrt(self.scale_sigma**2 + SCALE_VAR_PER_DAY * days)
        diff = math.sqrt(self.diff_sigma**2 + DIFF_VAR_PER_DAY * days)
        bias = self.compass_bias_sigma_deg
        if bias is not None:
            walk = config.compass_bias_walk_deg2_per_s * days * 86400.0
            bias = min(math.sqrt(bias**2 + walk), config.compass_bias_sigma_deg or math.inf)
        turn = self.turn_scale_sigma
        if turn is not None:
            turn = min(math.sqrt(turn**2 + TURN_VAR_PER_DAY * days),
                       config.turn_scale_sigma or math.inf)  # fmt: skip
        gb, gs = self.gyro_bias_sigma_deg_s, self.gyro_scale_sigma
        if gb is not None and gs is not None and config.gyro is not None:
            # the bias walks at the filter's own rate (and restarts at each turn-on): within a
            # day it is back at its prior; the sensitivity ages as the turn scale does
            gb = min(math.sqrt(gb**2 + config.gyro.bias_walk_deg2_per_s3 * days * 86400.0),
                     config.gyro.bias_sigma_deg_s)  # fmt: skip
            gs = min(math.sqrt(gs**2 + TURN_VAR_PER_DAY * days), config.gyro.scale_sigma)
        return replace(
            self,
            scale_sigma=min(scale, config.scale_sigma or math.inf),
            diff_sigma=min(diff, config.diff_sigma or math.inf),
            compass_bias_sigma_deg=bias,
            turn_scale_sigma=turn,
            gyro_bias_sigma_deg_s=gb,
            gyro_scale_sigma=gs,
        )

    def apply(self, est: PoseEstimator) -> None:
        """Start ``est`` (a car model's fresh filter) from these values: each state's mean and
        variance, its correlations with the others cleared."""
        if est.n <= model.N_STATE:
            return
        states = [(model.STATE_SCALE, self.scale, self.scale_sigma),
                  (model.STATE_DIFF, self.diff, self.diff_sigma)]  # fmt: skip
        if (
            est.config.compass_two_sigma_deg is not None
            and self.compass_bias_deg is not None
            and self.compass_bias_sigma_deg is not None
        ):
            states.append((model.STATE_BIAS, math.radians(self.compass_bias_deg),
                           math.radians(self.compass_bias_sigma_deg)))  # fmt: skip
        if self.turn_scale is not None and self.turn_scale_sigma is not None:
            states.append((model.STATE_TURN, self.turn_scale, self.turn_scale_sigma))
        g = (self.gyro_bias_deg_s, self.gyro_bias_sigma_deg_s, self.gyro_scale,
             self.gyro_scale_sigma)  # fmt: skip
        if est.n >= gyro.N_STATE_GYRO and g[0] is not None and g[1] is not None:
            states.append((gyro.STATE_GYRO_BIAS, math.radians(g[0]), math.radians(g[1])))
        if est.n >= gyro.N_STATE_GYRO and g[2] is not None and g[3] is not None:
            states.append((gyro.STATE_GYRO_SCALE, g[2], g[3]))
        est.adopt(states)

    def to_dict(self) -> dict[str, object]:
        out = {"schema": SCHEMA, **asdict(self)}
        out["compass_drives"] = [list(pair) for pair in self.compass_drives]  # JSON's lists
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> LearnedParams:
        """Read back with every value checked (``ValueError`` naming the first bad one)."""
        if data.get("schema") not in READ_SCHEMAS:
            raise ValueError(f"schema is {data.get('schema')!r}, not one of {READ_SCHEMAS}")
        unknown = set(data) - {"schema", *(f.name for f in fields(cls))}
        if unknown:
            raise ValueError(f"unknown fields: {', '.join(sorted(unknown))}")
        vid = data.get("vehicle_id")
        if not isinstance(vid, str) or not 0 < len(vid) <= 64:
            raise ValueError("vehicle_id must be a text of 1-64 characters")

        def num(key: str, lo: float, hi: float) -> float:
            v = data.get(key)
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"{key} must be a finite number, not {str(v)[:40]!r}")
            try:
                f = float(v)  # an integer of 400 digits does not fit: OverflowError
            except OverflowError:
                raise ValueError(f"{key} is a number too large for a float") from None
            if not math.isfinite(f):
                raise ValueError(f"{key} must be a finite number, not {v!r}")
            if not lo <= f <= hi:
                raise ValueError(f"{key} = {v} is outside [{lo:g}, {hi:g}]")
            return f

        bias = bias_sigma = None
        if (
            data.get("compass_bias_deg") is not None
            or data.get("compass_bias_sigma_deg") is not None
        ):
            bias = num("compass_bias_deg", -MAX_ABS_BIAS_DEG, MAX_ABS_BIAS_DEG)
            bias_sigma = num("compass_bias_sigma_deg", MIN_BIAS_SIGMA_DEG, MAX_BIAS_SIGMA_DEG)
        turn = turn_sigma = None
        if data.get("turn_scale") is not None or data.get("turn_scale_sigma") is not None:
            turn = num("turn_scale", -MAX_ABS_TURN, MAX_ABS_TURN)
            turn_sigma = num("turn_scale_sigma", MIN_TURN_SIGMA, MAX_TURN_SIGMA)
        gyro_fields: dict[str, float] = {}
        if any(data.get(k) is not None for k in _GYRO_LIMITS):
            gyro_fields = {k: num(k, lo, hi) for k, (lo, hi) in _GYRO_LIMITS.items()}
        return cls(
            vehicle_id=vid,
            compass_drives=_compass_drives(data.get("compass_drives", [])),
            saved_unix_s=num("saved_unix_s", 0.0, 1e11),
            distance_m=num("distance_m", 0.0, 1e9),
            scale=num("scale", -MAX_ABS_SCALE, MAX_ABS_SCALE),
            scale_sigma=num("scale_sigma", MIN_SCALE_SIGMA, MAX_SCALE_SIGMA),
            diff=num("diff", -MAX_ABS_DIFF, MAX_ABS_DIFF),
            diff_sigma=num("diff_sigma", MIN_DIFF_SIGMA, MAX_DIFF_SIGMA),
            compass_bias_deg=bias,
            compass_bias_sigma_deg=bias_sigma,
            turn_scale=turn,
            turn_scale_sigma=turn_sigma,
            **gyro_fields,
        )


_GYRO_LIMITS = {
    "gyro_bias_deg_s": (-MAX_ABS_GYRO_BIAS_DEG_S, MAX_ABS_GYRO_BIAS_DEG_S),
    "gyro_bias_sigma_deg_s": (MIN_GYRO_BIAS_SIGMA_DEG_S, MAX_GYRO_BIAS_SIGMA_DEG_S),
    "gyro_scale": (-MAX_ABS_GYRO_SCALE, MAX_ABS_GYRO_SCALE),
    "gyro_scale_sigma": (MIN_GYRO_SCALE_SIGMA, MAX_GYRO_SCALE_SIGMA),
}
"""A gyro car's learned fields and their bounds (``state_limits``): all four or none."""


def _gyro_learned(x: np.ndarray, sd: Callable[[int, float], float]) -> dict[str, float]:
    """A gyro car's bias (deg/s) and scale with their 1-sigma, never below what a drive knows."""
    return {
        "gyro_bias_deg_s": math.degrees(float(x[gyro.STATE_GYRO_BIAS])),
        "gyro_bias_sigma_deg_s": max(MIN_GYRO_BIAS_SIGMA_DEG_S,
                                     math.degrees(sd(gyro.STATE_GYRO_BIAS, 0.0))),
        "gyro_scale": float(x[gyro.STATE_GYRO_SCALE]),
        "gyro_scale_sigma": sd(gyro.STATE_GYRO_SCALE, MIN_GYRO_SCALE_SIGMA),
    }  # fmt: skip


def _compass_drives(value: object) -> tuple[tuple[float, float], ...]:
    """``compass_drives`` read back: at most ``compass_mount.KEPT`` pairs (offset within
    +-180 deg, sigma within the bias's bounds), or ``ValueError``."""
    if not isinstance(value, list | tuple) or len(value) > compass_mount.KEPT:
        raise ValueError(f"compass_drives must be a list of at most {compass_mount.KEPT} pairs")
    out = []
    for pair in value:
        if not (isinstance(pair, list | tuple) and len(pair) == 2
                and all(isinstance(v, int | float) and not isinstance(v, bool) for v in pair)):
            raise ValueError("compass_drives must hold [offset_deg, sigma_deg] pairs")
        b, s = float(pair[0]), float(pair[1])
        if not (abs(b) <= MAX_ABS_BIAS_DEG and MIN_BIAS_SIGMA_DEG <= s <= MAX_BIAS_SIGMA_DEG):
            raise ValueError(f"compass_drives pair {pair} is outside its bounds")
        out.append((b, s))
    return tuple(out)
