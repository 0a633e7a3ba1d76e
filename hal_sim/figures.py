"""Study figures (matplotlib, Agg): fig3 (range study); fig4 and its range heatmap
(landmark study)."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection

from hal_sim import engine
from hal_sim.provenance import wilson_interval

if TYPE_CHECKING:
    from hal_sim.study_design import StudyData

Fit = tuple[float, float, float, float]
"""``analysis.fit_growth``'s coefficients."""


def fig3(
    data: StudyData,
    path: Path,
    max_lines: int = 400,
    title: str = "Range without a map: uncertainty growth (thin: trials; thick: fitted growth)",
    caption: str = "",
    seed: int = 0,
    fits: Sequence[Fit | None] | None = None,
) -> None:
    """Major axis against distance driven for every trial, a fitted curve per condition; the
    legend gives each mean lost distance with its 95 % bootstrap interval. ``fits``: each
    condition's ``analysis.fit_growth``, when the caller has them (else fitted here)."""
    from hal_sim.analysis import fit_growth, growth_curve
    from hal_sim.study_design import LOSS_LINE_M

    fig, ax = plt.subplots(figsize=(9, 6), dpi=110)
    colours = plt.get_cmap("tab10")
    d = data.sample_km
    x_max = 1.0
    for i, c in enumerate(data.conditions):
        s = data.samples[c.key]
        col = colours(i)
        # every trial (thinned above max_lines so the PNG stays readable)
        rows = s if len(s) <= max_lines else s[:: max(1, len(s) // max_lines)]
        # One collection of the condition's lines, drawn as separate lines (each its own
        # alpha) but one artist: a thousand ax.plot calls took two of the study's seconds.
        lines = [
            np.column_stack((d[ok], row[ok])) for row in rows if (ok := np.isfinite(row)).any()
        ]
        ax.add_collection(LineCollection(lines, colors=[col], alpha=0.06, linewidths=0.6))
        if fits is None:
            fit = fit_growth(np.broadcast_to(d, s.shape).ravel(), s.ravel())
        else:
            fit = fits[i]
        if np.isfinite(s).any():
            x_max = max(x_max, float(d[np.isfinite(s).any(axis=0)].max()))
        lost = data.results[c.key][:, engine.RES_LOST_AT_M]
        lost = lost[np.isfinite(lost)] / 1000.0
        label = f"{c.label}: " + lost_label(lost, len(s), seed + c.index)
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
    ax.legend(loc="lower right", fontsize=9, title="mean lost distance (95 % bootstrap)")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    _caption(fig, caption)
    fig.savefig(path)
    plt.close(fig)


def lost_label(lost_km: np.ndarray, trials: int, seed: int) -> str:
    """ "mean lost 9.5 km [9.2, 9.8], 1000/1000 lost" or "never lost (0/1000)"."""
    from hal_sim.provenance import bootstrap_mean

    if len(lost_km) == 0:
        return f"never lost (0/{trials})"
    ci = bootstrap_mean(lost_km, seed)
    inter = "" if ci is None else f" [{ci[0]:.2f}, {ci[1]:.2f}]"
    return f"mean lost {lost_km.mean():.2f} km{inter}, {len(lost_km)}/{trials} lost"


def _caption(fig: Any, text: str) -> None:
    if text:
        fig.text(0.005, 0.003, text, fontsize=6.5, color="0.35", ha="left", va="bottom")


MIN_BIN_TRIALS = 5
"""Distance bins with fewer trials than this are left out of the success curves."""
RANGE_HEATMAP_NAME = "fig4_range_heatmap.png"
"""Written beside fig4.png by ``fig4``."""
CURVE_DETECTION_RATES = (0.2, 0.6, 1.0)
"""Detection rates drawn in fig4's panels: three bands per panel stay apart; every rate is
in the heatmap."""


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


def pooled_bins(
    distance_km: np.ndarray,
    success: np.ndarray,
    bin_km: float = 1.0,
    min_trials: int = MIN_BIN_TRIALS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(mean distance km, successes, trials, pooled): 1 km bins, each joined with the next
    until it holds ``min_trials`` (a short last group joins the one before), so a small study
    still draws a curve; pooled is True when any bin spans more than ``bin_km``. Empty with
    fewer than ``min_trials`` trials in all."""
    d = np.asarray(distance_km, dtype=float)
    y = np.asarray(success, dtype=bool)
    if len(d) < min_trials:
        return np.array([]), np.array([]), np.array([]), False
    idx = np.floor(d / bin_km).astype(int)
    groups: list[list[int]] = []
    current: list[int] = []
    for b in range(int(idx.max()) + 1):
        current.append(b)
        if np.isin(idx, current).sum() >= min_trials:
            groups.append(current)
            current = []
    if current:
        groups[-1] += current
    xs, ks, ns = [], [], []
    for g in groups:
        m = np.isin(idx, g)
        xs.append(float(d[m].mean()))
        ks.append(int(y[m].sum()))
        ns.append(int(m.sum()))
    pooled = any(len([b for b in g if (idx == b).any()]) > 1 for g in groups)
    return np.array(xs), np.array(ks), np.array(ns), pooled


def _trial_outcomes(data: StudyData, key: str) -> tuple[np.ndarray, np.ndarray]:
    r = data.results[key]
    return r[:, engine.RES_EUCLID_M] / 1000.0, r[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED


def success_panel(
    ax: Any, distance_km: np.ndarray, success: np.ndarray, colour: Any
) -> tuple[bool, bool]:
    """One success curve with its Wilson band in pooled 1 km bins, or, with fewer than
    ``MIN_BIN_TRIALS`` trials, the trials themselves as points (1: reached). Returns
    (pooled, too_few)."""
    x, k, n, pooled = pooled_bins(distance_km, success)
    if len(x) == 0:
        if len(distance_km):
            ax.plot(distance_km, success.astype(float), ls="none", marker="x", ms=5, color=colour)
        return False, True
    lo, hi = wilson_interval(k, n)
    if len(x) == 1:  # one pooled bin: a point with its interval (a band would have no width)
        yerr = np.array([k / n - lo, hi - k / n]).reshape(2, 1)
        ax.errorbar(x, k / n, yerr=yerr, color=colour, marker="o", ms=4, capsize=0, lw=1.6)
        return pooled, False
    ax.fill_between(x, lo, hi, color=colour, alpha=0.2, lw=0)
    ax.plot(x, k / n, color=colour, lw=1.6, marker=".", ms=4)
    return pooled, False


def fig4(
    data: StudyData,
    path: Path,
    rates: tuple[float, ...] = CURVE_DETECTION_RATES,
    caption: str = "",
    heatmap: bool = True,
) -> None:
    """Success against start-goal distance with 95 % Wilson bands, one panel per method and
    landmark density, a curve per detection rate in ``rates``; and, beside it
    (``RANGE_HEATMAP_NAME``, unless ``heatmap`` is false: ``range_heatmap`` draws it alone),
    the per-method heatmap of the range at 80 % success.

    Small studies draw what there is: bins are pooled to ``MIN_BIN_TRIALS`` trials (the
    panel says so), and a condition with fewer trials than that is drawn trial by trial."""
    from hal_sim.study_design import LANDMARK_DENSITIES, LANDMARK_METHODS, SUCCESS_TARGET

    methods = [m for m in LANDMARK_METHODS if any(c.method is m for c in data.conditions)]
    fig, axes = plt.subplots(
        len(methods),
        len(LANDMARK_DENSITIES),
        figsize=(3.4 * len(LANDMARK_DENSITIES) + 1.6, 2.9 * len(methods) + 1.4),
        dpi=100,
        sharex=True,
        sharey=True,
        squeeze=False,
    )
    cmap = plt.get_cmap("plasma")
    colour = {rate: cmap(0.8 * i / max(1, len(rates) - 1)) for i, rate in enumerate(rates)}
    d_max = max([1.0] + [float(np.nanmax(r[:, engine.RES_EUCLID_M])) / 1000.0
                         for r in data.results.values() if len(r)])  # fmt: skip
    any_pooled = False
    for row, method in enumerate(methods):
        for col, density in enumerate(LANDMARK_DENSITIES):
            ax = axes[row, col]
            pooled = too_few = False
            for c in data.conditions:
                if c.method is not method or c.density_per_km2 != density:
                    continue
                if c.detection_rate not in colour:
                    continue
                p, f = success_panel(ax, *_trial_outcomes(data, c.key), colour[c.detection_rate])
                pooled, too_few = pooled or p, too_few or f
            any_pooled = any_pooled or pooled
            note = []
            if too_few:
                note.append(f"fewer than {MIN_BIN_TRIALS} trials:\neach trial a point (1: reached)")
            elif pooled:
                note.append(f"bins pooled to ≥ {MIN_BIN_TRIALS} trials")
            if note:
                ax.text(0.97, 0.04, "\n".join(note), ha="right", va="bottom",
                        transform=ax.transAxes, fontsize=7, color="0.3")  # fmt: skip
            ax.axhline(SUCCESS_TARGET, color="black", linewidth=0.8, linestyle="--")
            ax.set_ylim(0, 1.02)
            ax.set_xlim(0.0, float(np.ceil(d_max)))
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
    trials = sorted({len(r) for r in data.results.values()})
    bins = "1 km bins"
    if any_pooled:
        need = MIN_BIN_TRIALS * int(np.ceil(d_max))
        bins += (
            f" pooled to ≥ {MIN_BIN_TRIALS} trials\n({trials[0]} trials per condition; "
            f"about {need} give every 1 km bin its own point)"
        )
    fig.suptitle(
        "Landmark study: success (goal reached, never lost) against distance, "
        f"compass ±30° (2σ), {bins}",
        fontsize=10 if any_pooled else 12,
    )
    fig.tight_layout(rect=(0, 0.02, 0.9, 0.97))
    _caption(fig, caption)
    fig.savefig(path)
    plt.close(fig)
    if heatmap:
        range_heatmap(data, path.with_name(RANGE_HEATMAP_NAME), caption)


def _method_name(method: Any) -> str:
    return str(method.value).replace("_", " ")


def range_grid(data: StudyData, method: Any) -> tuple[np.ndarray, np.ndarray]:
    """(range km at 80 % success, censored) over density (rows) x detection rate (columns)
    for one method; NaN where the condition was not run."""
    from hal_sim.analysis import range_at_success
    from hal_sim.study_design import LANDMARK_DENSITIES, LANDMARK_DETECTION_RATES

    km = np.full((len(LANDMARK_DENSITIES), len(LANDMARK_DETECTION_RATES)), np.nan)
    censored = np.zeros(km.shape, dtype=bool)
    for c in data.conditions:
        if c.method is not method:
            continue
        i = LANDMARK_DENSITIES.index(c.density_per_km2)
        j = LANDMARK_DETECTION_RATES.index(c.detection_rate)
        km[i, j], censored[i, j] = range_at_success(*_trial_outcomes(data, c.key))
    return km, censored


def range_heatmap(data: StudyData, path: Path, caption: str = "") -> None:
    """One heatmap per method: the range at 80 % success over landmark density x detection
    rate, one colour scale for all, each cell labelled ("+": success stayed above 80 % at
    every distance tried, so the range is at least that)."""
    from hal_sim.study_design import LANDMARK_DENSITIES, LANDMARK_DETECTION_RATES, LANDMARK_METHODS

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
    _caption(fig, caption)
    fig.savefig(path)
    plt.close(fig)


def write_range_table(summary: dict[str, Any], path: Path, header: str = "") -> None:
    """range_at_80pct.csv: per condition, success with its Wilson interval and the range at
    80 % success; the first line is the provenance (a ``#`` comment)."""
    cols = [
        "method",
        "density_per_km2",
        "detection_rate",
        "trials",
        "success_rate",
        "success_ci95_low",
        "success_ci95_high",
        "range_km_at_80pct",
        "range_censored",
        "mean_driven_km",
    ]
    with path.open("w", newline="") as f:
        if header:
            f.write(f"# {header}\n")
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for row in summary["conditions"]:
            ci = row.get("success_rate_ci95") or [None, None]
            w.writerow({**row, "success_ci95_low": ci[0], "success_ci95_high": ci[1]})
