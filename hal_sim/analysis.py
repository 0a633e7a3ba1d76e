"""Study results into numbers: the growth fit and lost distances (range), the range at 80 %
success (landmarks, field), the summaries with their 95 % intervals, and the comparison with
the paper's figures (SPEC 5) a reviewer reads (``paper_check``)."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hal_sim import engine
from hal_sim.params import SimParams
from hal_sim.provenance import bootstrap_mean, inside, wilson_pair
from hal_sim.study_design import LANDMARK_METHODS, LOSS_LINE_M, SUCCESS_TARGET

if TYPE_CHECKING:
    from hal_sim.study_design import StudyData


def fit_growth(
    distance_km: np.ndarray, major_m: np.ndarray
) -> tuple[float, float, float, float] | None:
    """Fit major^2 = c0 + c1 d + c2 d^2 + c3 d^3 (m^2, d in km), coefficients >= 0.

    The position variance grows linearly with distance while the compass bounds
    the heading error, with d^2 from an initial heading error, and with d^3 when
    the heading error random-walks (no compass); c0 is the starting
    uncertainty. Relative errors are minimised, so short and long distances
    count alike. Returns None when there is nothing to fit.
    """
    ok = np.isfinite(major_m) & (distance_km > 0) & (major_m > 0)
    if ok.sum() < 4:
        return None
    d = distance_km[ok]
    y = major_m[ok] ** 2
    w = 1.0 / y
    basis = np.column_stack([np.ones_like(d), d, d**2, d**3])
    best: tuple[float, np.ndarray] | None = None
    for bits in range(1, 16):
        cols = [k for k in range(4) if bits >> k & 1]
        coef, *_ = np.linalg.lstsq(basis[:, cols] * w[:, None], y * w, rcond=None)
        if np.any(coef < 0):
            continue
        full = np.zeros(4)
        full[cols] = coef
        err = float(np.sum(((basis @ full - y) * w) ** 2))
        if best is None or err < best[0]:
            best = (err, full)
    if best is None:
        return None
    c = best[1]
    return float(c[0]), float(c[1]), float(c[2]), float(c[3])


def fit_of(row: dict[str, Any]) -> tuple[float, float, float, float] | None:
    """The growth fit ``summarise_range`` stored in a condition's row, as ``fit_growth``
    returned it."""
    fit = row["fit_major_axis_sq"]
    return None if fit is None else (fit["c0_m2"], fit["c1_m2_per_km"], fit["c2_m2_per_km2"],
                                     fit["c3_m2_per_km3"])  # fmt: skip


def growth_curve(coef: tuple[float, float, float, float], distance_km: np.ndarray) -> np.ndarray:
    c0, c1, c2, c3 = coef
    return np.sqrt(c0 + c1 * distance_km + c2 * distance_km**2 + c3 * distance_km**3)


def fitted_lost_km(coef: tuple[float, float, float, float], limit_m: float = 100.0) -> float | None:
    """Where the fitted major axis crosses ``limit_m`` (None if it never grows)."""
    if max(coef[1:]) <= 0:
        return None
    lo, hi = 0.0, 1.0
    while growth_curve(coef, np.array([hi]))[0] < limit_m:
        hi *= 2.0
        if hi > 1e6:
            return None
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if growth_curve(coef, np.array([mid]))[0] < limit_m:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def range_at_success(
    distance_km: np.ndarray, success: np.ndarray, target: float = SUCCESS_TARGET
) -> tuple[float, bool]:
    """Distance at which a logistic fit of success against distance falls to ``target``.

    Returns (km, censored): censored is True when the success rate stays above
    the target over all distances tried (the figure is then the largest one).
    """
    d = np.asarray(distance_km, dtype=float)
    y = np.asarray(success, dtype=float)
    if len(d) == 0:
        return 0.0, False
    if y.mean() >= 0.999:
        return float(d.max()), True
    if y.mean() <= 0.001:
        return 0.0, False
    # Logistic regression y ~ sigmoid(w0 + w1 d) by Newton's method (2 parameters).
    X = np.column_stack([np.ones_like(d), d])
    w = np.array([math.log(max(y.mean(), 1e-3) / max(1 - y.mean(), 1e-3)), 0.0])
    for _ in range(50):
        z = np.clip(X @ w, -30, 30)
        pr = 1.0 / (1.0 + np.exp(-z))
        grad = X.T @ (y - pr)
        H = (X * (pr * (1 - pr))[:, None]).T @ X + 1e-9 * np.eye(2)
        step = np.linalg.solve(H, grad)
        w = w + step
        if np.abs(step).max() < 1e-10:
            break
    if w[1] >= 0:  # success does not fall with distance
        return (float(d.max()), True) if y.mean() >= target else (0.0, False)
    km = (math.log(target / (1 - target)) - w[0]) / w[1]
    if km > d.max():
        return float(d.max()), True
    return max(0.0, float(km)), False


def _mean_km(metres: np.ndarray) -> float | None:
    ok = np.isfinite(metres)
    return float(metres[ok].mean() / 1000.0) if ok.any() else None


def summarise_range(data: StudyData, sim: SimParams, seed: int = 0) -> dict[str, Any]:
    """Per condition: the mean lost distance (over the trials that were lost) with its 95 %
    bootstrap interval, the never-lost fraction with its Wilson interval, the growth fit."""
    conds = []
    for c in data.conditions:
        r = data.results[c.key]
        lost_m = r[:, engine.RES_LOST_AT_M]
        lost = np.isfinite(lost_m)
        ci = bootstrap_mean(lost_m[lost] / 1000.0, seed=seed + c.index)
        s = data.samples[c.key]
        dist = np.broadcast_to(data.sample_km, s.shape)
        fit = fit_growth(dist.ravel(), s.ravel())
        fit_lost = None if fit is None else fitted_lost_km(fit, LOSS_LINE_M)
        conds.append(
            {
                "compass_2sigma_deg": c.compass_two_sigma_deg,
                "trials": len(r),
                "mean_lost_km": float(lost_m[lost].mean() / 1000.0) if lost.any() else None,
                "mean_lost_km_ci95": ci,
                "lost_trials": int(lost.sum()),
                "median_lost_km": float(np.median(lost_m[lost]) / 1000.0) if lost.any() else None,
                "never_lost_fraction": float(1.0 - lost.mean()),
                "never_lost_fraction_ci95": wilson_pair(int((~lost).sum()), len(r)),
                "cap_km": sim.range_cap_km,
                "fit_major_axis_sq": None
                if fit is None
                else dict(
                    zip(
                        ("c0_m2", "c1_m2_per_km", "c2_m2_per_km2", "c3_m2_per_km3"),
                        fit,
                        strict=False,
                    )
                ),
                "fit_lost_km": fit_lost,
                "mean_turns_per_km": float(
                    np.mean(r[:, engine.RES_TURNS] / np.maximum(r[:, engine.RES_DRIVEN_M], 1) * 1e3)
                ),
                "compass_rejections_per_trial": float(r[:, engine.RES_COMPASS_REJECTS].mean()),
                # The truth's view: how often the true error passed half the lost axis
                # (the filter was wrong about itself), and the mean worst error.
                "true_lost_fraction": float(np.isfinite(r[:, engine.RES_TRUE_LOST_AT_M]).mean()),
                "mean_max_true_error_m": float(r[:, engine.RES_MAX_ERR_M].mean()),
                "mean_lost_either_km": _mean_km(
                    np.fmin(r[:, engine.RES_LOST_AT_M], r[:, engine.RES_TRUE_LOST_AT_M])
                ),
            }
        )
    return {"study": "range", "conditions": conds}


def summarise_landmarks(data: StudyData, seed: int = 0) -> dict[str, Any]:
    """Per condition: success rate with its Wilson interval, the range at 80 % success, and the
    success of the trials near the paper's field distance; per method the mean distance
    driven (bootstrap interval) and success."""
    conds = []
    for c in data.conditions:
        r = data.results[c.key]
        success = r[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED
        km, censored = range_at_success(r[:, engine.RES_EUCLID_M] / 1000.0, success)
        near = np.abs(r[:, engine.RES_EUCLID_M] - PAPER_FIELD_KM * 1000.0) <= NEAR_FIELD_KM * 1000
        conds.append(
            {
                "method": c.method.value,
                "density_per_km2": c.density_per_km2,
                "detection_rate": c.detection_rate,
                "trials": len(r),
                "success_rate": float(success.mean()),
                "success_rate_ci95": wilson_pair(int(success.sum()), len(r)),
                "near_paper_field_trials": int(near.sum()),
                "near_paper_field_success": float(success[near].mean()) if near.any() else None,
                "near_paper_field_success_ci95": wilson_pair(
                    int(success[near].sum()), int(near.sum())
                ),
                "range_km_at_80pct": km,
                "range_censored": censored,
                "mean_driven_km": float(r[:, engine.RES_DRIVEN_M].mean() / 1000.0),
                "lost_fraction": float((r[:, engine.RES_OUTCOME] == engine.OUTCOME_LOST).mean()),
                "timeout_fraction": float(
                    (r[:, engine.RES_OUTCOME] == engine.OUTCOME_TIMEOUT).mean()
                ),
                "mean_landmark_updates": float(r[:, engine.RES_LANDMARK_UPDATES].mean()),
            }
        )
    per_method: dict[str, dict[str, Any]] = {}
    for m in LANDMARK_METHODS:
        rs = [data.results[c.key] for c in data.conditions if c.method is m]
        if rs:
            allr = np.vstack(rs)
            ok = allr[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED
            driven = allr[:, engine.RES_DRIVEN_M] / 1000.0
            per_method[m.value] = {
                "mean_driven_km": float(driven.mean()),
                "mean_driven_km_ci95": bootstrap_mean(driven, seed=seed + len(per_method)),
                "success_rate": float(ok.mean()),
                "success_rate_ci95": wilson_pair(int(ok.sum()), len(ok)),
            }
    return {"study": "landmarks", "conditions": conds, "methods": per_method}


def write_trials_csv(
    data: StudyData, path: Path, header: str = "", relocalise: bool = False
) -> None:
    """Per-trial results, one row per trial, with the condition's columns first; the first
    line is the provenance, as a comment (``#``; ``read_csv_rows`` skips it). The relocalising
    arm's counts are columns only when the study ran it (``engine.N_PAPER_RESULT``)."""
    cols = ["condition", "method", "compass_2sigma_deg", "density_per_km2", "detection_rate"]
    names = engine.RESULT_NAMES if relocalise else engine.RESULT_NAMES[: engine.N_PAPER_RESULT]
    with path.open("w") as f:
        if header:
            f.write(f"# {header}\n")
        f.write(",".join([*cols, *names]) + "\n")
        for c in data.conditions:
            head = [
                c.key,
                c.method.value,
                "" if c.compass_two_sigma_deg is None else f"{c.compass_two_sigma_deg:g}",
                f"{c.density_per_km2:g}",
                f"{c.detection_rate:g}",
            ]
            for row in data.results[c.key]:
                vals = [
                    engine.OUTCOME_NAMES[int(v)] if i == engine.RES_OUTCOME else
                    ("" if not math.isfinite(v) else f"{v:.6g}")
                    for i, v in enumerate(row[: len(names)])
                ]  # fmt: skip
                f.write(",".join(head + vals) + "\n")


# ----------------------------------------------------------------------------- the paper
PAPER_RANGE_KM: dict[float | None, float | None] = {10.0: None, 20.0: 20.8, 30.0: 9.3, None: 0.3}
"""SPEC 5's Fig. 3 figures: mean distance before lost per compass 2-sigma (None: not lost)."""
PAPER_TOLERANCE = 0.15
"""SPEC 5: the simulator reproduces the paper's range figures within 15 %."""
PAPER_NEVER_LOST_MIN = 0.8
"""10 degrees, "not lost within the distances tried": at least this fraction never lost."""
PAPER_FIELD_KM = 6.9
PAPER_FIELD_DENSITY = 0.55
PAPER_FIELD_DETECTION = 0.6
"""The paper's field result: 80 % success at 6.9 km or more, 0.55 landmarks/km2, 60 %."""
NEAR_FIELD_KM = 1.0
"""Landmark-study trials within this of the paper's field distance are read against it."""
RANGE_CI_RESAMPLES = 200


def range_at_success_ci(
    distance_km: np.ndarray, success: np.ndarray, seed: int, resamples: int = RANGE_CI_RESAMPLES
) -> list[float] | None:
    """Percentile bootstrap 95 % interval of ``range_at_success`` (trials resampled)."""
    d = np.asarray(distance_km, dtype=float)
    y = np.asarray(success, dtype=bool)
    if len(d) < 2:
        return None
    rng = np.random.default_rng([seed, len(d)])
    kms = np.empty(resamples)
    for i in range(resamples):
        idx = rng.integers(0, len(d), len(d))
        kms[i] = range_at_success(d[idx], y[idx])[0]
    lo, hi = np.quantile(kms, [0.025, 0.975])
    return [float(lo), float(hi)]


def _row(
    figure: str, condition: str, quantity: str, paper: float | str, ours: float | None,
    ci: list[float] | None, paper_value: float | None, within: bool | None, note: str = "",
) -> dict[str, Any]:  # fmt: skip
    return {
        "figure": figure,
        "condition": condition,
        "quantity": quantity,
        "paper": paper,
        "ours": ours,
        "ci95": ci,
        "paper_inside_ci": None if paper_value is None else inside(paper_value, ci),
        "within_tolerance": within,
        "note": note,
    }


def paper_check_range(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """Fig. 3 against the paper: the paper's value inside our 95 % interval, and within 15 %."""
    rows = []
    for c in summary["conditions"]:
        deg = c["compass_2sigma_deg"]
        if deg not in PAPER_RANGE_KM:
            continue
        name = "no compass" if deg is None else f"compass {deg:g} deg (2 sigma)"
        paper = PAPER_RANGE_KM[deg]
        if paper is None:
            frac = c["never_lost_fraction"]
            rows.append(_row(
                "fig3", name, "never-lost fraction", "not lost", frac,
                c["never_lost_fraction_ci95"], 1.0, frac >= PAPER_NEVER_LOST_MIN,
                f"within: at least {PAPER_NEVER_LOST_MIN:.0%} never lost",
            ))  # fmt: skip
            continue
        ours = c["mean_lost_km"]
        within = None if ours is None else abs(ours - paper) / paper <= PAPER_TOLERANCE
        rows.append(_row(
            "fig3", name, "mean lost distance, km", paper, ours, c["mean_lost_km_ci95"], paper,
            within, f"within: {PAPER_TOLERANCE:.0%} (SPEC 5); interval: bootstrap of the mean",
        ))  # fmt: skip
    return rows


def paper_check_landmarks(
    data: StudyData, summary: dict[str, Any], seed: int
) -> list[dict[str, Any]]:
    """The paper's field result against the landmark study's nearest condition (0.5 per km2,
    60 % detection): the range at 80 % success (bootstrap interval) and the success of the
    trials within 1 km of 6.9 km (Wilson interval) against 80 %."""
    rows: list[dict[str, Any]] = []
    sparsest = min(x.density_per_km2 for x in data.conditions)
    near = [
        (c, s) for c, s in zip(data.conditions, summary["conditions"], strict=True)
        if c.density_per_km2 == sparsest and c.detection_rate == PAPER_FIELD_DETECTION
    ]  # fmt: skip
    for c, s in near:
        r = data.results[c.key]
        ok = r[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED
        ci = range_at_success_ci(r[:, engine.RES_EUCLID_M] / 1000.0, ok, seed + c.index)
        name = f"{c.method.value}, {c.density_per_km2:g}/km2, {c.detection_rate:.0%}"
        km = s["range_km_at_80pct"]
        rows.append(_row(
            "fig4", name, "range at 80 % success, km", f">= {PAPER_FIELD_KM}", km, ci,
            PAPER_FIELD_KM, km >= PAPER_FIELD_KM,
            "paper: field, 0.55/km2; within: ours at least 6.9 km"
            + (" (censored: at least)" if s["range_censored"] else ""),
        ))  # fmt: skip
        rows.append(_row(
            "fig4", name, f"success, trials {PAPER_FIELD_KM - NEAR_FIELD_KM:g}-"
            f"{PAPER_FIELD_KM + NEAR_FIELD_KM:g} km (n={s['near_paper_field_trials']})",
            SUCCESS_TARGET, s["near_paper_field_success"], s["near_paper_field_success_ci95"],
            SUCCESS_TARGET, None, "paper: field, 80 % at 6.9 km",
        ))  # fmt: skip
    return rows


def read_csv_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a study table, past its ``#`` provenance line."""
    with path.open(newline="") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


PAPER_CHECK_COLUMNS = (
    "figure", "condition", "quantity", "paper", "ours", "ci95_low", "ci95_high",
    "paper_inside_ci", "within_tolerance", "note",
)  # fmt: skip


def paper_check_table(rows: list[dict[str, Any]]) -> list[dict[str, str]]:
    """The comparison with the paper as text cells (the CSV and the terminal table)."""

    def num(v: Any) -> str:
        if v is None:
            return "-"
        return f"{v:.3g}" if isinstance(v, float) else str(v)

    def yes(v: bool | None) -> str:
        return "-" if v is None else ("yes" if v else "no")

    out = []
    for r in rows:
        ci = r["ci95"] or [None, None]
        out.append({
            "figure": r["figure"], "condition": r["condition"], "quantity": r["quantity"],
            "paper": num(r["paper"]), "ours": num(r["ours"]), "ci95_low": num(ci[0]),
            "ci95_high": num(ci[1]), "paper_inside_ci": yes(r["paper_inside_ci"]),
            "within_tolerance": yes(r["within_tolerance"]), "note": r["note"],
        })  # fmt: skip
    return out


def write_paper_check(rows: list[dict[str, Any]], path: Path, header: str) -> None:
    with path.open("w", newline="") as f:
        f.write(f"# {header}\n")
        w = csv.DictWriter(f, fieldnames=PAPER_CHECK_COLUMNS)
        w.writeheader()
        w.writerows(paper_check_table(rows))
