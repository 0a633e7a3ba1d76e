"""The fast study engine: one Monte Carlo trial as one numba-compiled loop.

It steps ``hal_sim.world`` and runs the estimator math of ``guidance.core.model``
and the navigator math of ``guidance.core.law`` — the same functions the in-car
application uses — without Python in the loop. ``hal_sim.reference`` runs the
same trial through the filterpy estimator and the ``Navigator`` class; the
benchmark ``benchmarks/study_speed.py`` checks that the two agree.

A trial (SPEC section 5):

* range study (``study=STUDY_RANGE``): drive to random goals one after the
  other (field protocol) until lost or ``range_cap_km`` driven;
* landmark study (``study=STUDY_LANDMARKS``): one goal; success is arriving
  without ever being lost; timeout at ``cap_factor * Manhattan + extra``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from guidance.core import law, model
from hal_sim import world
from hal_sim.params import (
    I_AREA_MAX,
    I_AREA_MIN,
    I_ARRIVE,
    I_BLOCK_MAX,
    I_BLOCK_MIN,
    I_COMPASS_GATE,
    I_COMPASS_PERIOD,
    I_COMPASS_SIGMA,
    I_DEAD_FRAC,
    I_DETECT,
    I_DT,
    I_EXIT_TOL,
    I_HYBRID_SWITCH,
    I_INIT_HEAD_SIGMA,
    I_INIT_POS_SIGMA,
    I_LM_CAP_EXTRA,
    I_LM_CAP_FACTOR,
    I_LM_GATE,
    I_LM_PASS,
    I_LM_SIGMA,
    I_LOOKAHEAD,
    I_LOST,
    I_MAG_ALPHA,
    I_MAG_BIAS_MAX,
    I_MAG_BIAS_MIN,
    I_MAG_DETECT,
    I_MAG_FRAC,
    I_MAG_NOISE,
    I_MAG_OFF,
    I_MAG_ON,
    I_MAX_WHEEL_STEP,
    I_ONEWAY_FRAC,
    I_QUANTUM,
    I_RANGE_CAP,
    I_REVISIT_FLOOR,
    I_REVISIT_GATE,
    I_SAMPLE_FIRST,
    I_SLIP,
    I_TABU,
    I_TRACK,
    I_TURN_V,
)

STUDY_RANGE = 0
STUDY_LANDMARKS = 1

OUTCOME_ARRIVED = 0
OUTCOME_LOST = 1
OUTCOME_TIMEOUT = 2
OUTCOME_STUCK = 3
OUTCOME_NAMES = ("arrived", "lost", "timeout", "stuck")
# A trial that has not covered its distance cap after this many steps at the turn
# speed is stuck (a controller fault, not a navigation result): it is ended and counted.
STUCK_FACTOR = 3.0

# Result vector.
(
    RES_OUTCOME,
    RES_DRIVEN_M,
    RES_EUCLID_M,
    RES_MANHATTAN_M,
    RES_LOST_AT_M,
    RES_LANDMARK_UPDATES,
    RES_TURNS,
    RES_FINAL_ERR_M,
    RES_GOALS,
    RES_STEPS,
    RES_AREA_KM2,
    RES_N_LANDMARKS,
    RES_COMPASS_REJECTS,
    RES_LANDMARK_REJECTS,
    RES_INTERFERENCE_REJECTS,
    RES_MAX_ERR_M,
    RES_TRUE_LOST_AT_M,
    N_RESULT,
) = range(18)
TRUE_LOST_FRACTION = 0.5
"""The truth is "lost" when the true position error exceeds this fraction of the lost
major axis (the radius of the ellipse at which the estimate declares itself lost)."""
RESULT_NAMES = (
    "outcome",
    "driven_m",
    "euclid_m",
    "manhattan_m",
    "lost_at_m",
    "landmark_updates",
    "turns",
    "final_error_m",
    "goals_reached",
    "steps",
    "area_km2",
    "n_landmarks",
    "compass_rejects",
    "landmark_rejects",
    "interference_rejects",
    "max_true_error_m",
    "true_lost_at_m",
)

MAX_MEMORY = 4096
MAX_EXITS = 4


@njit(cache=True, error_model="numpy")
def sample_distance_m(i: int, n: int, p: np.ndarray) -> float:
    """Where sample i of n is taken: log-spaced from the first sample distance to the range cap."""
    first = p[I_SAMPLE_FIRST]
    return first * (p[I_RANGE_CAP] / first) ** (i / (n - 1))


@njit(cache=True, error_model="numpy")
def predict(
    x: np.ndarray,
    P: np.ndarray,
    P_next: np.ndarray,
    F: np.ndarray,
    G: np.ndarray,
    Q: np.ndarray,
    dl: float,
    dr: float,
    track: float,
    quantum: float,
    slip: float,
) -> None:
    """EKF predict from wheel increments (SPEC 2), in place, with the functions filterpy gets."""
    d, dth = model.odometry_increment(dl, dr, track)
    model.motion_jacobians(x[2], dl, dr, track, F, G)
    model.process_noise(
        G, model.wheel_noise_var(dl, quantum, slip), model.wheel_noise_var(dr, quantum, slip), Q
    )
    x[0], x[1], x[2] = model.motion_predict(x[0], x[1], x[2], d, dth)
    model.predict_covariance(P, F, Q, P_next)
    P[:, :] = P_next


COMPASS_ACCEPTED = 0
COMPASS_GATED = 1
COMPASS_INTERFERENCE = 2


@njit(cache=True, error_model="numpy")
def compass_update(
    x: np.ndarray, P: np.ndarray, z: float, var: float, p: np.ndarray, det: np.ndarray
) -> int:
    """Compass update in place, after the interference detector and the gate.

    ``det`` holds the detector's (level, active) between calls. While it is
    active readings are rejected: the heading is left to odometry and its
    variance grows honestly, instead of being dragged by a biased field.
    Returns COMPASS_ACCEPTED, COMPASS_GATED or COMPASS_INTERFERENCE.
    """
    y, S = model.heading_innovation(x, P, z, var)
    nis = y * y / S
    if p[I_MAG_DETECT] > 0.0:
        level, active = model.interference_update(
            det[0], det[1] > 0.0, nis, p[I_MAG_ALPHA], p[I_MAG_ON], p[I_MAG_OFF]
        )
        det[0] = level
        det[1] = 1.0 if active else 0.0
        if active:
            return COMPASS_INTERFERENCE
    if nis > p[I_COMPASS_GATE]:
        return COMPASS_GATED
    model.heading_update(x, P, y, S, var)
    return COMPASS_ACCEPTED


@njit(cache=True, error_model="numpy")
def landmark_update_xy(
    x: np.ndarray,
    P: np.ndarray,
    zx: float,
    zy: float,
    var: float,
    gate: float,
    work: np.ndarray,
) -> bool:
    """Gated landmark position update in place; False when the gate rejects it."""
    y0, y1, s00, s01, s11 = model.position_innovation(x, P, zx, zy, var)
    if model.mahalanobis_sq_2d(y0, y1, s00, s01, s11) > gate:
        return False
    model.position_update(x, P, y0, y1, s00, s01, s11, var, work)
    return True


@njit(cache=True, error_model="numpy")
def filter_sequence(
    x0: np.ndarray, P0: np.ndarray, inputs: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Run the study engine's filter over fixed inputs; returns every step's (x, P).

    ``inputs`` rows are (dl, dr, compass or NaN, landmark x or NaN, landmark y).
    Used to check the engine against the app's filterpy estimator.
    """
    n = inputs.shape[0]
    xs = np.empty((n, 3))
    Ps = np.empty((n, 3, 3))
    x = x0.copy()
    P = P0.copy()
    P_next = np.empty((3, 3))
    F = np.empty((3, 3))
    G = np.empty((3, 2))
    Q = np.empty((3, 3))
    work = np.empty((3, 3))
    det = np.array([1.0, 0.0])
    for i in range(n):
        dl, dr = inputs[i, 0], inputs[i, 1]
        if abs(dl) <= p[I_MAX_WHEEL_STEP] and abs(dr) <= p[I_MAX_WHEEL_STEP]:
            predict(x, P, P_next, F, G, Q, dl, dr, p[I_TRACK], p[I_QUANTUM], p[I_SLIP])
        if p[I_COMPASS_SIGMA] > 0.0 and not math.isnan(inputs[i, 2]):
            compass_update(x, P, inputs[i, 2], p[I_COMPASS_SIGMA] ** 2, p, det)
        if not math.isnan(inputs[i, 3]):
            landmark_update_xy(
                x, P, inputs[i, 3], inputs[i, 4], p[I_LM_SIGMA] ** 2, p[I_LM_GATE], work
            )
        xs[i] = x
        Ps[i] = P
    return xs, Ps


