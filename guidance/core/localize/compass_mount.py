"""A compass mounted at any angle (issue 38, item 4): the mounting angle is a setting
(``[compass] mounting_offset_deg``, applied at the input edge) and a learned state (the car
model's compass bias ``b``: whatever the setting leaves, mounting and deviation together,
learned on every drive and kept in the learned file with its 1-sigma). A compass is mounted
once: its offset is one number for the car, so the offsets its drives end with must agree
within their uncertainties. A compass whose offset keeps moving between drives (a loose
bracket, a phone holder, a magnetised part nearby) is flagged.

The test: the last ``KEPT`` drives' end offsets ``b_i +- s_i`` (each drive's own filter
sigma at its end, which already holds the bias's drift within the drive) against their
weighted mean, ``chi2 = sum ((b_i - m) / s_i)^2`` with ``N - 1`` degrees of freedom, flagged
beyond P = 0.999 (one false flag in a thousand honest cars). Consecutive drives are
correlated (each starts from the last one's value), which makes them agree *more*; a
flag is therefore conservative."""

from __future__ import annotations

import math
from collections.abc import Sequence

from guidance.core import model

KEPT = 5
"""End offsets kept in the learned file (the last five drives)."""
CHI2_P999 = (10.83, 13.82, 16.27, 18.47)
"""chi-square quantiles at P = 0.999 for 1-4 degrees of freedom."""


def with_drive(
    drives: Sequence[tuple[float, float]], offset_deg: float, sigma_deg: float
) -> tuple[tuple[float, float], ...]:
    """``drives`` with this drive's end offset and sigma (deg) added, the last ``KEPT``."""
    out = (*((float(a), float(b)) for a, b in drives), (float(offset_deg), float(sigma_deg)))
    return out[-KEPT:]


def moving(drives: Sequence[tuple[float, float]]) -> tuple[float, float] | None:
    """(chi2, its P = 0.999 limit) when the end offsets disagree beyond their uncertainty
    (module doc), else None. Angles are compared wrapped around the first one."""
    if len(drives) < 2:
        return None
    ref = drives[0][0]
    vals = [ref + math.degrees(model.wrap_angle(math.radians(b - ref))) for b, _ in drives]
    w = [1.0 / (s * s) for _, s in drives]
    m = sum(wi * v for wi, v in zip(w, vals, strict=True)) / sum(w)
    chi2 = sum(wi * (v - m) ** 2 for wi, v in zip(w, vals, strict=True))
    limit = CHI2_P999[min(len(drives) - 1, len(CHI2_P999)) - 1]
    return (chi2, limit) if chi2 > limit else None


def warning(drives: Sequence[tuple[float, float]]) -> str:
    """One line saying the compass offset moves between drives, or ""."""
    flagged = moving(drives)
    if flagged is None:
        return ""
    seen = ", ".join(f"{b:+.1f} +- {s:.1f}" for b, s in drives)
    return (
        f"COMPASS OFFSET MOVES BETWEEN DRIVES: the last {len(drives)} drives ended at {seen} "
        f"deg (chi2 {flagged[0]:.1f} > {flagged[1]:.1f}, P = 0.999): a compass is mounted "
        "once, so its mount or the field around it changed; check the mount, then calibrate "
        "again"
    )
