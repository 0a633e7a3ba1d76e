"""The reference study engine: the same trial as ``hal_sim.engine``, run through the app's classes.

The world (city, vehicle, sensors) is stepped by the same compiled functions
with the same random numbers, and the trial's bookkeeping (lost check, arrival
and the next goal, samples, true error) is the engine's own; only estimation
goes through ``PoseEstimator`` (filterpy) instead of ``hal_sim.ekf``, and
decisions through ``Navigator``. It is about a hundred times
slower than the compiled engine and exists to show that the fast engine
computes what the application computes (``benchmarks/study_speed.py``, tests).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.messages import HeadingFix, LandmarkFix, WheelOdometry
from guidance.core.plan.navigator import Landmark, Method, Navigator, NavigatorConfig
from hal_sim import engine, world
from hal_sim.params import (
    I_COMPASS_PERIOD,
    I_DETECT,
    I_DT,
    I_LM_SIGMA,
    I_MAG_FRAC,
    I_MAG_NOISE,
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
    """One trial; returns (result vector as ``engine.RESULT_NAMES``, major-axis samples).

    The world and the bookkeeping are the engine's (``engine.begin_trial``,
    ``end_step``, ``finish_trial``); only the estimator and the navigator differ.
    """
    if study == engine.STUDY_FIELD:
        raise ValueError("the reference runs the range and landmark studies, not the field one")
    xs, ys, adj, net, lm_xy, node_start, node_lms, ts, ns, goal, area, mag = engine.setup_trial(
        trial_seed, study, density, p
    )
    samples = np.empty(n_samples)
    res, trial = engine.begin_trial(study, goal, area, len(lm_xy), xs, ys, ts, p, samples)
    est = PoseEstimator(est_cfg, float(ts[world.T_X]), float(ts[world.T_Y]), float(ts[world.T_TH]))
    landmarks = [Landmark(k, float(lm_xy[k, 0]), float(lm_xy[k, 1])) for k in range(len(lm_xy))]
    nav = Navigator((trial.goal_x, trial.goal_y), replace(nav_cfg, method=method), landmarks)
    lm_seen = -np.ones(len(lm_xy), dtype=np.int64)
    events = np.zeros(world.N_EVENTS)
    dirs = np.empty(4, dtype=np.int64)
    period = float(p[I_COMPASS_PERIOD])
    dt = float(p[I_DT])
    lm_sigma = float(p[I_LM_SIGMA])
    lm_updates = 0
    step = 0
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
        if landmark_ok:
            lm_updates += 1
            nav.on_landmark_fix(int(events[3]), major)
        else:
            nav.update_mode(major)
        x = est.x
        status, trial = engine.end_step(
            trial, samples, ts[world.T_DRIVEN], ts[world.T_X], ts[world.T_Y], x[0], x[1], major,
            step, study, p,
        )  # fmt: skip
        if status >= 0:
            break
        if status == engine.STEP_NEW_GOAL:
            trial = engine.next_goal(trial, xs, ys, net)
            nav.set_goal((trial.goal_x, trial.goal_y))
        if events[4] > 0.0:
            b = int(ns[world.R_B])
            n_exits = world.exits_at(adj, b, ns[world.R_A], dirs)
            to_b = float(events[5])
            at = np.array([x[0] + to_b * math.cos(x[2]), x[1] + to_b * math.sin(x[2]), x[2]])
            headings = [float(world.DIR_HEADING[dirs[e]]) for e in range(n_exits)]
            decision = nav.decide(t, at, est.P, headings)
            ns[world.R_C] = adj[b, dirs[decision.exit_index]]
    rej = est.rejections
    engine.finish_trial(
        res, trial, status, ts, ns, est.x, step, lm_updates,
        rej["compass_gate"], rej["landmark_gate"], rej["magnetic_interference"],
    )  # fmt: skip
    return res, samples


def filter_sequence(
    est: PoseEstimator, inputs: np.ndarray, landmark_sigma_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """``ekf.filter_sequence`` through the app's estimator: every step's (x, P).

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
