"""Studies at small N: well-formed outputs, resumption, worker and Dask independence, CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from guidance.errors import UserError
from hal_sim import analysis, engine, provenance, studies, study_design
from hal_sim.studies import StudyRun


def _rows(path: Path) -> list[dict[str, str]]:
    return analysis.read_csv_rows(path)


def test_range_study_small_n_outputs(tmp_path: Path) -> None:
    summary = StudyRun("range", tmp_path, 3, seed=4, workers=1).run()
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["conditions"] == summary["conditions"]
    conds = summary["conditions"]
    assert [c["compass_2sigma_deg"] for c in conds] == [10.0, 20.0, 30.0, None]
    for c in conds:
        assert c["trials"] == 3 and c["cap_km"] == 40.0
        assert 0.0 <= c["never_lost_fraction"] <= 1.0
    # Without a compass the car is lost within a few hundred metres.
    assert 0.05 < conds[-1]["mean_lost_km"] < 1.5
    rows = _rows(tmp_path / "trials.csv")
    assert len(rows) == 12
    assert {r["outcome"] for r in rows} <= set(engine.OUTCOME_NAMES)
    png = (tmp_path / "fig3.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_landmark_study_small_n_outputs(tmp_path: Path) -> None:
    summary = StudyRun("landmarks", tmp_path, 2, seed=4, workers=1).run()
    conds = summary["conditions"]
    assert len(conds) == 75
    assert {c["method"] for c in conds} == {"straight_to_goal", "landmark_to_landmark", "hybrid"}
    for c in conds:
        assert c["trials"] == 2
        assert 0.0 <= c["success_rate"] <= 1.0
        assert c["mean_driven_km"] > 0.0
    assert len(_rows(tmp_path / "trials.csv")) == 150
    assert (tmp_path / "fig4.png").stat().st_size > 20_000
    heatmap = (tmp_path / "fig4_range_heatmap.png").read_bytes()  # beside fig4.png
    assert heatmap[:8] == b"\x89PNG\r\n\x1a\n" and len(heatmap) > 20_000
    table = _rows(tmp_path / "range_at_80pct.csv")
    assert len(table) >= 75
    assert (tmp_path / "range_at_80pct.csv").read_text().startswith("# commit ")
    for c, row in zip(conds, table, strict=True):
        lo, hi = c["success_rate_ci95"]
        assert lo <= c["success_rate"] <= hi
        assert float(row["success_ci95_low"]) == lo and float(row["success_ci95_high"]) == hi
    assert set(summary["provenance"]) == PROVENANCE_KEYS and summary["n_trials"] == 150
    # The paper's field result against the nearest condition, one pair of rows per method.
    check = summary["paper_check"]
    assert len(check) == 6 and {r["figure"] for r in check} == {"fig4"}
    assert all(r["condition"].endswith("0.5/km2, 60%") for r in check)


def test_results_do_not_depend_on_worker_count(tmp_path: Path) -> None:
    StudyRun("range", tmp_path / "one", 30, seed=9, workers=1).run()
    StudyRun("range", tmp_path / "two", 30, seed=9, workers=2).run()
    a = (tmp_path / "one" / "trials.csv").read_text()
    b = (tmp_path / "two" / "trials.csv").read_text()
    assert a == b


def test_interrupted_study_resumes_where_it_stopped(tmp_path: Path) -> None:
    StudyRun("range", tmp_path / "full", 60, seed=2, workers=1).run()
    out = tmp_path / "resumed"
    StudyRun("range", out, 60, seed=2, workers=1).run()
    chunks = sorted((out / "chunks").glob("*.npz"))
    assert len(chunks) == 12
    for c in chunks[::2]:  # as if the run had been killed before these finished
        c.unlink()
    (out / "chunks" / "compass_20__00001.npz.tmp").write_bytes(b"half a file")
    seen: list[tuple[int, int]] = []
    StudyRun("range", out, 60, seed=2, workers=1).run(lambda d, t: seen.append((d, t)))
    assert seen[0] == (6, 12)  # the six chunks on disk were not run again
    assert (out / "trials.csv").read_text() == (tmp_path / "full" / "trials.csv").read_text()


def test_a_folder_from_another_study_is_refused(tmp_path: Path) -> None:
    StudyRun("range", tmp_path, 2, seed=1, workers=1).run()
    with pytest.raises(UserError):
        StudyRun("range", tmp_path, 2, seed=2, workers=1).run()


def test_dask_local_cluster_gives_the_same_results(tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    StudyRun("range", tmp_path / "local", 25, seed=6, workers=1).run()
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:  # fmt: skip
        StudyRun("range", tmp_path / "dask", 25, seed=6, workers=1,
                 scheduler=cluster.scheduler_address).run()  # fmt: skip
    a = (tmp_path / "local" / "trials.csv").read_text()
    assert a == (tmp_path / "dask" / "trials.csv").read_text()


@pytest.mark.parametrize(
    ("base", "cond", "first", "count"),
    [(0, 0, 0, 300), (1, 74, 0, 700), (3, 2, 2**32 - 200, 200), (2**32 - 1, 9, 5, 50)],
)
def test_trial_seeds_are_numpy_seed_sequences(base: int, cond: int, first: int, count: int) -> None:
    """The vectorised hash gives SeedSequence's own words (and beyond 32 bits, its slow path)."""
    want = [
        np.random.SeedSequence([base, cond, t]).generate_state(1)[0]
        for t in range(first, first + count)
    ]
    assert studies.trial_seeds(base, cond, first, count).tolist() == want
    assert studies.trial_seeds(2**32, cond, 0, 3).tolist() == [
        np.random.SeedSequence([2**32, cond, t]).generate_state(1)[0] for t in range(3)
    ]