@njit(cache=True, error_model="numpy")
def setup_trial(
    trial_seed: int, study: int, density: float, p: np.ndarray
) -> tuple[
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    int,
    float,
    np.ndarray,
]:
    """Seed, build the city and landmarks, place the car; return the world and the first goal.

    Range study: city area log-uniform, goals uniform over the city. Landmark
    study: city area uniform (more large cities, so long trips occur), and the
    goal is the node nearest a point at a distance drawn uniformly between
    0.2 km and 0.9 of the city's diagonal, in a random direction: success can
    then be read against distance evenly.
    """
    world.seed(trial_seed)
    if study == STUDY_RANGE:
        area = math.exp(np.random.uniform(math.log(p[I_AREA_MIN]), math.log(p[I_AREA_MAX])))
    else:
        area = np.random.uniform(p[I_AREA_MIN], p[I_AREA_MAX])
    aspect = np.random.uniform(0.7, 1.4)
    xs, ys, adj, net = world.make_city(
        area, aspect, p[I_BLOCK_MIN], p[I_BLOCK_MAX], p[I_DEAD_FRAC], p[I_ONEWAY_FRAC]
    )
    lm_xy, node_start, node_lms = world.place_landmarks(xs, ys, adj, net, density)
    start = world.random_node(net)
    if study == STUDY_RANGE:
        goal = world.random_node(net)
        while goal == start:
            goal = world.random_node(net)
    else:
        goal = world.node_at_distance(xs, ys, net, start, 200.0, 0.9)
    ts, ns = world.init_truth(xs, ys, adj, start, p)
    mag = world.make_interference(adj, p[I_MAG_FRAC], p[I_MAG_BIAS_MIN], p[I_MAG_BIAS_MAX])
    return xs, ys, adj, net, lm_xy, node_start, node_lms, ts, ns, goal, area, mag


