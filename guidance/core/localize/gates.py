"""The filter's gates (before filterpy's ``update``): whether an input may move the estimate,
and if not, why (the reason it is counted under).

Each input is first held to what it can physically be (finite; a wheel step, a landmark's
sigma and position within bounds: beyond them it is a damaged record, never a measurement),
then a measurement to its innovation's chi-square gate, the compass also to the interference
judge (``Interference``). Pure but for that judge's level: the estimator applies what passes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guidance.core import model
from guidance.core.localize.estimator_config import EstimatorConfig
from guidance.core.messages import LandmarkFix, WheelOdometry
from guidance.core.stages import LOST_HYSTERESIS, RELOCALISED

MIN_LANDMARK_SIGMA_M = 0.01
MAX_LANDMARK_SIGMA_M = 1000.0
"""A landmark fix claims its position to between a centimetre and a kilometre (1 sigma);
outside that it is a damaged record (1e200 squared overflows), not a measurement."""
MAX_COORDINATE_M = 1.0e7
"""Local metres: a quarter of the Earth's circumference from the start is not a city."""


@dataclass(frozen=True, slots=True)
class Verdict:
    """A measurement's gate: ``reason`` why it is refused (None: update the filter with it;
    ``RELOCALISED``: restart the position there), its d^2 and its variance (per axis)."""

    reason: str | None
    d2: float | None = None
    var: float = 0.0


class Interference:
    """Whether the compass's field is disturbed: an exponentially weighted level of its
    readings' NIS (modelled value 1), with hysteresis (``model.interference_update``, shared
    with the study engine). Readings are rejected while it is on.

    Inflating their variance instead was tried: the heading still converges to the biased
    field over a block (docs/reliability.md has the comparison)."""

    __slots__ = ("level", "on")

    def __init__(self) -> None:
        self.level = 1.0
        self.on = False

    def judge(self, d2: float, cfg: EstimatorConfig) -> bool:
        """Take one reading's d^2; True while the field is judged disturbed."""
        self.level, self.on = model.interference_update(
            self.level, self.on, d2, cfg.interference_alpha, cfg.interference_on_nis,
            cfg.interference_off_nis)  # fmt: skip
        return self.on


def odometry_refusal(cfg: EstimatorConfig, msg: WheelOdometry) -> str | None:
    """Why a wheel increment is not used (not finite; larger than ``max_wheel_step_m``)."""
    dl, dr = msg.d_left_m, msg.d_right_m
    if not (math.isfinite(dl) and math.isfinite(dr)):
        return "non_finite_input"
    if abs(dl) > cfg.max_wheel_step_m or abs(dr) > cfg.max_wheel_step_m:
        return "implausible_odometry"
    return None


def heading_verdict(
    cfg: EstimatorConfig, x: np.ndarray, P: np.ndarray, theta_rad: float, judge: Interference
) -> Verdict:
    """A heading fix against the state: no compass fitted, not finite, the field disturbed
    (``cfg.interference_detection``), outside the gate (1 dof), or used."""
    if cfg.compass_two_sigma_deg is None:
        return Verdict("no_compass_configured")
    if not math.isfinite(theta_rad):
        return Verdict("non_finite_input")
    var = model.two_sigma_deg_to_var(cfg.compass_two_sigma_deg)
    y, S = model.heading_innovation(x, P, theta_rad, var)
    d2 = y * y / S
    if cfg.interference_detection and judge.judge(d2, cfg):
        return Verdict("magnetic_interference", d2, var)
    if d2 > cfg.compass_gate_chi2:
        return Verdict("compass_gate", d2, var)
    return Verdict(None, d2, var)


def landmark_verdict(
    cfg: EstimatorConfig, x: np.ndarray, P: np.ndarray, msg: LandmarkFix
) -> Verdict:
    """A landmark fix against the state: not finite, implausible (sigma, position), a
    whole-database find while lost (``RELOCALISED``: the position restarts there, whatever
    its d^2), outside the gate (2 dof), or used."""
    if not (math.isfinite(msg.x_m) and math.isfinite(msg.y_m)
            and math.isfinite(msg.sigma_m) and msg.sigma_m > 0.0):  # fmt: skip
        return Verdict("non_finite_input")
    if not (
        MIN_LANDMARK_SIGMA_M <= msg.sigma_m <= MAX_LANDMARK_SIGMA_M
        and max(abs(msg.x_m), abs(msg.y_m)) <= MAX_COORDINATE_M
    ):
        return Verdict("implausible_landmark")
    var = msg.sigma_m**2
    y0, y1, s00, s01, s11 = model.position_innovation(x, P, msg.x_m, msg.y_m, var)
    d2 = model.mahalanobis_sq_2d(y0, y1, s00, s01, s11)
    lost_by = LOST_HYSTERESIS * cfg.lost_major_axis_m
    if msg.relocalised and float(model.major_axis_m(P)) > lost_by:
        return Verdict(RELOCALISED, d2, var)
    if d2 > cfg.landmark_gate_chi2:
        return Verdict("landmark_gate", d2, var)
    return Verdict(None, d2, var)
