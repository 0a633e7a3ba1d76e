"""Compass deviation calibration ("swinging the compass"): the deviation card and its fit.

Sign convention, in magnetic degrees clockwise from magnetic north::

    corrected = reading + deviation(reading)
    deviation(h) = A + B sin h + C cos h + D sin 2h + E cos 2h      (h = the compass reading)

The card takes the reading as its argument, as a ship's deviation card is used. A holds the
mounting offset; B, C the car's permanent (hard-iron) field; D, E its induced (soft-iron) field.
True heading = corrected + declination (east positive).

Procedure: stop with a known true heading, drive two slow circles in a car park (< ~500 m),
one each way (a compass lagging the turn biases A by lag x turn rate, opposite circles cancel);
:func:`reference_headings_from_odometry` carries the start heading through the drive by wheel
odometry and :func:`calibrate_from_drive` fits the card to the compass readings taken meanwhile.
The odometry reference drifts: a relative tyre radius difference δ turns it by δ·d/track radians
over d metres (0.05 % on a 1.62 m track: 0.18° per 10 m, 1.8° per 100 m, 18° per km), and a
track width error ε scales every turn (two circles, ε = 1 %: 7°). Keep the drive short; either
error shows as a step in the residuals between the first and the second circle.

Pure code: numpy only, no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from guidance.core.messages import CompassHeading
from guidance.core.model import compass_to_heading

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
Terms = Literal["offset only", "offset + 2 harmonics"]

MIN_READINGS: Final = 20
"""Fewest readings for any fit: 4x the 5 unknowns, and enough for a median-based noise scale."""
MAX_HARMONIC_DEG: Final = 45.0
"""Largest B..E accepted. A 45° first-harmonic term means the car's own field is already about
0.7 (sin 45°) of the earth's horizontal field at the compass; a 2h term above 28.6° (or B, C, D, E
together) makes the card fold back on itself, which :func:`_problem` checks separately. Such a
compass needs moving away from the iron, not a card."""
MIN_COVERAGE_DEG: Final = 240.0
"""Heading span (360° minus the largest gap) needed to fit B..E. Readings spread evenly over a
span S amplify the worst-case coefficient noise, against a full turn, by 4.1x at 240°, 15x at
180° and 83x at 120° (smallest eigenvalue of the normalised 5-column design matrix), and the
2h terms (period 180°) need more than half a turn to be told from the offset and the 1h terms."""
SECTOR_DEG: Final = 30.0
"""Occupied 30° sectors (of 12) are needed as well: ceil(min coverage / 30), the fewest a filled
arc of that span occupies (8 at 240°). Stops a few isolated readings from passing as coverage
(four readings 90° apart leave no gap over 120°)."""
POOR_FIT_RMS_DEG: Final = 5.0
"""Residual rms above which the result says the card explains the readings poorly: twice the
2.4° noise of a real in-car magnetometer (comma2k19 RAV4)."""
MIN_SPEED_MPS: Final = 1.0
"""Readings below this odometry speed are dropped. A car cannot turn in place, so a standing car
adds the same heading again and again (weighting it over the rest of the circle), and at walking
pace the wheel-speed quantisation dominates the left/right difference the reference comes from."""
MAX_DRIVE_M: Final = 1000.0
"""Drive length above which the result carries a drift warning (18° at 0.05 % tyre mismatch)."""
SCALE_FLOOR_DEG: Final = 0.5
"""Floor of the robust noise scale: below half a degree a cheap compass's noise is not resolved,
and without a floor a noise-free fit would call every rounding error an outlier."""
HUBER_K: Final = 1.345  # 95 % efficiency on Gaussian noise
TUKEY_C: Final = 4.685  # 95 % efficiency; residuals beyond c * scale get zero weight: outliers
_IRLS_ITER: Final = 10
_NAMES: Final = ("a_deg", "b_deg", "c_deg", "d_deg", "e_deg")


def _wrap180(a: FloatArray) -> FloatArray:
    """Degrees to [-180, 180)."""
    return np.asarray(np.mod(a + 180.0, 360.0) - 180.0, dtype=np.float64)


def _circular_mean_deg(a: FloatArray) -> float:
    r = np.radians(a)
    return math.degrees(math.atan2(float(np.mean(np.sin(r))), float(np.mean(np.cos(r)))))


def _design(h_deg: FloatArray, full: bool) -> FloatArray:
    r = np.radians(h_deg)
    cols = [np.ones_like(r)]
    if full:
        cols += [np.sin(r), np.cos(r), np.sin(2.0 * r), np.cos(2.0 * r)]
    return np.column_stack(cols)


@dataclass(frozen=True, slots=True)
class CompassCalibration:
    """A deviation card: ``corrected = reading + deviation_deg(reading)`` (module docstring)."""

    a_deg: float = 0.0
    b_deg: float = 0.0
    c_deg: float = 0.0
    d_deg: float = 0.0
    e_deg: float = 0.0

    def deviation_deg(self, reading_deg: float) -> float:
        """Degrees to add to the compass reading (any real reading; wraps naturally)."""
        r = math.radians(reading_deg)
        first = self.b_deg * math.sin(r) + self.c_deg * math.cos(r)
        return self.a_deg + first + self.d_deg * math.sin(2 * r) + self.e_deg * math.cos(2 * r)

    def apply(self, reading_deg: float) -> float:
        """Corrected magnetic heading in [0, 360)."""
        w = (reading_deg + self.deviation_deg(reading_deg)) % 360.0
        return 0.0 if w >= 360.0 else w  # -1e-17 % 360.0 rounds to 360.0

    def as_dict(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in _NAMES}

    @classmethod
    def from_mapping(cls, m: Mapping[str, object]) -> CompassCalibration:
        """From ``a_deg`` .. ``e_deg`` (missing ones are 0); ValueError when unusable."""
        unknown = sorted(set(m) - set(_NAMES))
        if unknown:
            raise ValueError(f"unknown compass calibration key(s) {unknown}; expected {_NAMES}")
        values: dict[str, float] = {}
        for name in _NAMES:
            v = m.get(name, 0.0)
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"compass calibration {name} must be a number, got {v!r}")
            try:
                values[name] = float(v)
            except OverflowError:
                raise ValueError(f"compass calibration {name} is out of range") from None
        cal = cls(**values)
        problem = _problem(cal)
        if problem:
            raise ValueError(f"compass calibration rejected: {problem}")
        return cal

    @property
    def is_identity(self) -> bool:
        return all(getattr(self, name) == 0.0 for name in _NAMES)


def compass_heading_to_theta(
    reading: CompassHeading,
    declination_deg: float,
    mounting_offset_deg: float = 0.0,
    card: CompassCalibration | None = None,
) -> float:
    """Filter heading (rad, CCW from east, SPEC section 7) of the car from a compass reading:
    the deviation ``card`` (when calibrated), then the mounting offset (clockwise positive: the
    angle from the compass's forward mark to the car's forward axis), then the declination,
    which a true heading (HDT) skips. The pipeline's one conversion (``Pipeline.compass_fix``).
    """
    deg = reading.heading_deg if card is None else card.apply(reading.heading_deg)
    decl = 0.0 if reading.is_true else declination_deg
    return float(compass_to_heading(deg + mounting_offset_deg, decl))


def _problem(cal: CompassCalibration) -> str | None:
    """Why a card is unusable, or None (limits: MAX_HARMONIC_DEG)."""
    for name, v in cal.as_dict().items():
        if not math.isfinite(v):
            return f"{name} = {v} is not a finite number"
    if abs(cal.a_deg) > 180.0:
        return f"a_deg = {cal.a_deg:g} is outside [-180, 180]"
    for name in _NAMES[1:]:
        v = getattr(cal, name)
        if abs(v) > MAX_HARMONIC_DEG:
            return (
                f"{name} = {v:g} exceeds ±{MAX_HARMONIC_DEG:g} degrees: the car's own field "
                "is nearly as strong as the earth's there, more than a deviation card can "
                "correct. What to do: mount the compass away from steel, speakers and wiring "
                "(the roof, a mast), or use a compass with its own hard-iron calibration "
                "(a 3-axis magnetometer calibrated by its maker's figure-of-eight routine), "
                "or run uncalibrated: leave the card out and the car model's wide compass "
                "bias prior takes it"
            )
    # Single-valued card: d(corrected)/d(reading) > 0 everywhere, or the card says the compass
    # turns backwards while the car turns, which no compass does: the fit or the data are wrong.
    h = np.radians(np.arange(0.0, 360.0, 0.25))
    b, c, d, e = (math.radians(getattr(cal, n)) for n in _NAMES[1:])
    slope = 1 + b * np.cos(h) - c * np.sin(h) + 2 * d * np.cos(2 * h) - 2 * e * np.sin(2 * h)
    k = int(np.argmin(slope))
    if slope[k] <= 0.0:
        return (
            f"the deviation curve folds back near reading {math.degrees(h[k]):.0f} degrees "
            f"(d corrected / d reading = {slope[k]:.2f}): it is not single-valued"
        )
    return None


@dataclass(frozen=True, slots=True)
class FitResult:
    """A fitted card and how well it fits. Residual figures are over the inliers only."""

    calibration: CompassCalibration
    residual_rms_deg: float
    residual_max_deg: float
    n_used: int
    n_outliers: int
    coverage_deg: float
    terms: Terms
    note: str = ""


def heading_coverage(readings_deg: npt.ArrayLike) -> tuple[float, int]:
    """(360° minus the largest circular gap between readings, occupied 30° sectors of 12)."""
    h = np.sort(np.mod(np.asarray(readings_deg, dtype=np.float64).ravel(), 360.0))
    if h.size == 0:
        return 0.0, 0
    gaps = np.diff(np.append(h, h[0] + 360.0))
    sectors = np.unique(np.floor(h / SECTOR_DEG).astype(np.int64) % 12).size
    return float(360.0 - gaps.max()), int(sectors)


def _wls(x: FloatArray, y: FloatArray, w: FloatArray) -> FloatArray:
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(x * sw[:, None], y * sw, rcond=None)
    return np.asarray(coef, dtype=np.float64)


def _mad_scale(r: FloatArray) -> float:
    return max(1.4826 * float(np.median(np.abs(r - np.median(r)))), SCALE_FLOOR_DEG)


def _irls(x: FloatArray, y_wrapped: FloatArray, robust: bool) -> tuple[FloatArray, FloatArray]:
    """Coefficients and wrapped residuals. Huber first (convex: the result does not depend on
    the start), then Tukey's biweight, which gives interference spikes no weight at all. Every
    step re-unwraps the data around the current curve, so an offset near ±180° fits too."""
    c0 = _circular_mean_deg(y_wrapped)
    y = c0 + _wrap180(y_wrapped - c0)
    coef = _wls(x, y, np.ones_like(y))
    for phase in ("huber", "tukey") if robust else ("plain",):
        for _ in range(_IRLS_ITER):
            r = _wrap180(y_wrapped - x @ coef)
            u = np.abs(r) / _mad_scale(r)
            if phase == "huber":
                w = np.minimum(1.0, HUBER_K / np.maximum(u, 1e-12))
            elif phase == "tukey":
                w = np.where(u < TUKEY_C, (1.0 - (u / TUKEY_C) ** 2) ** 2, 0.0)
            else:
                w = np.ones_like(r)
            new = _wls(x, x @ coef + r, w)
            done = float(np.max(np.abs(new - coef))) < 1e-7
            coef = new
            if done:
                break
    return coef, _wrap180(y_wrapped - x @ coef)


def fit_deviation(
    readings_deg: npt.ArrayLike,
    reference_deg: npt.ArrayLike,
    *,
    min_coverage_deg: float = MIN_COVERAGE_DEG,
    robust: bool = True,
) -> FitResult:
    """Fit the card to compass readings and the true magnetic heading at each reading.

    Least squares of wrap180(reference - reading) on [1, sin h, cos h, sin 2h, cos 2h] (h the
    reading), robust by default (see ``_irls``; outliers are residuals beyond TUKEY_C times the
    MAD scale). Fits the offset A only when the readings cover less than ``min_coverage_deg``
    or too few 30° sectors (SECTOR_DEG), and says so in ``note``. ValueError for fewer than
    MIN_READINGS readings, bad input, or a fitted card that is unusable (``_problem``).
    """
    h = np.mod(np.asarray(readings_deg, dtype=np.float64), 360.0)
    ref = np.asarray(reference_deg, dtype=np.float64)
    if h.ndim != 1 or h.shape != ref.shape:
        raise ValueError(
            f"readings {h.shape} and references {ref.shape}: need two equal 1-D arrays"
        )
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(ref))):
        raise ValueError("readings and references must be finite (drop missing readings first)")
    if h.size < MIN_READINGS:
        raise ValueError(f"{h.size} compass readings; a calibration needs at least {MIN_READINGS}")
    if not 0.0 < min_coverage_deg <= 360.0:
        raise ValueError(f"min_coverage_deg = {min_coverage_deg} is outside (0, 360]")
    y = _wrap180(ref - h)
    min_sectors = math.ceil(min_coverage_deg / SECTOR_DEG)
    coverage, sectors = heading_coverage(h)
    full = coverage >= min_coverage_deg and sectors >= min_sectors
    coef, r = _irls(_design(h, full), y, robust)
    inlier = np.abs(r) < TUKEY_C * _mad_scale(r) if robust else np.ones(h.size, dtype=np.bool_)
    if full:  # spikes must not be what bridged a gap: check again on the inliers
        coverage, sectors = heading_coverage(h[inlier])
        if coverage < min_coverage_deg or sectors < min_sectors:
            full = False
            coef, r = _irls(_design(h, False), y, robust)
            inlier = np.abs(r) < TUKEY_C * _mad_scale(r) if robust else inlier
    values = np.zeros(5)
    values[: coef.size] = coef
    values[0] = float(_wrap180(values[:1])[0])
    cal = CompassCalibration(*(float(v) for v in values))
    problem = _problem(cal)
    if problem:
        raise ValueError(f"the fitted deviation card is unusable: {problem}")
    notes = []
    if not full:
        notes.append(
            f"readings cover {coverage:.0f} degrees of heading ({sectors} of 12 30-degree "
            f"sectors; {min_coverage_deg:.0f} degrees and {min_sectors} sectors needed): "
            "fitted the constant offset only; drive two slow circles to fit the deviation curve"
        )
    n_out = int(h.size - np.count_nonzero(inlier))
    if n_out > 0.2 * h.size:
        notes.append(
            f"{n_out} of {h.size} readings rejected as interference: calibrate away from "
            "steel structures, power lines and other cars"
        )
    used = r[inlier]
    rms = float(np.sqrt(np.mean(used**2)))
    if rms > POOR_FIT_RMS_DEG:
        notes.append(
            f"residual rms {rms:.1f} degrees: the card explains the readings poorly; check the "
            "start heading, the track width and the compass mounting"
        )
    return FitResult(
        calibration=cal,
        residual_rms_deg=rms,
        residual_max_deg=float(np.max(np.abs(used))),
        n_used=int(used.size),
        n_outliers=n_out,
        coverage_deg=coverage,
        terms="offset + 2 harmonics" if full else "offset only",
        note="; ".join(notes),
    )


@dataclass(frozen=True, slots=True, eq=False)
class OdometryReference:
    """Magnetic heading dead-reckoned from wheel odometry, at the odometry times ``t_s``.

    ``magnetic_deg`` is unwrapped (continuous, may leave [0, 360)) so it interpolates across
    north; ``distance_m`` is cumulative |distance|; ``speed_mps[k]`` is the mean speed over
    (t_s[k-1], t_s[k]] (``speed_mps[0]`` repeats ``speed_mps[1]``). Queries outside
    [t_s[0], t_s[-1]] give NaN (heading, distance, speed) or False (``moving``).
    """

    t_s: FloatArray
    magnetic_deg: FloatArray
    distance_m: FloatArray
    speed_mps: FloatArray

    @property
    def total_distance_m(self) -> float:
        return float(self.distance_m[-1])

    def _inside(self, t: FloatArray) -> BoolArray:
        return np.asarray((t >= self.t_s[0]) & (t <= self.t_s[-1]), dtype=np.bool_)

    def magnetic_at(self, t_s: npt.ArrayLike) -> FloatArray:
        """Magnetic reference heading in [0, 360) at the given times (linear in between)."""
        t = np.asarray(t_s, dtype=np.float64)
        m = np.mod(np.interp(t, self.t_s, self.magnetic_deg), 360.0)
        return np.where(self._inside(t), m, np.nan)

    def distance_at(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        return np.where(self._inside(t), np.interp(t, self.t_s, self.distance_m), np.nan)

    def speed_at(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        k = np.clip(np.searchsorted(self.t_s, t, side="left"), 1, self.t_s.size - 1)
        return np.where(self._inside(t), self.speed_mps[k], np.nan)

    def moving(self, t_s: npt.ArrayLike, min_speed_mps: float = MIN_SPEED_MPS) -> BoolArray:
        """The readings worth fitting: inside the drive and at least ``min_speed_mps``."""
        s = self.speed_at(t_s)
        return np.asarray(np.isfinite(s) & (s >= min_speed_mps), dtype=np.bool_)


def reference_headings_from_odometry(
    t_s: npt.ArrayLike,
    d_left_m: npt.ArrayLike,
    d_right_m: npt.ArrayLike,
    *,
    track_m: float,
    start_true_heading_deg: float,
    declination_deg: float,
) -> OdometryReference:
    """Dead-reckon the magnetic heading through a calibration drive.

    ``d_left_m[k]``/``d_right_m[k]`` are the rear wheels' signed distances since the previous
    sample (as in WheelOdometry). The start heading (true, clockwise from north) holds at
    ``t_s[0]``, so the first increment is not used. The heading turns (d_right - d_left)/track
    radians counter-clockwise, so the compass heading falls in a left turn; magnetic = true -
    declination (east positive). Drift: module docstring.
    """
    t = np.asarray(t_s, dtype=np.float64)
    dl = np.asarray(d_left_m, dtype=np.float64)
    dr = np.asarray(d_right_m, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 or dl.shape != t.shape or dr.shape != t.shape:
        raise ValueError("t_s, d_left_m, d_right_m must be equal 1-D arrays of 2 or more samples")
    scalars = (track_m, start_true_heading_deg, declination_deg)
    if not all(np.all(np.isfinite(a)) for a in (t, dl, dr, *scalars)):
        raise ValueError("odometry times, increments, track and headings must be finite")
    if not track_m > 0.0:
        raise ValueError(f"track_m = {track_m} must be positive")
    dt = np.diff(t)
    if np.any(dt <= 0.0):
        raise ValueError(f"odometry times must increase strictly (sample {int(np.argmin(dt)) + 1})")
    turn_deg = -np.degrees((dr[1:] - dl[1:]) / track_m)  # compass: clockwise positive
    magnetic = (
        start_true_heading_deg - declination_deg + np.concatenate(([0.0], np.cumsum(turn_deg)))
    )
    step = np.abs(0.5 * (dl[1:] + dr[1:]))
    speed = step / dt
    return OdometryReference(
        t_s=t,
        magnetic_deg=magnetic,
        distance_m=np.concatenate(([0.0], np.cumsum(step))),
        speed_mps=np.concatenate((speed[:1], speed)),
    )


def calibrate_from_drive(
    reading_t_s: npt.ArrayLike,
    readings_deg: npt.ArrayLike,
    reference: OdometryReference,
    *,
    min_speed_mps: float = MIN_SPEED_MPS,
    max_drive_m: float = MAX_DRIVE_M,
    min_coverage_deg: float = MIN_COVERAGE_DEG,
    robust: bool = True,
) -> FitResult:
    """Fit the card to the compass readings of a calibration drive (module docstring).

    Drops readings outside the odometry span or below ``min_speed_mps`` (MIN_SPEED_MPS says
    why), then :func:`fit_deviation`. Warns in ``note`` when the drive up to the last reading
    is longer than ``max_drive_m``: the odometry heading has drifted by then.
    """
    t = np.asarray(reading_t_s, dtype=np.float64)
    h = np.asarray(readings_deg, dtype=np.float64)
    if t.ndim != 1 or t.shape != h.shape:
        raise ValueError(f"reading times {t.shape} and readings {h.shape}: need equal 1-D arrays")
    keep = reference.moving(t, min_speed_mps)
    n = int(np.count_nonzero(keep))
    if n < MIN_READINGS:
        raise ValueError(
            f"{n} of {t.size} compass readings were taken while the car moved at "
            f">= {min_speed_mps:g} m/s during the odometry record; a calibration needs at least "
            f"{MIN_READINGS}"
        )
    result = fit_deviation(
        h[keep], reference.magnetic_at(t[keep]), min_coverage_deg=min_coverage_deg, robust=robust
    )
    notes = [result.note] if result.note else []
    if n < t.size:
        notes.append(f"{t.size - n} readings taken standing, slow or outside the drive dropped")
    drive_m = float(reference.distance_at(np.max(t[keep])))
    if drive_m > max_drive_m:
        notes.append(
            f"warning: {drive_m:.0f} m driven (> {max_drive_m:.0f} m): the odometry heading "
            "drifts with distance (0.05 % tyre mismatch on a 1.6 m track: 18 degrees per km); "
            "calibrate with two slow circles right after setting the start heading"
        )
    return replace(result, note="; ".join(notes))
