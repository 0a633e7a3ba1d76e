"""The gyro's measurement model (guidance/core/localize/gyro.py): Jacobians against finite
differences of the motion it describes, the zero-velocity update against the closed form of a
mean of readings, the integrator against the integral of a known rate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from guidance.core import model
from guidance.core.localize import gyro


def _step(x: np.ndarray, d_raw: float, diff_raw: float, angle: float, span: float) -> np.ndarray:
    """The motion the Jacobian describes: the wheels' distance (scale states), the gyro's turn
    (bias and scale states), the chord at the mid-point heading."""
    k, kd = x[model.STATE_SCALE], x[model.STATE_DIFF]
    dl, dr = 0.5 * (2 * d_raw - diff_raw), 0.5 * (2 * d_raw + diff_raw)
    cl, cr = model.corrected_wheels(dl, dr, k, kd)
    d = 0.5 * (cl + cr)
    dth = gyro.gyro_turn(angle, span, x[gyro.STATE_GYRO_BIAS], x[gyro.STATE_GYRO_SCALE])
    out = x.copy()
    out[0], out[1], out[2] = model.motion_predict(x[0], x[1], x[2], d, dth)
    return out


def test_the_gyro_step_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        x = np.zeros(gyro.N_STATE_GYRO)
        x[:3] = rng.normal(0, 50), rng.normal(0, 50), rng.uniform(-3, 3)
        x[model.STATE_SCALE] = rng.normal(0, 0.02)
        x[model.STATE_DIFF] = rng.normal(0, 3e-4)
        x[gyro.STATE_GYRO_BIAS] = rng.normal(0, 0.01)
        x[gyro.STATE_GYRO_SCALE] = rng.normal(0, 0.02)
        d_raw, diff_raw = rng.uniform(0.1, 3.0), rng.normal(0, 0.01)
        angle, span = rng.normal(0, 0.1), rng.uniform(0.01, 0.3)
        F, Q = np.eye(gyro.N_STATE_GYRO), np.zeros((gyro.N_STATE_GYRO,) * 2)
        dl, dr = d_raw - 0.5 * diff_raw, d_raw + 0.5 * diff_raw
        cl, cr = model.corrected_wheels(dl, dr, x[model.STATE_SCALE], x[model.STATE_DIFF])
        d = 0.5 * (cl + cr)
        dth = gyro.gyro_turn(angle, span, x[gyro.STATE_GYRO_BIAS], x[gyro.STATE_GYRO_SCALE])
        gyro.fill_gyro_step(x, d_raw, dr - dl, d, dth, angle, span, 1e-6, 1e-4, F, Q)
        base = _step(x, d_raw, diff_raw, angle, span)
        for j in range(gyro.N_STATE_GYRO):
            h = 1e-7
            xp = x.copy()
            xp[j] += h
            num = (_step(xp, d_raw, diff_raw, angle, span) - base) / h
            np.testing.assert_allclose(F[:3, j], num[:3], atol=2e-5, rtol=1e-4)
        assert np.allclose(Q, Q.T) and np.all(np.linalg.eigvalsh(Q) >= -1e-15)


def test_standstill_readings_teach_the_bias_as_their_mean() -> None:
    """With a wide prior and no walk, n standstill readings give the bias their mean and a
    variance of R / n (the closed form of averaging); the heading, correlated with the bias,
    moves with it."""
    rng = np.random.default_rng(2)
    cfg = gyro.GyroConfig(bias_sigma_deg_s=50.0)
    x = np.zeros(gyro.N_STATE_GYRO)
    P = np.diag([1.0, 1.0, 0.01, 4e-4, 9e-8, 1e-4, 4e-4, cfg.bias_var, 4e-4])
    P[2, gyro.STATE_GYRO_BIAS] = P[gyro.STATE_GYRO_BIAS, 2] = -0.5 * math.sqrt(0.01 * cfg.bias_var)
    true_bias = math.radians(0.2)
    var = gyro.reading_var(cfg, 0.2)
    readings = true_bias + rng.normal(0.0, math.sqrt(var), 400)
    for r in readings:
        assert gyro.zupt_update(x, P, float(r), var, model.CHI2_1D_P999) is not None
    assert x[gyro.STATE_GYRO_BIAS] == pytest.approx(np.mean(readings), abs=1e-4 * math.sqrt(var))
    assert P[gyro.STATE_GYRO_BIAS, gyro.STATE_GYRO_BIAS] == pytest.approx(var / 400, rel=0.01)
    assert np.all(np.linalg.eigvalsh(P) > 0)


def test_a_turning_car_whose_wheels_read_zero_is_gated_out() -> None:
    cfg = gyro.GyroConfig()
    x = np.zeros(gyro.N_STATE_GYRO)
    P = np.eye(gyro.N_STATE_GYRO) * 1e-6
    P[gyro.STATE_GYRO_BIAS, gyro.STATE_GYRO_BIAS] = math.radians(0.02) ** 2
    creeping = math.radians(5.0)  # 0.4 m/s round a 5 m radius
    assert gyro.zupt_update(x, P, creeping, gyro.reading_var(cfg, 0.2), model.CHI2_1D_P999) is None
    assert x[gyro.STATE_GYRO_BIAS] == 0.0


def test_a_reading_is_a_sample_of_the_whole_band_or_a_mean_over_its_period() -> None:
    """Slow readings are samples of the sensor's band (N^2 x bandwidth, whatever the rate);
    fast ones means over their period (N^2 / dt): a stop then teaches as much at 1 kHz as
    the information of the time it lasts (N^2 per second)."""
    cfg = gyro.GyroConfig()
    band = cfg.noise_var_per_s * cfg.bandwidth_hz
    assert gyro.reading_var(cfg, 0.2) == pytest.approx(band)
    assert gyro.reading_var(cfg, 0.1) == pytest.approx(band)
    assert gyro.reading_var(cfg, 0.001) / 1000 == pytest.approx(cfg.noise_var_per_s / 1.0)


def test_the_integrator_integrates_a_known_rate_and_nothing_while_standing() -> None:
    integ = gyro.GyroIntegrator()
    cfg = gyro.GyroConfig()
    t = np.arange(0.0, 10.0 + 1e-9, 0.01)
    rate = 0.3 * np.sin(t)
    for ti, ri in zip(t, rate, strict=True):
        integ.reading(float(ti), float(ri), cfg)
    angle, span, var = integ.take()
    assert var == pytest.approx(gyro.reading_var(cfg, 0.01) * 0.01 * 10.0, rel=1e-3)
    assert angle == pytest.approx(0.3 * (1 - math.cos(10.0)), abs=1e-5)
    assert span == pytest.approx(10.0)
    integ.wheel_step(10.0, zero=False)
    confirmed = []
    for ti in np.arange(10.01, 20.0, 0.01):
        integ.reading(float(ti), 0.01, cfg)
        confirmed += integ.wheel_step(float(ti), zero=True)
    assert integ.take()[0] == pytest.approx(0.0, abs=1e-3)  # the first reading of the stop
    # every reading strictly inside the zero run; the last waits for the wheels' next step,
    # which moves: it is dropped (the car may have been pulling away)
    assert len(confirmed) == len(np.arange(10.01, 20.0, 0.01)) - 1
    assert len(integ.pending) == 1
    integ.wheel_step(20.0, zero=False)
    assert integ.pending == []
    integ.reading(30.0, 1.0, cfg)  # after a gap: starts over
    assert integ.take() == (0.0, 0.0, 0.0)


def test_a_config_out_of_range_is_refused() -> None:
    with pytest.raises(ValueError, match="bias_sigma"):
        gyro.GyroConfig(bias_sigma_deg_s=0.0)
    with pytest.raises(ValueError, match="max_hold"):
        gyro.GyroConfig(max_hold_s=math.nan)