def test_trial_seeds_are_independent_of_chunking() -> None:
    whole = studies.trial_seeds(3, 1, 0, 100)
    parts = np.concatenate([studies.trial_seeds(3, 1, 0, 40), studies.trial_seeds(3, 1, 40, 60)])
    assert (whole == parts).all()
    assert len(set(whole.tolist())) == 100


def test_cli_json_and_errors(tmp_path: Path) -> None:
    guidance = [sys.executable, "-m", "guidance.tools.cli"]
    done = subprocess.run(
        [*guidance, "study", "range", "--trials-per-condition", "2", "--out", str(tmp_path),
         "--no-progress", "--json", "--workers", "1"],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["study"] == "range" and len(summary["conditions"]) == 4
    bad = subprocess.run(
        [*guidance, "study", "range", "--trials-per-condition", "0", "--out", str(tmp_path / "x")],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert bad.returncode == 2
    assert "Traceback" not in bad.stderr and "trials-per-condition" in bad.stderr


def test_interference_study_detection_keeps_the_truth_closer(tmp_path: Path) -> None:
    summary = StudyRun("interference", tmp_path, 40, seed=3, workers=1).run()
    by = {
        (c["compass_2sigma_deg"], c["interference_frac"] > 0, c["interference_detection"]): c
        for c in summary["conditions"]
    }
    assert len(by) == 6
    for compass in (20.0, 30.0):
        clean, off, on = by[compass, False, True], by[compass, True, False], by[compass, True, True]
        assert off["interference_rejects_per_trial"] == 0
        assert on["interference_rejects_per_trial"] > 50
        # Undetected zones corrupt the estimate silently: the truth wanders far from it.
        assert off["mean_max_true_error_m"] > 1.5 * on["mean_max_true_error_m"]
        assert off["mean_max_true_error_m"] > 3 * clean["mean_max_true_error_m"]
    assert (tmp_path / "fig_interference.png").stat().st_size > 20_000


PROVENANCE_KEYS = {"commit", "dirty", "versions", "platform", "machine", "argv"}


def test_every_output_carries_provenance_parameters_and_intervals(tmp_path: Path) -> None:
    summary = StudyRun("range", tmp_path, 6, seed=4, workers=1).run()
    prov = summary["provenance"]
    assert set(prov) == PROVENANCE_KEYS
    assert {"numpy", "numba", "filterpy"} <= set(prov["versions"])
    assert all(prov["versions"][k] for k in ("numpy", "numba", "filterpy"))
    assert prov["commit"] is None or len(prov["commit"]) == 40
    assert summary["n_trials"] == 24 and summary["seed"] == 4
    par = summary["parameters"]
    assert par["trials_per_condition"] == 6 and par["sim"]["range_cap_km"] == 40.0
    assert len(par["conditions"]) == 4 and set(par["estimator"]) == {
        c.key for c in study_design.range_conditions()
    }
    for c in summary["conditions"]:
        if c["lost_trials"] >= 2:
            lo, hi = c["mean_lost_km_ci95"]
            assert lo <= c["mean_lost_km"] <= hi
        lo, hi = c["never_lost_fraction_ci95"]
        assert lo <= c["never_lost_fraction"] <= hi
    # The comparison with the paper: one row per compass, the paper's value against the interval.
    check = summary["paper_check"]
    assert [r["condition"] for r in check][-1] == "no compass"
    none = check[-1]
    assert none["paper"] == 0.3 and none["paper_inside_ci"] == (
        none["ci95"][0] <= 0.3 <= none["ci95"][1]
    )
    cap = provenance.caption(prov, 4, 24, 6)
    for table in ("trials.csv", "paper_check.csv"):
        first = (tmp_path / table).read_text().splitlines()[0]
        assert first == f"# {cap}" and "seed 4" in first and "N = 24" in first
    assert len(_rows(tmp_path / "paper_check.csv")) == 4


def test_figures_carry_the_caption_and_the_lost_interval(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import matplotlib.figure

    texts: list[str] = []
    real = matplotlib.figure.Figure.savefig

    def spy(self: matplotlib.figure.Figure, *a: object, **k: object) -> None:
        texts.extend(t.get_text() for t in self.texts)
        for ax in self.axes:
            if ax.get_legend():
                texts.extend(t.get_text() for t in ax.get_legend().get_texts())
        real(self, *a, **k)  # type: ignore[arg-type]

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    # drawn in this process, where the spy sees them (with no other thread alive the study
    # draws its figures in forked children: the test then saw nothing, run alone)
    monkeypatch.setattr(studies, "_can_fork", lambda: False)
    StudyRun("range", tmp_path, 4, seed=2, workers=1).run()
    assert any(t.startswith("commit ") and "N = 16 (4 per condition)" in t for t in texts)
    no_compass = next(t for t in texts if t.startswith("no compass"))
    assert "mean lost" in no_compass and "[" in no_compass and "/4 lost" in no_compass


def test_provenance_without_git(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", "/nonexistent")
    prov = provenance.provenance()
    assert prov["commit"] is None and prov["dirty"] is None
    assert prov["versions"]["numpy"]
    assert provenance.caption(prov, 1, 10, 10).startswith("commit no git;")


def test_bootstrap_interval_covers_the_mean_at_its_rate() -> None:
    rng = np.random.default_rng(0)
    hits = 0
    for i in range(200):
        v = rng.exponential(2.0, 60)
        lo, hi = provenance.bootstrap_mean(v, seed=i, resamples=400) or (0.0, 0.0)
        hits += lo <= 2.0 <= hi
    assert 0.88 <= hits / 200 <= 0.99  # a 95 % interval (percentile bootstrap runs a bit short)
    assert provenance.bootstrap_mean(np.array([1.0]), seed=0) is None
