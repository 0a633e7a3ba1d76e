"""Study figures (matplotlib, Agg): fig3 (range study); fig4 and its range heatmap
(landmark study)."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from hal_sim import engine

if TYPE_CHECKING:
    from hal_sim.studies import StudyData


def fig3(
    data: StudyData,
    path: Path,
    max_lines: int = 400,
    title: str = "Range without a map: uncertainty growth (thin: trials; thick: fitted growth)",
) -> None:
    """Major axis against distance driven for every trial, a fitted curve per condition."""
    from hal_sim.studies import LOSS_LINE_M, fit_growth, growth_curve

    fig, ax = plt.subplots(figsize=(9, 6), dpi=110)
    colours = plt.get_cmap("tab10")
    d = data.sample_km
    x_max = 1.0
    for i, c in enumerate(data.conditions):
        s = data.samples[c.key]
        col = colours(i)
        # every trial (thinned above max_lines so the PNG stays readable)
        rows = s if len(s) <= max_lines else s[:: max(1, len(s) // max_lines)]
        for row in rows:
            ok = np.isfinite(row)
            ax.plot(d[ok], row[ok], color=col, alpha=0.06, linewidth=0.6)
        fit = fit_growth(np.broadcast_to(d, s.shape).ravel(), s.ravel())
        if np.isfinite(s).any():
            x_max = max(x_max, float(d[np.isfinite(s).any(axis=0)].max()))
        lost = data.results[c.key][:, engine.RES_LOST_AT_M]
        mean_lost = np.nanmean(lost) / 1000 if np.isfinite(lost).any() else None
        label = c.label
        label += f": mean lost {mean_lost:.1f} km" if mean_lost is not None else ": never lost"
        if fit is not None:
            xx = np.geomspace(d[0], d[-1], 200)
            ax.plot(xx, growth_curve(fit, xx), color=col, linewidth=2.2, label=label)
        else:
            ax.plot([], [], color=col, linewidth=2.2, label=label)
    ax.axhline(LOSS_LINE_M, color="black", linestyle="--", linewidth=1.2, label="lost: 100 m")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(d[0], x_max * 1.05)
    ax.set_ylim(1, 1000)
    ax.set_xlabel("Distance driven along the streets (Manhattan), km")
    ax.set_ylabel("Major axis of the 2σ position ellipse, m")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(loc="lower right", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


WILSON_Z = 1.96
"""Two-sided 95 % normal quantile for the Wilson score interval."""
MIN_BIN_TRIALS = 5
"""Distance bins with fewer trials than this are left out of the success curves."""
RANGE_HEATMAP_NAME = "fig4_range_heatmap.png"
"""Written beside fig4.png by ``fig4``."""
CURVE_DETECTION_RATES = (0.2, 0.6, 1.0)
"""Detection rates drawn in fig4's panels: three bands per panel stay apart; every rate is
in the heatmap."""


def wilson_interval(
    successes: np.ndarray, trials: np.ndarray, z: float = WILSON_Z
) -> tuple[np.ndarray, np.ndarray]:
    """Wilson score interval (lower, upper) of a binomial proportion, per element.

    Unlike the normal approximation it stays inside [0, 1] and is not zero-width at
    0 % or 100 %, which matters in bins of a few dozen trials.
    """
    k = np.asarray(successes, dtype=float)
    n = np.asarray(trials, dtype=float)
    p = k / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    return np.clip(centre - half, 0.0, 1.0), np.clip(centre + half, 0.0, 1.0)


def success_bins(
    distance_km: np.ndarray,
    success: np.ndarray,
    bin_km: float = 1.0,
    min_trials: int = MIN_BIN_TRIALS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bin centre km, successes, trials) in distance bins holding at least ``min_trials``."""
    if len(distance_km) == 0:
        return np.array([]), np.array([]), np.array([])
    edges = np.arange(0.0, float(distance_km.max()) + bin_km, bin_km)
    idx = np.digitize(distance_km, edges) - 1
    xs, ks, ns = [], [], []
    for b in range(len(edges) - 1):
        m = idx == b
        if m.sum() >= min_trials:
            xs.append(edges[b] + bin_km / 2)
            ks.append(int(success[m].sum()))
            ns.append(int(m.sum()))
    return np.array(xs), np.array(ks), np.array(ns)


