"""The chance of reaching the goal: fitted on one set of simulated trials, calibrated on
1,000 others (predicted against realised success per decile, within 10 points)."""

from __future__ import annotations

import numpy as np

from guidance.core.navigator import Method, NavigatorConfig
from hal_sim import chance, engine, params, studies
from hal_sim.params import SimParams


def _trials(seed: int, n: int) -> np.ndarray:
    sim = SimParams()
    p = params.pack(sim, params.estimator_config(sim, 30.0), NavigatorConfig(), 0.6)
    seeds = studies.trial_seeds(seed, 0, 0, n)
    res, _ = engine.run_batch(seeds, engine.STUDY_LANDMARKS, Method.HYBRID.code, 0.5, p, 1)
    return res


def test_chance_of_success_is_calibrated_on_held_back_drives() -> None:
    table = chance.ChanceTable.from_results({"hybrid": _trials(seed=21, n=600)})
    held = _trials(seed=22, n=1000)  # other seeds: other cities, starts and goals
    to_go = held[:, engine.RES_EUCLID_M] / 1000.0
    predicted = np.array([table.chance("hybrid", d) for d in to_go])
    realised = (held[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED).astype(float)
    pred, real, n = chance.calibration(predicted, realised)
    assert n.sum() == 1000
    assert np.max(np.abs(pred - real)) <= 0.10, (pred.round(2), real.round(2))
    # It says something: far goals are less likely than near ones.
    assert table.chance("hybrid", 1.0) > table.chance("hybrid", 10.0) + 0.2


def test_logistic_fit_recovers_known_coefficients() -> None:
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 12, 20000)
    y = rng.random(20000) < 1 / (1 + np.exp(-(3.0 - 0.5 * d)))
    w0, w1 = chance.fit_logistic(d, y)
    assert abs(w0 - 3.0) < 0.15 and abs(w1 + 0.5) < 0.03
