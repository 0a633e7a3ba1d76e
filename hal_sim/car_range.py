"""Fig. 3's question for real cars: how far a car drives before it is "lost", uncalibrated and
calibrated (issue 21, item 5).

The paper's range study (``hal_sim.studies``, fig3) drives the paper's model: white noise per
odometry count, a compass of known 2-sigma and no bias. A real car has persistent errors: the
population of ``hal_sim.population`` (wheel scale, left/right difference, compass offset and
hard-iron curve, drift, start errors, drawn heavier-tailed than the filter's priors). Here each
car of that population drives random routes through the car's real ``Pipeline`` (car model)
until it declares itself lost (2-sigma major axis over 100 m, as in the paper) or reaches
``cap_m``, in four conditions:

* **odometry only, uncalibrated**: the car model's priors (wheel scale 2 %, left/right 0.03 %);
* **odometry only, calibrated**: the car first drives 3 km with landmark fixes (40 per km^2,
  60 % seen; ``population.learn_then_drive``) and the range drive, another route a day later
  without landmarks, starts from what it learned (``guidance.core.localize.learned``), widened
  for the day;
* **compass, uncalibrated**: its compass as delivered (offset N(0, 40 deg), hard iron up to 0.4
  of the earth's field), the filter's uncalibrated compass prior (60 deg, 250 deg^2/rad);
* **compass, calibrated**: a deviation card from ``guidance calibrate`` (two circles give the
  card back within 1.5 deg: tests/guidance/tools/test_calibrate.py), so the readings keep the
  card's residual only (``card_residual``: offset N(0, 1.5 deg), a hard-iron residual of up
  to 0.02 of the field, about 1 deg), the calibrated prior (5 deg, 16 deg^2/rad), and the
  learned parameters of a first drive as above.

The cars, their routes and their noise are the same in the uncalibrated and the calibrated
condition (same seeds). The paper model's figures are not touched: they are drawn beside for
reference (``PAPER_LOST_KM``, docs/simulation.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from hal_sim.car_errors import CarErrors, draw_car
from hal_sim.population import CarResult, drive_car

CONDITIONS: tuple[tuple[str, bool, bool], ...] = (
    ("odometry only, uncalibrated", False, False),
    ("odometry only, calibrated (learned)", False, True),
    ("compass, uncalibrated", True, False),
    ("compass, calibrated (card + learned)", True, True),
)
"""(label, compass, calibrated)."""
PAPER_LOST_KM = {"paper model, no compass": 0.31, "paper model, compass 30 deg": 9.52,
                 "paper model, compass 20 deg": 21.77}  # fmt: skip
"""The paper model's mean lost distances as measured (docs/simulation.md, seed 11, 1,000
trials each; the paper: about 0.3, 9.3 and 20.8 km); 10 deg is never lost within 40 km."""
LEARN_M = 3000.0
LEARN_LANDMARKS_PER_KM2 = 40.0


def card_residual(errors: CarErrors, rng: np.random.Generator) -> CarErrors:
    """The compass errors a deviation card leaves (module docstring)."""
    return replace(
        errors,
        compass_offset_deg=float(rng.normal(0.0, 1.5)),
        hard_iron_ratio=float(rng.uniform(0.0, 0.02)),
    )


def range_car(
    seed: int, errors: CarErrors, *, compass: bool, calibrated: bool, cap_m: float
) -> CarResult:
    """One car's range drive in one condition (module docstring)."""
    learned = None
    if calibrated:
        if compass:
            errors = card_residual(errors, np.random.default_rng([seed, 7]))
        first = drive_car(seed, errors, compass=compass, landmarks_per_km2=LEARN_LANDMARKS_PER_KM2,
                          distance_m=LEARN_M, calibrated=True)  # fmt: skip
        assert first.learned is not None  # the car model always has them
        cfg = car_model(EstimatorConfig(compass_two_sigma_deg=30.0 if compass else None),
                        calibrated=True)  # fmt: skip
        learned = first.learned.widened(first.learned.saved_unix_s + 86400.0, cfg)
    return drive_car(seed + 1000, errors, compass=compass, learned=learned, distance_m=cap_m,
                     stop_when_lost=True, calibrated=calibrated)  # fmt: skip


@dataclass(slots=True)
class RangeFigures:
    label: str
    cars: int
    cap_km: float
    lost_km: list[float]
    """Per car, the distance when lost was declared; ``cap_km`` for a car never lost."""
    never_lost: float
    true_error_at_lost_m: list[float]
    results: list[CarResult]

    @property
    def mean_km(self) -> float:
        """Mean lost distance, the cars never lost counted at the cap (a lower bound then)."""
        return float(np.mean(self.lost_km))

    @property
    def median_km(self) -> float:
        return float(np.median(self.lost_km))

    def row(self) -> str:
        err = self.true_error_at_lost_m
        err_txt = f"{np.median(err):.0f} m" if err else "-"
        q = np.percentile(self.lost_km, [10, 90])
        bound = ">= " if self.never_lost > 0 else ""
        return (
            f"| {self.label} | {bound}{self.mean_km:.2f} km | {self.median_km:.2f} km | "
            f"{q[0]:.2f} - {q[1]:.2f} km | {100 * self.never_lost:.0f} % | {err_txt} |"
        )


TABLE_HEADER = (
    "| condition | mean lost distance | median | p10 - p90 | never lost within the cap | "
    "median true error when lost |\n|---|---|---|---|---|---|"
)


def range_study(cars: int, seed: int, cap_m: float) -> list[RangeFigures]:
    """Every condition over the same ``cars`` cars (errors drawn with ``seed``)."""
    rng = np.random.default_rng(seed)
    errors = [draw_car(rng) for _ in range(cars)]
    out = []
    for label, compass, calibrated in CONDITIONS:
        results = [
            range_car(20_000 + 10 * i, e, compass=compass, calibrated=calibrated, cap_m=cap_m)
            for i, e in enumerate(errors)
        ]
        lost = [r.lost_at_m / 1000 if r.lost_at_m is not None else cap_m / 1000 for r in results]
        out.append(
            RangeFigures(
                label=label,
                cars=cars,
                cap_km=cap_m / 1000,
                lost_km=lost,
                never_lost=float(np.mean([r.lost_at_m is None for r in results])),
                true_error_at_lost_m=[
                    r.lost_at_error_m for r in results if r.lost_at_error_m is not None
                ],
                results=results,
            )
        )
    return out


def median_axis_curve(results: list[CarResult], d_km: np.ndarray) -> np.ndarray:
    """The median 2-sigma major axis at each distance over the cars still driving (NaN where
    fewer than half of them are: the rest were lost)."""
    rows = []
    for r in results:
        if not r.axis_m:
            continue
        d = np.array([a[0] for a in r.axis_m]) / 1000.0
        ax = np.array([a[1] for a in r.axis_m])
        v = np.interp(d_km, d, ax, left=math.nan, right=math.nan)
        rows.append(v)
    if not rows:
        return np.full_like(d_km, math.nan)
    m = np.asarray(rows)
    alive = np.isfinite(m).mean(axis=0)
    with np.errstate(all="ignore"):
        med = np.nanmedian(np.where(np.isfinite(m), m, math.inf), axis=0)
    return np.where(alive >= 0.5, med, math.nan)
