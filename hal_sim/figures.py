"""Study figures (matplotlib, Agg): fig3 (range study) and fig4 (landmark study)."""

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


def success_curve(
    distance_km: np.ndarray, success: np.ndarray, bin_km: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Success rate in distance bins (bins with fewer than 5 trials are left out)."""
    if len(distance_km) == 0:
        return np.array([]), np.array([])
    edges = np.arange(0.0, float(distance_km.max()) + bin_km, bin_km)
    idx = np.digitize(distance_km, edges) - 1
    xs, ys = [], []
    for b in range(len(edges) - 1):
        m = idx == b
        if m.sum() >= 5:
            xs.append(edges[b] + bin_km / 2)
            ys.append(float(success[m].mean()))
    return np.array(xs), np.array(ys)


def fig4(data: StudyData, path: Path) -> None:
    """One panel per method: success rate against Euclidean start-goal distance."""
    from hal_sim.studies import LANDMARK_DENSITIES, LANDMARK_DETECTION_RATES, LANDMARK_METHODS

    fig, axes = plt.subplots(1, 3, figsize=(16, 5.5), dpi=100, sharey=True)
    cmap = plt.get_cmap("viridis")
    styles = {
        r: s
        for r, s in zip(LANDMARK_DETECTION_RATES, (":", "-.", "--", (0, (5, 1)), "-"), strict=False)
    }
    for ax, method in zip(axes, LANDMARK_METHODS, strict=False):
        for c in data.conditions:
            if c.method is not method:
                continue
            r = data.results[c.key]
            x, y = success_curve(r[:, engine.RES_EUCLID_M] / 1000.0, r[:, engine.RES_OUTCOME] == 0)
            col = cmap(LANDMARK_DENSITIES.index(c.density_per_km2) / (len(LANDMARK_DENSITIES) - 1))
            ax.plot(
                x, y, color=col, linestyle=styles[c.detection_rate], linewidth=1.3,
                label=f"{c.density_per_km2:g}/km², {c.detection_rate:.0%}",
            )  # fmt: skip
        ax.axhline(0.8, color="black", linewidth=0.8, linestyle="--")
        ax.set_title(method.value.replace("_", " "))
        ax.set_xlabel("Euclidean start-goal distance, km")
        ax.set_ylim(0, 1.02)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("Success rate (goal reached, never lost)")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center right", fontsize=7, title="density, detection", ncol=1)
    fig.suptitle("Landmark study: success against distance (compass ±30°, 2σ)")
    fig.tight_layout(rect=(0, 0, 0.88, 0.95))
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