@njit(cache=True, error_model="numpy")
def run_trial(
    trial_seed: int,
    study: int,
    method: int,
    density: float,
    p: np.ndarray,
    samples: np.ndarray,
) -> np.ndarray:
    """Run one trial; fill ``samples`` with the major axis at ``sample_distance_m``."""
    xs, ys, adj, net, lm_xy, node_start, node_lms, ts, ns, goal, area, mag = setup_trial(
        trial_seed, study, density, p
    )
    res = np.full(N_RESULT, math.nan)
    nx = xs.shape[0]
    gx, gy = xs[goal % nx], ys[goal // nx]
    sx, sy = ts[world.T_X], ts[world.T_Y]
    res[RES_EUCLID_M] = math.hypot(gx - sx, gy - sy)
    res[RES_MANHATTAN_M] = abs(gx - sx) + abs(gy - sy)
    res[RES_AREA_KM2] = area
    res[RES_N_LANDMARKS] = lm_xy.shape[0]
    if study == STUDY_RANGE:
        cap = p[I_RANGE_CAP]
    else:
        cap = p[I_LM_CAP_FACTOR] * res[RES_MANHATTAN_M] + p[I_LM_CAP_EXTRA]

    max_steps = int(STUCK_FACTOR * cap / (p[I_TURN_V] * p[I_DT])) + 1000
    # Estimator state.
    x = np.array([sx, sy, ts[world.T_TH]])
    sp = p[I_INIT_POS_SIGMA]
    sh = p[I_INIT_HEAD_SIGMA]
    P = np.diag(np.array([sp * sp, sp * sp, sh * sh]))
    P_next = np.empty((3, 3))
    F = np.empty((3, 3))
    G = np.empty((3, 2))
    Q = np.empty((3, 3))
    work = np.empty((3, 3))
    track = p[I_TRACK]
    lm_var = p[I_LM_SIGMA] ** 2
    compass_var = p[I_COMPASS_SIGMA] ** 2
    has_compass = p[I_COMPASS_SIGMA] > 0.0
    # Navigator state.
    mem_xy = np.zeros((MAX_MEMORY, 2))
    mem_h = np.zeros((MAX_MEMORY, MAX_EXITS))
    mem_c = np.zeros((MAX_MEMORY, MAX_EXITS), dtype=np.int64)
    n_mem = 0
    passed = np.zeros(lm_xy.shape[0], dtype=np.bool_)
    mode = law.MODE_LANDMARK if method == law.METHOD_LANDMARK_TO_LANDMARK else law.MODE_GOAL
    lm_seen = -np.ones(lm_xy.shape[0], dtype=np.int64)
    events = np.zeros(8)
    dirs = np.empty(4, dtype=np.int64)
    headings = np.empty(4)
    penalties = np.empty(4)
    costs = np.empty(4)
    decide_params = np.array(
        [p[I_REVISIT_GATE], p[I_REVISIT_FLOOR] ** 2, p[I_TABU], p[I_EXIT_TOL], p[I_LM_PASS],
         p[I_LOOKAHEAD]]
    )  # fmt: skip
    period = p[I_COMPASS_PERIOD]
    n_samples = samples.shape[0]
    for i in range(n_samples):
        samples[i] = math.nan
    next_sample = 0
    next_sample_m = sample_distance_m(0, n_samples, p)
    lm_updates = 0
    goals = 0
    c_rej = 0
    l_rej = 0
    i_rej = 0
    max_err2 = 0.0
    true_lost2 = (TRUE_LOST_FRACTION * p[I_LOST]) ** 2
    arrive2 = p[I_ARRIVE] ** 2
    det = np.array([1.0, 0.0])
    outcome = OUTCOME_TIMEOUT
    step = 0
    while True:
        world.world_step(
            ts,
            ns,
            xs,
            ys,
            lm_xy,
            node_start,
            node_lms,
            lm_seen,
            p,
            math.floor((step + 1) / period) > math.floor(step / period),
            p[I_DETECT],
            events,
        )
        step += 1
        dl, dr = events[0], events[1]
        if abs(dl) <= p[I_MAX_WHEEL_STEP] and abs(dr) <= p[I_MAX_WHEEL_STEP]:
            predict(x, P, P_next, F, G, Q, dl, dr, track, p[I_QUANTUM], p[I_SLIP])
        if has_compass and not math.isnan(events[2]):
            z = events[2]
            if p[I_MAG_FRAC] > 0.0:
                z = world.disturb_compass(mag, adj, ns, z, p[I_MAG_NOISE])
            code = compass_update(x, P, z, compass_var, p, det)
            if code == COMPASS_GATED:
                c_rej += 1
            elif code == COMPASS_INTERFERENCE:
                i_rej += 1
        landmark_update = False
        if events[3] >= 0.0:
            k = int(events[3])
            if landmark_update_xy(x, P, lm_xy[k, 0], lm_xy[k, 1], lm_var, p[I_LM_GATE], work):
                lm_updates += 1
                passed[k] = True
                landmark_update = True
            else:
                l_rej += 1
        ex, ey = ts[world.T_X] - x[0], ts[world.T_Y] - x[1]
        err2 = ex * ex + ey * ey
        if err2 > max_err2:
            max_err2 = err2
            if err2 > true_lost2 and math.isnan(res[RES_TRUE_LOST_AT_M]):
                res[RES_TRUE_LOST_AT_M] = ts[world.T_DRIVEN]
        major = model.major_axis_m(P)
        mode = law.next_mode(method, mode, major, p[I_HYBRID_SWITCH], landmark_update)
        driven = ts[world.T_DRIVEN]
        while driven >= next_sample_m:
            samples[next_sample] = major
            next_sample += 1
            next_sample_m = (
                sample_distance_m(next_sample, n_samples, p)
                if next_sample < n_samples
                else math.inf
            )
        if major > p[I_LOST]:
            res[RES_LOST_AT_M] = driven
            outcome = OUTCOME_LOST
            break
        if (x[0] - gx) ** 2 + (x[1] - gy) ** 2 <= arrive2:
            goals += 1
            if study == STUDY_LANDMARKS:
                outcome = OUTCOME_ARRIVED
                break
            new_goal = world.random_node(net)
            while new_goal == goal:
                new_goal = world.random_node(net)
            goal = new_goal
            gx, gy = xs[goal % nx], ys[goal // nx]
            passed[:] = False
        if driven >= cap:
            outcome = OUTCOME_TIMEOUT
            break
        if step >= max_steps:
            outcome = OUTCOME_STUCK
            break
        if events[4] > 0.0:
            # The intersection ahead: project the estimate to it, then decide.
            b = ns[world.R_B]
            n_exits = world.exits_at(adj, b, ns[world.R_A], dirs)
            to_b = events[5]
            ix = x[0] + to_b * math.cos(x[2])
            iy = x[1] + to_b * math.sin(x[2])
            for e in range(n_exits):
                headings[e] = world.DIR_HEADING[dirs[e]]
            hs = headings[:n_exits]
            best, _k, _revisit, n_mem, _target = law.decide_exit(
                ix, iy, P[0, 0], P[0, 1], P[1, 1], hs, mem_xy, mem_h, mem_c, n_mem, passed,
                lm_xy, gx, gy, mode, decide_params, penalties, costs,
            )  # fmt: skip
            ns[world.R_C] = adj[b, dirs[best]]
    res[RES_OUTCOME] = outcome
    res[RES_DRIVEN_M] = ts[world.T_DRIVEN]
    res[RES_LANDMARK_UPDATES] = lm_updates
    res[RES_TURNS] = ns[world.R_TURNS]
    res[RES_FINAL_ERR_M] = math.hypot(ts[world.T_X] - x[0], ts[world.T_Y] - x[1])
    res[RES_GOALS] = goals
    res[RES_STEPS] = step
    res[RES_COMPASS_REJECTS] = c_rej
    res[RES_LANDMARK_REJECTS] = l_rej
    res[RES_INTERFERENCE_REJECTS] = i_rej
    res[RES_MAX_ERR_M] = math.sqrt(max_err2)
    return res


@njit(cache=True, error_model="numpy")
def run_batch(
    seeds: np.ndarray, study: int, method: int, density: float, p: np.ndarray, n_samples: int
) -> tuple[np.ndarray, np.ndarray]:
    """Run many trials in one compiled call: (results [n, N_RESULT], samples [n, n_samples])."""
    n = seeds.shape[0]
    out = np.empty((n, N_RESULT))
    samples = np.empty((n, n_samples))
    for i in range(n):
        out[i] = run_trial(seeds[i], study, method, density, p, samples[i])
    return out, samples
