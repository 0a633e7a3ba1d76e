"""The field protocol study: goals one after the other, one landmark placed for each, until
lost or the time limit; its legs and its comparison with the paper's field result."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from guidance.core.navigator import Method, NavigatorConfig
from hal_sim import analysis, engine, field, field_study, params, studies, world
from hal_sim.params import SimParams
from hal_sim.studies import StudyRun


def _run(n: int, sim: SimParams, method: Method = Method.HYBRID) -> tuple[np.ndarray, np.ndarray]:
    p = params.pack(sim, params.estimator_config(sim, 30.0), NavigatorConfig(), 0.6)
    seeds = studies.trial_seeds(8, 0, 0, n)
    return engine.run_batch(seeds, engine.STUDY_FIELD, method.code, 0.55, p, params.N_SAMPLES)


def test_field_runs_drive_goal_after_goal_until_lost_or_the_time_limit() -> None:
    sim = SimParams(field_time_limit_min=20.0)
    res, legs = _run(12, sim)
    outcome = res[:, engine.RES_OUTCOME]
    assert set(outcome) <= {engine.OUTCOME_LOST, engine.OUTCOME_TIMEOUT}
    limit_steps = round(20.0 * 60 / sim.dt_s)
    timed = outcome == engine.OUTCOME_TIMEOUT
    assert timed.any() and (res[timed, engine.RES_STEPS] == limit_steps).all()
    assert (res[~timed, engine.RES_STEPS] < limit_steps).all()
    for r, row in zip(res, legs, strict=True):
        rec = row[np.isfinite(row)]
        # One leg per goal reached, then one failed leg when the run ended lost.
        assert (rec > 0).sum() == r[engine.RES_GOALS]
        assert (rec < 0).sum() == (1 if r[engine.RES_OUTCOME] == engine.OUTCOME_LOST else 0)
        if len(rec) and rec[-1] < 0:
            assert (rec[:-1] > 0).all()
        # At most one landmark per goal (the first and each new one), none twice at a node.
        assert 1 <= r[engine.RES_GOAL_LANDMARKS] <= r[engine.RES_GOALS] + 1
    assert res[:, engine.RES_GOALS].sum() > 12


def test_goal_landmarks_are_used_and_switching_them_off_keeps_the_city() -> None:
    sim = SimParams(field_time_limit_min=15.0)
    on, _ = _run(10, sim)
    off, _ = _run(10, replace(sim, field_goal_landmark=False))
    assert (off[:, engine.RES_GOAL_LANDMARKS] == 0).all()
    np.testing.assert_array_equal(on[:, engine.RES_AREA_KM2], off[:, engine.RES_AREA_KM2])
    np.testing.assert_array_equal(on[:, engine.RES_N_LANDMARKS], off[:, engine.RES_N_LANDMARKS])
    assert on[:, engine.RES_LANDMARK_UPDATES].sum() > off[:, engine.RES_LANDMARK_UPDATES].sum()


def test_a_goal_landmark_lies_on_a_street_of_the_goal_within_sighting_range() -> None:
    sim = SimParams()
    p = params.pack(sim, params.estimator_config(sim, 30.0), NavigatorConfig(), 0.6)
    xs, ys, adj, net, lm, ns0, nl, *_ = engine.setup_trial(5, engine.STUDY_FIELD, 0.55, p)
    base = lm.shape[0] - adj.shape[0]
    assert np.isnan(lm[base:]).all() and (nl == field.EMPTY).sum() >= adj.shape[0]
    active = base
    goals = np.nonzero(net)[0][:30]
    for g in goals:
        active = field.place_goal_landmark(int(g), xs, ys, adj, lm, ns0, nl, active, p)
    assert active == base + len(goals)
    assert field.place_goal_landmark(int(goals[0]), xs, ys, adj, lm, ns0, nl, active, p) == active
    nx = xs.shape[0]
    for k, g in enumerate(goals):
        gx, gy = xs[g % nx], ys[g // nx]
        x, y = lm[base + k]
        assert math.hypot(x - gx, y - gy) <= sim.sighting_range_m + 1e-9
        assert x == gx or y == gy  # on a street through the goal
        assert base + k in nl[ns0[g] : ns0[g + 1]]  # listed where the car looks
    assert world.N_TRUTH > 0


def test_run_success_distance_counts_time_limit_runs_as_never_lost() -> None:
    lost = np.array([1.0, 2.0, 3.0, 4.0, 5.0, np.nan, np.nan, np.nan, np.nan, np.nan])
    assert field_study.km_at_run_success(lost) == 2.0  # 8 of 10 runs are lost beyond 2 km
    assert field_study.km_at_run_success(np.full(10, np.nan)) == math.inf


def test_field_study_outputs_and_paper_check(tmp_path: Path) -> None:
    sim = SimParams(field_time_limit_min=15.0)
    summary = StudyRun("field", tmp_path, 6, seed=2, workers=1, sim=sim).run()
    assert [c["method"] for c in summary["conditions"]] == [
        m.value for m in studies.LANDMARK_METHODS
    ]
    for c in summary["conditions"]:
        assert c["runs"] == 6 and c["density_per_km2"] == 0.55 and c["detection_rate"] == 0.6
        lo, hi = c["leg_success_ci95"]
        assert lo <= c["leg_success"] <= hi
    assert summary["parameters"]["sim"]["field_time_limit_min"] == 15.0
    assert len(summary["paper_check"]) == 9
    assert {r["figure"] for r in summary["paper_check"]} == {"field"}
    for r in summary["paper_check"]:  # a reader's sentence, never a Python None
        assert r["note"].startswith("within: "), r
        if r["quantity"].startswith("distance 80 %") and r["ours"] is None:
            assert "never lost" in r["note"], r
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["provenance"]["versions"]["numba"]
    table = analysis.read_csv_rows(tmp_path / "field_table.csv")
    assert [r["method"] for r in table] == [m.value for m in studies.LANDMARK_METHODS]
    assert (tmp_path / "field_table.csv").read_text().startswith("# commit ")
    assert (tmp_path / "fig_field.png").stat().st_size > 20_000
