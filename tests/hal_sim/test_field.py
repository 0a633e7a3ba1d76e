"""The field protocol study: goals one after the other, one landmark placed for each, until
lost or the time limit; its legs and its comparison with the paper's field result."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from guidance.core.plan.navigator import Method, NavigatorConfig
from hal_sim import analysis, engine, field, field_study, params, studies, study_design, world
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
        m.value for m in study_design.LANDMARK_METHODS
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
    assert [r["method"] for r in table] == [m.value for m in study_design.LANDMARK_METHODS]
    assert (tmp_path / "field_table.csv").read_text().startswith("# commit ")
    assert (tmp_path / "fig_field.png").stat().st_size > 20_000


# ----------------------------------------------------------------------------- relocalising arm
def _arms(n: int, minutes: float, p_change: dict[int, float] | None = None) -> tuple[
    tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]
]:  # fmt: skip
    """(paper's arm, relocalising arm) on the same runs of the hybrid at the field conditions."""
    out = []
    for reloc in (False, True):
        sim = SimParams(field_time_limit_min=minutes, relocalise=reloc)
        p = params.pack(sim, params.estimator_config(sim, 30.0), NavigatorConfig(), 0.6)
        for i, v in (p_change or {}).items():
            p[i] = v
        seeds = studies.trial_seeds(8, 0, 0, n)
        out.append(engine.run_batch(
            seeds, engine.STUDY_FIELD, Method.HYBRID.code, 0.55, p, params.N_SAMPLES
        ))  # fmt: skip
    return out[0], out[1]


def test_the_relocalising_arm_is_the_papers_until_lost_then_carries_on_and_is_found() -> None:
    (paper, paper_legs), (reloc, reloc_legs) = _arms(40, 40.0)
    lost = paper[:, engine.RES_OUTCOME] == engine.OUTCOME_LOST
    assert 5 <= lost.sum() < 40
    # The arm draws nothing of its own: first lost where the paper's run ended, and a run
    # never lost is the same run to the last bit.
    np.testing.assert_array_equal(reloc[:, engine.RES_LOST_AT_M], paper[:, engine.RES_LOST_AT_M])
    n = engine.N_PAPER_RESULT
    np.testing.assert_array_equal(reloc[~lost, :n], paper[~lost, :n])
    np.testing.assert_array_equal(reloc_legs[~lost], paper_legs[~lost])
    assert (paper[:, engine.RES_LOST_EPISODES : engine.RES_FINAL_LOST_AT_M] == 0).all()
    episodes = reloc[:, engine.RES_LOST_EPISODES]
    resets = reloc[:, engine.RES_RELOCALISATIONS]
    ended_lost = reloc[:, engine.RES_OUTCOME] == engine.OUTCOME_LOST
    assert (episodes[~lost] == 0).all() and (episodes[lost] >= 1).all()
    # Each episode closes at a reset, the last one possibly never.
    np.testing.assert_array_equal(resets, episodes - ended_lost)
    assert np.isfinite(reloc[ended_lost, engine.RES_FINAL_LOST_AT_M]).all()
    assert np.isnan(reloc[~ended_lost, engine.RES_FINAL_LOST_AT_M]).all()
    # Lost runs carry on to the time limit; found again, most reach goals.
    assert (reloc[lost, engine.RES_STEPS] == round(40.0 * 60 / 0.1)).all()
    assert (reloc[lost, engine.RES_GOALS_AFTER_LOST] > 0).sum() >= lost.sum() // 2
    assert reloc[:, engine.RES_GOALS].sum() > paper[:, engine.RES_GOALS].sum()
    # Every sighting is of a true landmark within 20 m: none outside the 40 m 2-sigma circle.
    assert reloc[:, engine.RES_FALSE_RELOCALISATIONS].sum() == 0
    for r, row in zip(reloc, reloc_legs, strict=True):
        rec = row[np.isfinite(row)]
        assert (rec > 0).sum() == r[engine.RES_GOALS]
        assert (rec < 0).sum() <= 1  # only the leg running at the limit can fail
        if (rec < 0).any():
            assert rec[-1] < 0 and r[engine.RES_LOST_EPISODES] >= 1


def test_a_reset_narrower_than_the_sighting_range_counts_false_relocalisations() -> None:
    """The count is the truth against the reset's 2-sigma circle: with a 5 m sigma (10 m
    circle) some of the 20 m sightings fall outside it."""
    _, (reloc, _) = _arms(40, 40.0, {params.I_RESET_SIGMA: 5.0})
    false = reloc[:, engine.RES_FALSE_RELOCALISATIONS].sum()
    assert 0 < false < reloc[:, engine.RES_RELOCALISATIONS].sum()


def test_relocalising_field_study_outputs(tmp_path: Path) -> None:
    sim = SimParams(field_time_limit_min=30.0, relocalise=True)
    summary = StudyRun("field", tmp_path, 8, seed=2, workers=1, sim=sim).run()
    assert summary["relocalise"] is True
    head = (tmp_path / "trials.csv").read_text().splitlines()[1].split(",")
    assert head[-5:] == list(engine.RESULT_NAMES[engine.N_PAPER_RESULT :])
    rows = analysis.read_csv_rows(tmp_path / "trials.csv")
    for c in summary["conditions"]:
        r = c["relocalisation"]
        mine = [x for x in rows if x["method"] == c["method"]]
        assert r["ever_lost"] == sum(x["lost_at_m"] != "" for x in mine)
        assert r["relocalisations"] == sum(int(x["relocalisations"]) for x in mine)
        assert r["found_again"] <= r["ever_lost"] and r["false_relocalisations"] == 0
        assert r["ended_lost"] == sum(x["outcome"] == "lost" for x in mine)
    table = analysis.read_csv_rows(tmp_path / "field_table.csv")
    assert set(field_study.RELOCALISE_COLUMNS) <= set(table[0])


def test_the_papers_field_study_writes_the_papers_columns_only(tmp_path: Path) -> None:
    StudyRun("field", tmp_path, 2, seed=2, workers=1, sim=SimParams(field_time_limit_min=5.0)).run()
    head = (tmp_path / "trials.csv").read_text().splitlines()[1].split(",")
    assert head[5:] == list(engine.RESULT_NAMES[: engine.N_PAPER_RESULT])
    table = analysis.read_csv_rows(tmp_path / "field_table.csv")
    assert not set(field_study.RELOCALISE_COLUMNS) & set(table[0])


def test_cli_relocalise_flag(tmp_path: Path) -> None:
    guidance = [sys.executable, "-m", "guidance.tools.cli", "study"]
    done = subprocess.run(
        [*guidance, "field", "--relocalise", "--trials-per-condition", "2", "--out",
         str(tmp_path), "--no-progress", "--json", "--workers", "1"],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["relocalise"] is True and summary["parameters"]["sim"]["relocalise"] is True
    assert all("relocalisation" in c for c in summary["conditions"])
    bad = subprocess.run(
        [*guidance, "landmarks", "--relocalise", "--out", str(tmp_path / "x")],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert bad.returncode == 2
    assert "Traceback" not in bad.stderr and "field study only" in bad.stderr
