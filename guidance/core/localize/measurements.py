"""The filter's parts (pure): filterpy's EKF with the odometry motion model as its state
transition, and the heading and position measurement functions with their Jacobians, for the
paper's 3-state model and the car model (``guidance.core.model``'s state layout)."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from guidance.core import model


@functools.cache
def ekf_class() -> Any:
    """filterpy's EKF with the odometry motion model as its state transition. filterpy (and
    the scipy.stats it imports, about a second) is imported when the first estimator is made:
    what only needs the configuration (a study's workers, ``hal_sim.params``) never waits."""
    from filterpy.kalman import ExtendedKalmanFilter

    class _Ekf(ExtendedKalmanFilter):
        x: np.ndarray

        def predict_x(self, u: np.ndarray) -> None:
            x, y, th = model.motion_predict(self.x[0], self.x[1], self.x[2], u[0], u[1])
            nxt = np.array(self.x, dtype=float)
            nxt[0], nxt[1], nxt[2] = x, y, th
            self.x = nxt

    return _Ekf


def h_heading(x: np.ndarray) -> np.ndarray:
    if x.shape[0] > model.STATE_BIAS:
        return np.array([x[2] + x[model.STATE_BIAS]])
    return np.array([x[2]])


def H_heading(x: np.ndarray) -> np.ndarray:
    if x.shape[0] > model.STATE_BIAS:
        return _padded(_H_HEADING_CAR, x.shape[0])
    return _H_HEADING


def h_position(x: np.ndarray) -> np.ndarray:
    return np.array([x[0], x[1]])


def H_position(x: np.ndarray) -> np.ndarray:
    if x.shape[0] > model.N_STATE:
        return _padded(_H_POSITION_CAR, x.shape[0])
    return _H_POSITION


def _padded(H: np.ndarray, n: int) -> np.ndarray:
    """``H`` for a state of ``n`` (the car model's with a gyro's two more: zeros for them)."""
    if H.shape[1] == n:
        return H
    return np.hstack([H, np.zeros((H.shape[0], n - H.shape[1]))])


def heading_residual(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([model.heading_residual(float(a[0]), float(b[0]))])


_H_HEADING = np.array([[0.0, 0.0, 1.0]])
_H_POSITION = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_H_HEADING_CAR = np.zeros((1, model.N_STATE_CAR))
_H_HEADING_CAR[0, model.STATE_THETA] = _H_HEADING_CAR[0, model.STATE_BIAS] = 1.0
_H_POSITION_CAR = np.hstack([_H_POSITION, np.zeros((2, model.N_STATE_CAR - model.N_STATE))])