def _trial_outcomes(data: StudyData, key: str) -> tuple[np.ndarray, np.ndarray]:
    r = data.results[key]
    return r[:, engine.RES_EUCLID_M] / 1000.0, r[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED


def fig4(data: StudyData, path: Path, rates: tuple[float, ...] = CURVE_DETECTION_RATES) -> None:
    """Success against start-goal distance with 95 % Wilson bands, one panel per method and
    landmark density, a curve per detection rate in ``rates``; and, beside it
    (``RANGE_HEATMAP_NAME``), the per-method heatmap of the range at 80 % success."""
    from hal_sim.studies import LANDMARK_DENSITIES, LANDMARK_METHODS, SUCCESS_TARGET

    methods = [m for m in LANDMARK_METHODS if any(c.method is m for c in data.conditions)]
    fig, axes = plt.subplots(
        len(methods),
        len(LANDMARK_DENSITIES),
        figsize=(3.4 * len(LANDMARK_DENSITIES) + 1.6, 2.9 * len(methods) + 1.2),
        dpi=100,
        sharex=True,
        sharey=True,
        squeeze=False,
    )
    cmap = plt.get_cmap("plasma")
    colour = {rate: cmap(0.8 * i / max(1, len(rates) - 1)) for i, rate in enumerate(rates)}
    for row, method in enumerate(methods):
        for col, density in enumerate(LANDMARK_DENSITIES):
            ax = axes[row, col]
            drew = False
            for c in data.conditions:
                if c.method is not method or c.density_per_km2 != density:
                    continue
                if c.detection_rate not in colour:
                    continue
                x, k, n = success_bins(*_trial_outcomes(data, c.key))
                if len(x) == 0:
                    continue
                lo, hi = wilson_interval(k, n)
                ax.fill_between(x, lo, hi, color=colour[c.detection_rate], alpha=0.2, lw=0)
                ax.plot(x, k / n, color=colour[c.detection_rate], lw=1.6, marker=".", ms=4)
                drew = True
            if not drew:
                ax.text(
                    0.5,
                    0.5,
                    f"fewer than {MIN_BIN_TRIALS} trials\nin every 1 km bin",
                    ha="center",
                    va="center",
                    transform=ax.transAxes,
                    fontsize=8,
                    color="0.4",
                )
            ax.axhline(SUCCESS_TARGET, color="black", linewidth=0.8, linestyle="--")
            ax.set_ylim(0, 1.02)
            ax.grid(True, alpha=0.3)
            ax.set_title(f"{_method_name(method)}, {density:g} landmarks/km²", fontsize=9)
            if row == len(methods) - 1:
                ax.set_xlabel("Euclidean start-goal distance, km")
            if col == 0:
                ax.set_ylabel("Success rate")
    handles = [plt.Line2D([], [], color=colour[r], lw=1.6, label=f"{r:.0%}") for r in rates]
    handles.append(plt.Line2D([], [], color="black", lw=0.8, ls="--", label="80 % success"))
    fig.legend(
        handles=handles,
        loc="center right",
        title="detection rate\n(bands: 95 %\nWilson interval;\nall rates: heatmap)",
        fontsize=9,
        title_fontsize=9,
    )
    fig.suptitle(
        "Landmark study: success (goal reached, never lost) against distance, "
        "compass ±30° (2σ), 1 km bins"
    )
    fig.tight_layout(rect=(0, 0, 0.9, 0.97))
    fig.savefig(path)
    plt.close(fig)
    range_heatmap(data, path.with_name(RANGE_HEATMAP_NAME))


def _method_name(method: Any) -> str:
    return str(method.value).replace("_", " ")


def range_grid(data: StudyData, method: Any) -> tuple[np.ndarray, np.ndarray]:
    """(range km at 80 % success, censored) over density (rows) x detection rate (columns)
    for one method; NaN where the condition was not run."""
    from hal_sim.studies import LANDMARK_DENSITIES, LANDMARK_DETECTION_RATES, range_at_success

    km = np.full((len(LANDMARK_DENSITIES), len(LANDMARK_DETECTION_RATES)), np.nan)
    censored = np.zeros(km.shape, dtype=bool)
    for c in data.conditions:
        if c.method is not method:
            continue
        i = LANDMARK_DENSITIES.index(c.density_per_km2)
        j = LANDMARK_DETECTION_RATES.index(c.detection_rate)
        km[i, j], censored[i, j] = range_at_success(*_trial_outcomes(data, c.key))
    return km, censored


def range_heatmap(data: StudyData, path: Path) -> None:
    """One heatmap per method: the range at 80 % success over landmark density x detection
    rate, one colour scale for all, each cell labelled ("+": success stayed above 80 % at
    every distance tried, so the range is at least that)."""
    from hal_sim.studies import LANDMARK_DENSITIES, LANDMARK_DETECTION_RATES, LANDMARK_METHODS

    methods = [m for m in LANDMARK_METHODS if any(c.method is m for c in data.conditions)]
    grids = [range_grid(data, m) for m in methods]
    finite = [g[0][np.isfinite(g[0])] for g in grids]
    vmax = max([1.0] + [float(v.max()) for v in finite if len(v)])
    fig, axes = plt.subplots(
        1,
        len(methods),
        figsize=(4.6 * len(methods) + 1.4, 4.9),
        dpi=100,
        squeeze=False,
        layout="constrained",
    )
    cmap = plt.get_cmap("viridis")
    norm = matplotlib.colors.Normalize(vmin=0.0, vmax=vmax)
    image = None
    for ax, method, (km, censored) in zip(axes[0], methods, grids, strict=True):
        image = ax.imshow(km, cmap=cmap, norm=norm, origin="lower", aspect="auto")
        for i in range(km.shape[0]):
            for j in range(km.shape[1]):
                if not np.isfinite(km[i, j]):
                    continue
                text = f"{km[i, j]:.1f}" + ("+" if censored[i, j] else "")
                dark = norm(km[i, j]) < 0.55
                ax.text(j, i, text, ha="center", va="center", fontsize=9,
                        color="white" if dark else "black")  # fmt: skip
        ax.set_xticks(range(len(LANDMARK_DETECTION_RATES)))
        ax.set_xticklabels([f"{r:.0%}" for r in LANDMARK_DETECTION_RATES])
        ax.set_yticks(range(len(LANDMARK_DENSITIES)))
        ax.set_yticklabels([f"{d:g}" for d in LANDMARK_DENSITIES])
        ax.set_xlabel("Landmark detection rate")
        ax.set_title(_method_name(method))
    axes[0, 0].set_ylabel("Landmark density, per km²")
    trials = sorted({len(r) for r in data.results.values()})
    n = f"{trials[0]}" if len(trials) == 1 else f"{trials[0]}-{trials[-1]}"
    fig.suptitle(
        "Landmark study: range at 80 % success (compass ±30°, 2σ; "
        f"{n} trials per cell; +: above 80 % at every distance tried)"
    )
    if image is not None:
        bar = fig.colorbar(image, ax=list(axes[0]), fraction=0.04, pad=0.02)
        bar.set_label("Range at 80 % success: Euclidean start-goal distance, km")
    fig.savefig(path)
    plt.close(fig)


def write_range_table(summary: dict[str, Any], path: Path) -> None:
    cols = [
        "method",
        "density_per_km2",
        "detection_rate",
        "trials",
        "success_rate",
        "range_km_at_80pct",
        "range_censored",
        "mean_driven_km",
    ]
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for row in summary["conditions"]:
            w.writerow(row)
