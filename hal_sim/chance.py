"""The chance-of-success study (``guidance study chance``): the table the car ships
(``guidance/core/plan/chance_table.json``, read by ``guidance.core.plan.chance``) and its
calibration.

Each condition of a grid (method, landmark density, detection rate, compass 2-sigma) runs the
landmark study's trials with ``engine.STUDY_CHANCE``: at the study's sample distances along
each trial the engine records the 2-sigma major axis and the *estimated* distance still to go
(what the car knows), and the trial's outcome says whether that point led to the goal. A
logistic model in those two numbers (``guidance.core.plan.chance.FEATURES``) is fitted per condition
by Newton's method. The calibration is measured on drives the table never saw: other seeds, and
conditions drawn off the grid (the car interpolates between grid points), one point per drive at
a random moment of it: predicted against realised success per decile.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from guidance.core.plan import chance as core_chance
from guidance.core.plan.navigator import Method, NavigatorConfig
from hal_sim import engine, params
from hal_sim.provenance import wilson_pair

if TYPE_CHECKING:
    from hal_sim.study_design import Condition, StudyData

METHODS = (Method.STRAIGHT_TO_GOAL, Method.LANDMARK_TO_LANDMARK, Method.HYBRID)
DENSITIES = (0.0, 0.5, 1.0, 2.0, 5.0, 10.0)
DETECTION_RATES = (0.2, 0.6, 1.0)
COMPASS_DEG: tuple[float | None, ...] = (None, 10.0, 20.0, 30.0, 45.0)
"""The grid: the landmark study's methods and range of densities and detection rates, with
the range study's compasses (None: no compass)."""
RIDGE = 1.0
"""A ridge on the weights (a unit Gaussian prior, against the tens of thousands of points of a
condition): where every trial arrives (or none) there is no finite maximum-likelihood fit;
with it the fit stays finite and predicts about 1 (or 0)."""
MAX_STEP = 2.0
CALIBRATION_DRIVES = 2000
CALIBRATION_SEED_OFFSET = 1_000_003
"""Held-back drives are seeded from (seed + this, drive index): never a training trial's."""
MAX_CALIBRATION_GAP = 0.10
"""Issue 26: predicted against realised success within 10 points in every decile."""


