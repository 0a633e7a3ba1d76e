"""The reference study engine: the same trial as ``hal_sim.engine``, run through the app's classes.

The world (city, vehicle, sensors) is stepped by the same compiled functions
with the same random numbers; estimation goes through ``PoseEstimator``
(filterpy) and decisions through ``Navigator``. It is about a hundred times
slower than the compiled engine and exists to show that the fast engine
computes what the application computes (``benchmarks/study_speed.py``, tests).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from guidance.core.estimator import EstimatorConfig, PoseEstimator
from guidance.core.messages import HeadingFix, LandmarkFix, WheelOdometry
from guidance.core.navigator import Landmark, Method, Navigator, NavigatorConfig
from hal_sim import engine, world
from hal_sim.params import (
    I_COMPASS_PERIOD,
    I_DETECT,
    I_DT,
    I_LM_CAP_EXTRA,
    I_LM_CAP_FACTOR,
    I_LM_SIGMA,
    I_MAG_FRAC,
    I_MAG_NOISE,
    I_RANGE_CAP,
)


def run_trial(
    trial_seed: int,
    study: int,
    method: Method,
    density: float,
    p: np.ndarray,
    est_cfg: EstimatorConfig,
    nav_cfg: NavigatorConfig,
    n_samples: int,
) -> tuple[np.ndarray, np.ndarray]:
    """One trial; returns (result vector as ``engine.RESULT_NAMES``, major-axis samples)."""
    xs, ys, adj, net, lm_xy, node_start, node_lms, ts, ns, goal, area, mag = engine.setup_trial(
        trial_seed, study, density, p
    )
    nx = xs.shape[0]
    res = np.full(engine.N_RESULT, math.nan)
    samples = np.full(n_samples, math.nan)
    gx, gy = float(xs[goal % nx]), float(ys[goal // nx])
    sx, sy = float(ts[world.T_X]), float(ts[world.T_Y])
    res[engine.RES_EUCLID_M] = math.hypot(gx - sx, gy - sy)
    res[engine.RES_MANHATTAN_M] = abs(gx - sx) + abs(gy - sy)
    res[engine.RES_AREA_KM2] = area
    res[engine.RES_N_LANDMARKS] = lm_xy.shape[0]
    if study == engine.STUDY_RANGE:
        cap = p[I_RANGE_CAP]
    else:
        cap = p[I_LM_CAP_FACTOR] * res[engine.RES_MANHATTAN_M] + p[I_LM_CAP_EXTRA]
    nav_cfg = replace(nav_cfg, method=method)
    est = PoseEstimator(est_cfg, sx, sy, float(ts[world.T_TH]))
    landmarks = [Landmark(k, float(lm_xy[k, 0]), float(lm_xy[k, 1])) for k in range(len(lm_xy))]
    nav = Navigator((gx, gy), nav_cfg, landmarks)
    lm_seen = -np.ones(len(lm_xy), dtype=np.int64)
    events = np.zeros(8)
    dirs = np.empty(4, dtype=np.int64)
    period = float(p[I_COMPASS_PERIOD])
    dt = float(p[I_DT])
    lm_sigma = float(p[I_LM_SIGMA])
    next_sample = 0
    lm_updates = goals = 0
    outcome = engine.OUTCOME_TIMEOUT
    step = 0
    max_err = 0.0
    while True:
        world.world_step(
            ts, ns, xs, ys, lm_xy, node_start, node_lms, lm_seen, p,
            math.floor((step + 1) / period) > math.floor(step / period), p[I_DETECT], events,
        )  # fmt: skip
        step += 1
        t = step * dt
        est.process(WheelOdometry(t, float(events[0]), float(events[1])))
        if not math.isnan(events[2]):
            z = float(events[2])
            if p[I_MAG_FRAC] > 0.0:
                z = world.disturb_compass(mag, adj, ns, z, p[I_MAG_NOISE])
            est.process(HeadingFix(t, z))
        landmark_ok = False
        if events[3] >= 0.0:
            k = int(events[3])
            fix = LandmarkFix(t, k, float(lm_xy[k, 0]), float(lm_xy[k, 1]), lm_sigma)
            landmark_ok = est.process(fix).accepted
        major = est.major_axis_m
        xe = est.x
        err = math.hypot(float(ts[world.T_X]) - xe[0], float(ts[world.T_Y]) - xe[1])
        if err > max_err:
            max_err = err
            if err > engine.TRUE_LOST_FRACTION * est.config.lost_major_axis_m and math.isnan(
                res[engine.RES_TRUE_LOST_AT_M]
            ):
                res[engine.RES_TRUE_LOST_AT_M] = float(ts[world.T_DRIVEN])
        if landmark_ok:
            lm_updates += 1
            nav.on_landmark_fix(int(events[3]), major)
        else:
            nav.update_mode(major)
        driven = float(ts[world.T_DRIVEN])
        while next_sample < n_samples and driven >= engine.sample_distance_m(
            next_sample, n_samples, p
        ):
            samples[next_sample] = major
            next_sample += 1
        x = est.x
        if major > est.config.lost_major_axis_m:
            res[engine.RES_LOST_AT_M] = driven
            outcome = engine.OUTCOME_LOST
            break
        if nav.arrived(x):
            goals += 1
            if study == engine.STUDY_LANDMARKS:
                outcome = engine.OUTCOME_ARRIVED
                break
            new_goal = world.random_node(net)
            while new_goal == goal:
                new_goal = world.random_node(net)
            goal = new_goal
            gx, gy = float(xs[goal % nx]), float(ys[goal // nx])
            nav.set_goal((gx, gy))
        if driven >= cap:
            break
        if events[4] > 0.0:
            b = int(ns[world.R_B])
            n_exits = world.exits_at(adj, b, ns[world.R_A], dirs)
            to_b = float(events[5])
            at = np.array([x[0] + to_b * math.cos(x[2]), x[1] + to_b * math.sin(x[2]), x[2]])
            headings = [float(world.DIR_HEADING[dirs[e]]) for e in range(n_exits)]
            decision = nav.decide(t, at, est.P, headings)
            ns[world.R_C] = adj[b, dirs[decision.exit_index]]
    res[engine.RES_OUTCOME] = outcome
    res[engine.RES_DRIVEN_M] = ts[world.T_DRIVEN]
    res[engine.RES_LANDMARK_UPDATES] = lm_updates
    res[engine.RES_TURNS] = ns[world.R_TURNS]
    x = est.x
    res[engine.RES_FINAL_ERR_M] = math.hypot(ts[world.T_X] - x[0], ts[world.T_Y] - x[1])
    res[engine.RES_GOALS] = goals
    res[engine.RES_STEPS] = step
    res[engine.RES_COMPASS_REJECTS] = est.rejections["compass_gate"]
    res[engine.RES_LANDMARK_REJECTS] = est.rejections["landmark_gate"]
    res[engine.RES_INTERFERENCE_REJECTS] = est.rejections["magnetic_interference"]
    res[engine.RES_MAX_ERR_M] = max_err
    return res, samples


def filter_sequence(
    est: PoseEstimator, inputs: np.ndarray, landmark_sigma_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """``engine.filter_sequence`` through the app's estimator: every step's (x, P).

    ``inputs`` rows are (dl, dr, compass or NaN, landmark x or NaN, landmark y); step i
    is stamped 0.1 (i + 1) s.
    """
    n = len(inputs)
    xs = np.empty((n, 3))
    Ps = np.empty((n, 3, 3))
    for i, row in enumerate(inputs):
        t = 0.1 * (i + 1)
        est.process(WheelOdometry(t, float(row[0]), float(row[1])))
        if not math.isnan(row[2]):
            est.process(HeadingFix(t, float(row[2])))
        if not math.isnan(row[3]):
            est.process(LandmarkFix(t, i, float(row[3]), float(row[4]), landmark_sigma_m))
        xs[i] = est.x
        Ps[i] = est.P
    return xs, Ps
