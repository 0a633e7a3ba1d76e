"""The landmark study's figures (real matplotlib, Agg): Wilson bands, legible success-curve
panels, and the per-method heatmap of the range at 80 % success."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.figure
import numpy as np
import pytest

from hal_sim import analysis, engine, figures, study_design
from hal_sim.study_design import StudyData


def synthetic_study(trials: int = 400, seed: int = 0) -> StudyData:
    """Landmark-study results whose success falls with distance, later for denser and more
    reliably detected landmarks (only the columns the figures read are filled)."""
    rng = np.random.default_rng(seed)
    conditions = study_design.landmark_conditions()
    results = {}
    for c in conditions:
        r = np.full((trials, engine.N_RESULT), np.nan)
        d_km = rng.uniform(0.2, 12.0, trials)
        half_km = 2.0 + 0.5 * c.density_per_km2 + 4.0 * c.detection_rate  # 50 % success here
        p = 1.0 / (1.0 + np.exp((d_km - half_km) / 0.8))
        r[:, engine.RES_EUCLID_M] = d_km * 1000.0
        arrived = rng.random(trials) < p
        r[:, engine.RES_OUTCOME] = np.where(arrived, engine.OUTCOME_ARRIVED, engine.OUTCOME_LOST)
        results[c.key] = r
    # One condition never falls below 80 %: its range is censored (a lower bound).
    always = next(c for c in conditions if c.density_per_km2 == 10.0 and c.detection_rate == 1.0)
    results[always.key][:, engine.RES_OUTCOME] = engine.OUTCOME_ARRIVED
    samples = {c.key: np.zeros((trials, 0)) for c in conditions}
    return StudyData(conditions, results, samples, np.zeros(0))


@pytest.fixture
def saved(monkeypatch: pytest.MonkeyPatch) -> list[tuple[matplotlib.figure.Figure, Path]]:
    """Every figure saved, with its path, through the real savefig."""
    out: list[tuple[matplotlib.figure.Figure, Path]] = []
    real = matplotlib.figure.Figure.savefig

    def spy(self: matplotlib.figure.Figure, fname: Any, *a: Any, **k: Any) -> None:
        out.append((self, Path(fname)))
        real(self, fname, *a, **k)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    return out


def test_wilson_interval_matches_scipy() -> None:
    stats = pytest.importorskip("scipy.stats")
    k = np.array([0, 1, 5, 10, 37])
    n = np.array([10, 10, 10, 10, 50])
    lo, hi = figures.wilson_interval(k, n)
    for i in range(len(k)):
        ci = stats.binomtest(int(k[i]), int(n[i])).proportion_ci(0.95, method="wilson")
        assert lo[i] == pytest.approx(ci.low, abs=1e-4)
        assert hi[i] == pytest.approx(ci.high, abs=1e-4)
    assert lo[0] == 0.0 and hi[0] == pytest.approx(0.2775, abs=1e-4)  # not zero-width at 0 %
    assert hi[3] == 1.0 and lo[3] < 1.0


def test_success_bins_count_trials_and_skip_thin_bins() -> None:
    d = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 1.5, 1.6, 2.5, 2.6, 2.7, 2.8, 2.9])
    ok = np.array([1, 1, 1, 0, 1, 1, 1, 1, 0, 0, 1, 0, 0], dtype=bool)
    x, k, n = figures.success_bins(d, ok)
    assert x.tolist() == [0.5, 2.5]  # the 1-2 km bin has 2 trials (< 5): left out
    assert k.tolist() == [5, 1] and n.tolist() == [6, 5]


def test_range_grid_is_the_summary_range() -> None:
    data = synthetic_study()
    summary = analysis.summarise_landmarks(data)
    for method in study_design.LANDMARK_METHODS:
        km, censored = figures.range_grid(data, method)
        design = study_design
        assert km.shape == (len(design.LANDMARK_DENSITIES), len(design.LANDMARK_DETECTION_RATES))
        for row in summary["conditions"]:
            if row["method"] != method.value:
                continue
            i = study_design.LANDMARK_DENSITIES.index(row["density_per_km2"])
            j = study_design.LANDMARK_DETECTION_RATES.index(row["detection_rate"])
            assert km[i, j] == pytest.approx(row["range_km_at_80pct"])
            assert censored[i, j] == row["range_censored"]
        # Denser, better detected landmarks reach further (the synthetic truth).
        assert km[0, 0] < km[-1, -2] and km[0, 0] < km[-2, -1]


def test_fig4_writes_curves_with_bands_and_the_range_heatmap_beside_it(
    tmp_path: Path, saved: list[tuple[matplotlib.figure.Figure, Path]]
) -> None:
    data = synthetic_study()
    figures.fig4(data, tmp_path / "fig4.png")
    assert [p.name for _, p in saved] == ["fig4.png", figures.RANGE_HEATMAP_NAME]
    for _, p in saved:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 20_000

    curves, _ = saved[0]
    panels = curves.axes
    assert len(panels) == len(study_design.LANDMARK_METHODS) * len(study_design.LANDMARK_DENSITIES)
    for ax in panels:
        # Legible: one line per drawn detection rate plus the 80 % line, each with a band.
        assert len(ax.lines) == len(figures.CURVE_DETECTION_RATES) + 1
        assert len(ax.collections) == len(figures.CURVE_DETECTION_RATES)
        assert ax.get_title().endswith("landmarks/km²") and ax.get_ylim() == (0, 1.02)
    assert {ax.get_xlabel() for ax in panels[-5:]} == {"Euclidean start-goal distance, km"}
    assert panels[0].get_ylabel() == "Success rate"
    legend = curves.legends[0]
    assert [t.get_text() for t in legend.get_texts()] == ["20%", "60%", "100%", "80 % success"]
    assert "Wilson" in legend.get_title().get_text()
    # The band holds the curve: Wilson bounds around each bin's success rate.
    band = np.asarray(panels[0].collections[0].get_paths()[0].vertices)
    assert band[:, 1].min() >= 0.0 and band[:, 1].max() <= 1.0

    heat, _ = saved[1]
    maps = [ax for ax in heat.axes if ax.images]
    assert [ax.get_title() for ax in maps] == ["straight to goal", "landmark to landmark", "hybrid"]
    assert {ax.get_xlabel() for ax in maps} == {"Landmark detection rate"}
    assert maps[0].get_ylabel() == "Landmark density, per km²"
    colorbar = next(ax for ax in heat.axes if not ax.images and ax.get_ylabel())
    assert colorbar.get_ylabel() == "Range at 80 % success: Euclidean start-goal distance, km"
    assert "range at 80 % success" in heat.get_suptitle()
    for ax, method in zip(maps, study_design.LANDMARK_METHODS, strict=True):
        km, censored = figures.range_grid(data, method)
        np.testing.assert_allclose(np.asarray(ax.images[0].get_array()), km)
        labels = {t.get_text() for t in ax.texts}
        expected = {
            f"{v:.1f}" + ("+" if c else "")
            for v, c in zip(km.ravel(), censored.ravel(), strict=True)
        }
        assert labels == expected
    # The censored cell (straight to goal, 10/km², 100 %: top right) is marked as a lower bound.
    corner = next(t for t in maps[0].texts if t.get_position() == (4, 4))
    assert corner.get_text().endswith("+")
    assert sum(t.get_text().endswith("+") for ax in maps for t in ax.texts) == 1


def test_fig4_with_too_few_trials_says_so(
    tmp_path: Path, saved: list[tuple[matplotlib.figure.Figure, Path]]
) -> None:
    figures.fig4(synthetic_study(trials=3), tmp_path / "fig4.png")
    texts = [t.get_text() for ax in saved[0][0].axes for t in ax.texts]
    assert len(texts) == 15 and all("fewer than 5 trials" in t for t in texts)
    for ax in saved[0][0].axes:  # what there is: each trial a point, on a 0-12 km axis
        points = [ln for ln in ax.lines if ln.get_marker() == "x"]
        assert sum(len(ln.get_xdata()) for ln in points) == 3 * len(figures.CURVE_DETECTION_RATES)
        assert ax.get_xlim()[0] == 0.0 and ax.get_xlim()[1] >= 10.0
    assert (tmp_path / figures.RANGE_HEATMAP_NAME).exists()


def test_fig4_small_study_pools_bins_and_keeps_a_sensible_axis(
    tmp_path: Path, saved: list[tuple[matplotlib.figure.Figure, Path]]
) -> None:
    """--trials-per-condition 10: a curve in every panel, not 15 empty panels."""
    data = synthetic_study(trials=10)
    figures.fig4(data, tmp_path / "fig4.png")
    fig = saved[0][0]
    d_max = max(float(r[:, engine.RES_EUCLID_M].max()) for r in data.results.values()) / 1e3
    for ax in fig.axes:
        assert len(ax.lines) == len(figures.CURVE_DETECTION_RATES) + 1
        assert len(ax.collections) == len(figures.CURVE_DETECTION_RATES)
        assert ax.get_xlim() == (0.0, float(np.ceil(d_max)))
        assert [t.get_text() for t in ax.texts] == ["bins pooled to ≥ 5 trials"]
        for line in ax.lines[:-1]:  # every pooled point stands for at least 5 trials
            assert len(line.get_xdata()) <= 2
    assert "pooled to ≥ 5 trials" in fig.get_suptitle() and "10 trials per condition" in (
        fig.get_suptitle()
    )


def test_pooled_bins_hold_every_trial_and_at_least_the_minimum() -> None:
    rng = np.random.default_rng(1)
    d = rng.uniform(0, 12, 23)
    ok = rng.random(23) < 0.5
    x, k, n, pooled = figures.pooled_bins(d, ok)
    assert n.sum() == 23 and k.sum() == ok.sum() and n.min() >= 5 and pooled
    assert np.all(np.diff(x) > 0)
    x, k, n, pooled = figures.pooled_bins(d[:4], ok[:4])
    assert len(x) == 0 and not pooled