def fit_logistic(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Weights of P(success) = sigmoid(X w): Newton's method with ``RIDGE`` and steps of at
    most ``MAX_STEP`` (a nearly separable condition, all but one trial arriving, would
    otherwise overshoot)."""
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    w = np.zeros(X.shape[1])
    m = min(max(float(y.mean()), 1e-3), 1 - 1e-3)
    w[0] = math.log(m / (1 - m))
    eye = RIDGE * np.eye(X.shape[1])
    for _ in range(200):
        pr = 1.0 / (1.0 + np.exp(-np.clip(X @ w, -30, 30)))
        H = (X * (pr * (1 - pr))[:, None]).T @ X + eye
        step = np.linalg.solve(H, X.T @ (y - pr) - RIDGE * w)
        size = float(np.abs(step).max())
        if size > MAX_STEP:
            step *= MAX_STEP / size
        w = w + step
        if size < 1e-9:
            break
    return w


def fit_monotone(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``fit_logistic`` with the physics kept: the chance does not rise with the distance to
    go, nor with the major axis over [0, lost]. A fit that breaks either (noise, or a
    condition where nearly every trial arrives) is refitted without that term."""
    keep = [0, 1, 2, 3]
    w = np.zeros(4)
    for _ in range(4):
        w = np.zeros(4)
        w[keep] = fit_logistic(X[:, keep], y)
        if w[1] > 0 and 1 in keep:
            keep.remove(1)
        elif (w[2] > 0 or w[2] + 2 * w[3] > 0) and 2 in keep:
            keep.remove(2)
        elif w[3] > 0 and 3 in keep:
            keep.remove(3)
        else:
            break
    return w


def feature_matrix(to_go_km: np.ndarray, axis_ratio: np.ndarray) -> np.ndarray:
    """``core_chance.features`` (the car's) for arrays: one row per point."""
    d = np.asarray(to_go_km, dtype=float)
    a = np.asarray(axis_ratio, dtype=float)
    return np.column_stack(core_chance.features(d, a))


def sample_points(
    results: np.ndarray, samples: np.ndarray, lost_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(features, success) of every recorded point of every trial (``STUDY_CHANCE`` rows)."""
    n = samples.shape[1] // 2
    major, to_go = samples[:, :n], samples[:, n:]
    ok = results[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED
    valid = np.isfinite(major) & np.isfinite(to_go) & (major < lost_m)
    y = np.broadcast_to(ok[:, None], major.shape)[valid]
    return feature_matrix(to_go[valid] / 1000.0, major[valid] / lost_m), y.astype(float)


def condition_key(method: Method, density: float, detection: float, compass: float | None) -> str:
    c = "none" if compass is None else f"{compass:g}"
    return f"{method.value}_d{density:g}_p{detection:g}_c{c}"


def build_table(data: StudyData, lost_m: float, prov: dict[str, Any]) -> core_chance.ChanceTable:
    """Fit every grid condition of a ``chance`` study."""
    coef: dict[tuple[str, float | None], tuple[tuple[tuple[float, ...], ...], ...]] = {}
    for m in METHODS:
        for c in COMPASS_DEG:
            grid = []
            for d in DENSITIES:
                row = []
                for r in DETECTION_RATES:
                    key = condition_key(m, d, r, c)
                    if key not in data.results:
                        raise ValueError(f"the chance study has no condition {key}")
                    X, y = sample_points(data.results[key], data.samples[key], lost_m)
                    w = fit_monotone(X, y) if len(y) else np.array([-30.0, 0, 0, 0])
                    row.append(tuple(float(v) for v in np.clip(w, -999.0, 999.0)))
                grid.append(tuple(row))
            coef[(m.value, c)] = tuple(grid)
    return core_chance.ChanceTable(
        DENSITIES, DETECTION_RATES, COMPASS_DEG, coef, lost_m, provenance=prov
    )


def draw_condition(rng: np.random.Generator) -> tuple[Method, float, float, float | None]:
    """A held-back drive's condition, off the grid: any method, a density log-uniform over
    the grid's range (none a fifth of the time), a detection rate and a compass between the
    grid's ends (no compass a tenth of the time)."""
    method = METHODS[int(rng.integers(len(METHODS)))]
    density = (
        0.0 if rng.random() < 0.2 else float(math.exp(rng.uniform(math.log(0.3), math.log(10))))
    )
    detection = float(rng.uniform(DETECTION_RATES[0], DETECTION_RATES[-1]))
    compass = None if rng.random() < 0.1 else float(rng.uniform(10.0, 45.0))
    return method, density, detection, compass


def held_back(
    table: core_chance.ChanceTable, seed: int, drives: int = CALIBRATION_DRIVES
) -> dict[str, np.ndarray]:
    """Predicted and realised success of ``drives`` held-back drives, one random point each."""
    sim = params.SimParams()
    nav = NavigatorConfig()
    rng = np.random.default_rng([seed, CALIBRATION_SEED_OFFSET])
    n = params.N_SAMPLES
    pred = np.empty(drives)
    real = np.empty(drives)
    for i in range(drives):
        method, density, detection, compass = draw_condition(rng)
        p = params.pack(sim, params.estimator_config(sim, compass), nav, detection)
        s = np.random.SeedSequence([seed + CALIBRATION_SEED_OFFSET, i]).generate_state(1)
        res, smp = engine.run_batch(
            s.astype(np.int64), engine.STUDY_CHANCE, method.code, density, p, 2 * n
        )
        major, to_go = smp[0, :n], smp[0, n:]
        ok = np.flatnonzero(np.isfinite(major) & (major < table.lost_major_axis_m))
        if len(ok):
            k = int(rng.choice(ok))
            a, d = float(major[k]), float(to_go[k])
        else:  # ended before its first sample: the start
            a, d = 0.0, float(res[0, engine.RES_EUCLID_M])
        pred[i] = table.chance(method.value, density, detection, compass, d, a)
        real[i] = float(res[0, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED)
    return {"predicted": pred, "realised": real}


def calibration(
    predicted: np.ndarray, realised: np.ndarray, bins: int = 10
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean predicted, realised rate, drives) per decile of the prediction."""
    order = np.argsort(predicted, kind="stable")
    groups = np.array_split(order, bins)
    pred = np.array([predicted[g].mean() for g in groups])
    real = np.array([realised[g].mean() for g in groups])
    return pred, real, np.array([len(g) for g in groups])


def conditions() -> list[Condition]:
    from hal_sim.study_design import Condition

    out: list[Condition] = []
    for m in METHODS:
        for c in COMPASS_DEG:
            for d in DENSITIES:
                for r in DETECTION_RATES:
                    out.append(Condition(len(out), condition_key(m, d, r, c), "chance", m, c, d, r))
    return out


def summarise(
    data: StudyData, out: Path, seed: int, prov: dict[str, Any], cap: str
) -> dict[str, Any]:
    """Fit the table (``chance_table.json``), measure its calibration on held-back drives
    (``fig_chance.png``) and return the summary."""
    lost_m = float(params.estimator_config(params.SimParams(), 30.0).lost_major_axis_m)
    trials = min(len(r) for r in data.results.values())
    table = build_table(
        data, lost_m, {**prov, "study": "chance", "seed": seed, "trials_per_condition": trials}
    )

    (out / "chance_table.json").write_text(json.dumps(table.as_json(), indent=1) + "\n")
    hb = held_back(table, seed)
    pred, real, n = calibration(hb["predicted"], hb["realised"])
    gap = float(np.max(np.abs(pred - real)))
    rows = []
    for p_, r_, k in zip(pred, real, n, strict=True):
        hits = round(float(r_) * int(k))
        rows.append({"predicted": float(p_), "realised": float(r_), "drives": int(k),
                     "realised_ci95": wilson_pair(hits, int(k))})  # fmt: skip
    fig_chance(rows, table, out / "fig_chance.png", cap)
    return {
        "study": "chance",
        "table": str(out / "chance_table.json"),
        "conditions": len(data.conditions),
        "calibration": {
            "drives": int(n.sum()),
            "seed_offset": CALIBRATION_SEED_OFFSET,
            "deciles": rows,
            "max_gap": gap,
            "within_10_points": gap <= MAX_CALIBRATION_GAP,
            "mean_predicted": float(hb["predicted"].mean()),
            "realised_rate": float(hb["realised"].mean()),
        },
    }


def fig_chance(
    rows: list[dict[str, Any]], table: core_chance.ChanceTable, path: Path, caption: str
) -> None:
    """Calibration (predicted against realised, per decile, with Wilson intervals) and the
    chance against the distance to go for a few conditions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5.2), dpi=110)
    pred = np.array([r["predicted"] for r in rows])
    real = np.array([r["realised"] for r in rows])
    lo = np.array([r["realised_ci95"][0] for r in rows])
    hi = np.array([r["realised_ci95"][1] for r in rows])
    ax.fill_between([0, 1], [-0.1, 0.9], [0.1, 1.1], color="0.9", label="within 10 points")
    ax.plot([0, 1], [0, 1], color="0.4", linewidth=1, label="perfect calibration")
    drives = sum(r["drives"] for r in rows)
    ax.errorbar(pred, real, yerr=[real - lo, hi - real], fmt="o", color="C0", capsize=3,
                label=f"deciles of {drives} held-back drives (95 %)")  # fmt: skip
    ax.set(xlim=(0, 1), ylim=(0, 1.02), xlabel="predicted chance of reaching the goal",
           ylabel="share of drives that reached it",
           title="Calibration on held-back drives")  # fmt: skip
    ax.legend(loc="upper left", fontsize=8)
    d = np.linspace(0.2, 12.0, 120)
    for k, (m, dens, comp) in enumerate(
        ((Method.STRAIGHT_TO_GOAL, 0.0, 20.0), (Method.STRAIGHT_TO_GOAL, 0.0, 30.0),
         (Method.HYBRID, 0.5, 30.0), (Method.HYBRID, 2.0, 30.0), (Method.HYBRID, 0.5, 45.0))
    ):  # fmt: skip
        for axis_m, style in ((5.0, "-"), (50.0, "--")):
            y = [table.chance(m.value, dens, 0.6, comp, x * 1000, axis_m) for x in d]
            label = f"{m.value}, {dens:g}/km², ±{comp:g}°" if style == "-" else None
            bx.plot(d, y, style, color=f"C{k}", label=label)
    bx.plot([], [], "k-", label="2σ major axis 5 m")
    bx.plot([], [], "k--", label="2σ major axis 50 m")
    bx.set(xlim=(0, 12), ylim=(0, 1.02), xlabel="estimated distance to go (km, straight line)",
           ylabel="chance of reaching the goal", title="The table (60 % detection)")  # fmt: skip
    bx.legend(loc="lower left", fontsize=7)
    fig.suptitle("Chance of reaching the goal")
    fig.text(0.01, 0.005, caption, fontsize=6, color="0.35")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path)
    plt.close(fig)
