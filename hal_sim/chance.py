"""The chance of reaching the goal, from the landmark study's trials (issue 26, item 5; the
model only: not yet wired to the car's state message, screen, monitor, map or voice).

Per condition (method, landmark density, detection rate; compass 30 degrees), success is
fitted as a logistic function of the Euclidean distance to go: P = 1 / (1 + exp(-(w0 + w1
d))), by the same Newton fit as ``analysis.range_at_success``. ``ChanceTable`` holds the
coefficients and predicts for a distance still to go. Its calibration is checked against
held-back simulated trials (``calibration``): predicted against realised success per decile
of the prediction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hal_sim import engine


def fit_logistic(distance_km: np.ndarray, success: np.ndarray) -> tuple[float, float]:
    """(w0, w1) of P(success) = sigmoid(w0 + w1 d), Newton's method with a tiny ridge."""
    d = np.asarray(distance_km, dtype=float)
    y = np.asarray(success, dtype=float)
    X = np.column_stack([np.ones_like(d), d])
    m = min(max(y.mean(), 1e-3), 1 - 1e-3)
    w = np.array([math.log(m / (1 - m)), 0.0])
    for _ in range(60):
        pr = 1.0 / (1.0 + np.exp(-np.clip(X @ w, -30, 30)))
        H = (X * (pr * (1 - pr))[:, None]).T @ X + 1e-6 * np.eye(2)
        step = np.linalg.solve(H, X.T @ (y - pr) - 1e-6 * w)
        w = w + step
        if np.abs(step).max() < 1e-10:
            break
    return float(w[0]), float(w[1])


@dataclass(frozen=True, slots=True)
class ChanceTable:
    """Logistic coefficients per condition key (``studies.Condition.key``)."""

    coef: dict[str, tuple[float, float]]

    @classmethod
    def from_results(cls, results: dict[str, np.ndarray]) -> ChanceTable:
        coef = {}
        for key, r in results.items():
            ok = r[:, engine.RES_OUTCOME] == engine.OUTCOME_ARRIVED
            coef[key] = fit_logistic(r[:, engine.RES_EUCLID_M] / 1000.0, ok)
        return cls(coef)

    def chance(self, key: str, to_go_km: float) -> float:
        """Probability of reaching the goal from ``to_go_km`` (Euclidean) away."""
        w0, w1 = self.coef[key]
        return 1.0 / (1.0 + math.exp(-min(max(w0 + w1 * to_go_km, -30.0), 30.0)))


def calibration(
    predicted: np.ndarray, realised: np.ndarray, bins: int = 10
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean predicted, realised rate, trials) per decile of the prediction."""
    order = np.argsort(predicted)
    groups = np.array_split(order, bins)
    pred = np.array([predicted[g].mean() for g in groups])
    real = np.array([realised[g].mean() for g in groups])
    return pred, real, np.array([len(g) for g in groups])
