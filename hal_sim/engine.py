"""The fast study engine: one Monte Carlo trial as one numba-compiled loop.

It steps ``hal_sim.world`` and runs the estimator steps of ``hal_sim.ekf`` (the
math of ``guidance.core.model``) and the decision step of ``guidance.core.law`` —
the same functions the in-car application uses — without Python in the loop.
``hal_sim.reference`` runs the same trial through the filterpy estimator and the
``Navigator`` class; the benchmark ``benchmarks/study_speed.py`` checks that the
two agree. The trial's bookkeeping (``begin_trial``, ``end_step``,
``finish_trial``: the lost check, arrival and the next goal, the samples, the
true error) is written once, in ``hal_sim.trial`` (re-exported here), and both loops
call it.

A trial (SPEC section 5):

* range study (``study=STUDY_RANGE``): drive to random goals one after the
  other (field protocol) until lost or ``range_cap_km`` driven;
* landmark study (``study=STUDY_LANDMARKS``): one goal; success is arriving
  without ever being lost; timeout at ``cap_factor * Manhattan + extra``;
* field study (``study=STUDY_FIELD``, SPEC 5's field protocol): goals one after the other,
  each at a random distance like the landmark study's, one landmark placed for each
  (``hal_sim.field``), until lost or the time limit; the sample row holds the legs.

The relocalising arm (``SimParams.relocalise``, any study): lost no longer ends a trial. A lost
episode opens when the major axis passes the lost limit; a landmark sighted while one is open
resets the position around it (``model.reset_position``, the car's own) and closes it; the
trial ends on arrival or at its limit, as lost when an episode is still open. Up to its first
lost a trial is the paper's, step for step (the arm draws nothing of its own).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from guidance.core import law, model
from hal_sim import ekf, field, rng, world
from hal_sim.params import (
    I_COMPASS_PERIOD,
    I_COMPASS_SIGMA,
    I_DETECT,
    I_EXIT_TOL,
    I_HYBRID_SWITCH,
    I_INIT_HEAD_SIGMA,
    I_INIT_POS_SIGMA,
    I_LM_GATE,
    I_LM_PASS,
    I_LM_SIGMA,
    I_LOOKAHEAD,
    I_LOST,
    I_MAG_FRAC,
    I_MAG_NOISE,
    I_MAX_WHEEL_STEP,
    I_QUANTUM,
    I_RELOCALISE,
    I_RESET_SIGMA,
    I_REVISIT_FLOOR,
    I_REVISIT_GATE,
    I_SLIP,
    I_TABU,
    I_TRACK,
    I_TRUE_COMPASS_SIGMA,
)
from hal_sim.trial import (
    MAX_EXITS,
    MAX_MEMORY,
    N_PAPER_RESULT,
    N_RESULT,
    OUTCOME_ARRIVED,
    OUTCOME_LOST,
    OUTCOME_NAMES,
    OUTCOME_STUCK,
    OUTCOME_TIMEOUT,
    RES_AREA_KM2,
    RES_COMPASS_REJECTS,
    RES_DRIVEN_M,
    RES_EUCLID_M,
    RES_FALSE_RELOCALISATIONS,
    RES_FINAL_ERR_M,
    RES_FINAL_LOST_AT_M,
    RES_GOAL_LANDMARKS,
    RES_GOALS,
    RES_GOALS_AFTER_LOST,
    RES_INTERFERENCE_REJECTS,
    RES_LANDMARK_REJECTS,
    RES_LANDMARK_UPDATES,
    RES_LOST_AT_M,
    RES_LOST_EPISODES,
    RES_MANHATTAN_M,
    RES_MAX_ERR_M,
    RES_N_LANDMARKS,
    RES_OUTCOME,
    RES_RELOCALISATIONS,
    RES_STEPS,
    RES_TRUE_LOST_AT_M,
    RES_TURNS,
    RESULT_NAMES,
    STEP_LOST,
    STEP_NEW_GOAL,
    STEP_ON,
    STUCK_FACTOR,
    STUDY_CHANCE,
    STUDY_FIELD,
    STUDY_LANDMARKS,
    STUDY_RANGE,
    TRUE_LOST_FRACTION,
    Trial,
    begin_trial,
    end_step,
    finish_trial,
    next_goal,
    sample_distance_m,
    setup_trial,
    with_goal,
)

__all__ = [  # the trial's names, re-exported: callers use engine.*
    "MAX_EXITS",
    "MAX_MEMORY",
    "N_PAPER_RESULT",
    "N_RESULT",
    "OUTCOME_ARRIVED",
    "OUTCOME_LOST",
    "OUTCOME_NAMES",
    "OUTCOME_STUCK",
    "OUTCOME_TIMEOUT",
    "RESULT_NAMES",
    "RES_AREA_KM2",
    "RES_COMPASS_REJECTS",
    "RES_DRIVEN_M",
    "RES_EUCLID_M",
    "RES_FALSE_RELOCALISATIONS",
    "RES_FINAL_ERR_M",
    "RES_FINAL_LOST_AT_M",
    "RES_GOALS",
    "RES_GOALS_AFTER_LOST",
    "RES_GOAL_LANDMARKS",
    "RES_INTERFERENCE_REJECTS",
    "RES_LANDMARK_REJECTS",
    "RES_LANDMARK_UPDATES",
    "RES_LOST_AT_M",
    "RES_LOST_EPISODES",
    "RES_MANHATTAN_M",
    "RES_MAX_ERR_M",
    "RES_N_LANDMARKS",
    "RES_OUTCOME",
    "RES_RELOCALISATIONS",
    "RES_STEPS",
    "RES_TRUE_LOST_AT_M",
    "RES_TURNS",
    "STEP_LOST",
    "STEP_NEW_GOAL",
    "STEP_ON",
    "STUCK_FACTOR",
    "STUDY_CHANCE",
    "STUDY_FIELD",
    "STUDY_LANDMARKS",
    "STUDY_RANGE",
    "TRUE_LOST_FRACTION",
    "Trial",
    "begin_trial",
    "end_step",
    "finish_trial",
    "next_goal",
    "run_batch",
    "run_trial",
    "sample_distance_m",
    "setup_trial",
    "with_goal",
]


@njit(cache=True, error_model="numpy")
def run_trial(
    trial_seed: int,
    study: int,
    method: int,
    density: float,
    p: np.ndarray,
    samples: np.ndarray,
) -> np.ndarray:
    """Run one trial; fill ``samples`` with the major axis at ``sample_distance_m`` (field
    study: with its legs, ``hal_sim.field``)."""
    xs, ys, adj, net, lm_xy, node_start, node_lms, ts, ns, goal, area, mag = setup_trial(
        trial_seed, study, density, p
    )
    is_field = study == STUDY_FIELD
    n_active = lm_xy.shape[0] - (adj.shape[0] if is_field else 0)
    n_base = n_active
    legs = samples
    if is_field:
        samples = samples[:0]
        legs[:] = math.nan
        n_active = field.place_goal_landmark(
            goal, xs, ys, adj, lm_xy, node_start, node_lms, n_active, p
        )
    res, trial = begin_trial(study, goal, area, n_base, xs, ys, ts, p, samples)
    leg_m = res[RES_EUCLID_M]
    # Estimator state.
    x = ekf.state(ts[world.T_X], ts[world.T_Y], ts[world.T_TH])
    sp = p[I_INIT_POS_SIGMA]
    sh = p[I_INIT_HEAD_SIGMA]
    P = np.diag(np.array([sp * sp, sp * sp, sh * sh]))
    work = np.empty((3, 3))
    det = np.array([1.0, 0.0])
    # Navigator state.
    mem_xy = np.zeros((MAX_MEMORY, 2))
    mem_h = np.zeros((MAX_MEMORY, MAX_EXITS))
    mem_c = np.zeros((MAX_MEMORY, MAX_EXITS), dtype=np.int64)
    passed = np.zeros(lm_xy.shape[0], dtype=np.bool_)
    lm_seen = -np.ones(lm_xy.shape[0], dtype=np.int64)
    events = np.zeros(world.N_EVENTS)
    dirs = np.empty(4, dtype=np.int64)
    headings = np.empty(4)
    penalties = np.empty(4)
    costs = np.empty(4)
    decide_params = law.decide_params(
        p[I_REVISIT_GATE], p[I_REVISIT_FLOOR], p[I_TABU], p[I_EXIT_TOL], p[I_LM_PASS],
        p[I_LOOKAHEAD],
    )  # fmt: skip
    drive(
        res, trial, study, method, p, samples, legs, ts, ns, xs, ys, adj, net, lm_xy,
        node_start, node_lms, mag, x, P, work, det, mem_xy, mem_h, mem_c, passed, lm_seen,
        events, dirs, headings, penalties, costs, decide_params, n_active, n_base, leg_m,
    )  # fmt: skip
    return res


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp"})
def drive(
    res: np.ndarray, trial: Trial, study: int, method: int, p: np.ndarray,
    samples: np.ndarray, legs: np.ndarray, ts: np.ndarray, ns: np.ndarray, xs: np.ndarray,
    ys: np.ndarray, adj: np.ndarray, net: np.ndarray, lm_xy: np.ndarray,
    node_start: np.ndarray, node_lms: np.ndarray, mag: np.ndarray, x: np.ndarray,
    P: np.ndarray, work: np.ndarray, det: np.ndarray, mem_xy: np.ndarray, mem_h: np.ndarray,
    mem_c: np.ndarray, passed: np.ndarray, lm_seen: np.ndarray, events: np.ndarray,
    dirs: np.ndarray, headings: np.ndarray, penalties: np.ndarray, costs: np.ndarray,
    decide_params: np.ndarray, n_active: int, n_base: int, leg_m: float,
) -> None:  # fmt: skip
    """The trial's step loop, from ``run_trial``'s world and state to its result in ``res``.

    Every array is an argument, none a local: numba counts references to a function's
    local arrays at each call it passes them to (about twenty atomic operations a step
    here), and not to its arguments.
    """
    is_field = study == STUDY_FIELD
    track = p[I_TRACK]
    lm_var = p[I_LM_SIGMA] ** 2
    compass_var = p[I_COMPASS_SIGMA] ** 2
    has_compass = p[I_COMPASS_SIGMA] > 0.0
    n_mem = 0
    n_legs = 0
    mode = law.MODE_LANDMARK if method == law.METHOD_LANDMARK_TO_LANDMARK else law.MODE_GOAL
    period = p[I_COMPASS_PERIOD]
    true_sigma = p[I_TRUE_COMPASS_SIGMA]
    lm_updates = 0
    c_rej = 0
    l_rej = 0
    i_rej = 0
    step = 0
    status = STEP_ON
    readings = math.floor(step / period)  # compass readings due so far
    # The larger position eigenvalue below which the major axis is under every threshold it
    # is held against (lost; the hybrid's switch), with a margin over the rounding.
    threshold = p[I_LOST]
    if method == law.METHOD_HYBRID:
        threshold = min(threshold, p[I_HYBRID_SWITCH])
    bound_max = threshold * threshold / (4.0 * model.CHI2_2D_2SIGMA) * (1.0 - 1e-12)
    # The relocalising arm: the open lost episode, its counts, and the reset's 2-sigma circle.
    carry_on = p[I_RELOCALISE] > 0.0
    reset_var = p[I_RESET_SIGMA] * p[I_RESET_SIGMA]
    lost_open = False
    leg_lost = False
    episodes = resets = false_resets = goals_after = 0
    first_lost_m = final_lost_m = math.nan
    s0, s1 = rng.from_word(ns[world.R_RNG0]), rng.from_word(ns[world.R_RNG1])  # in registers
    while True:
        # world.world_step, its draws made here: see world.step_core. A reading is due when
        # floor((step + 1) / period) > floor(step / period); the right side is the last
        # step's left side, kept (one division a step, not two).
        due_by_next = math.floor((step + 1) / period)
        due = due_by_next > readings
        readings = due_by_next
        u_left, u_right, gauss, s0, s1 = world.draw_step(due, true_sigma, s0, s1)
        world.step_core(
            ts, ns, xs, ys, lm_xy, node_start, node_lms, lm_seen, p, due, u_left, u_right,
            gauss, events,
        )  # fmt: skip
        if events[world.EV_N_SIGHTED] > 0:
            world.detect(events, p[I_DETECT])
        step += 1
        dl, dr = events[0], events[1]
        if abs(dl) <= p[I_MAX_WHEEL_STEP] and abs(dr) <= p[I_MAX_WHEEL_STEP]:
            ekf.predict(x, P, dl, dr, track, p[I_QUANTUM], p[I_SLIP])
        if has_compass and not math.isnan(events[2]):
            z = events[2]
            if p[I_MAG_FRAC] > 0.0:
                z = world.disturb_compass(mag, adj, ns, z, p[I_MAG_NOISE])
            code = ekf.compass_update(x, P, z, compass_var, p, det)
            if code == ekf.COMPASS_GATED:
                c_rej += 1
            elif code == ekf.COMPASS_INTERFERENCE:
                i_rej += 1
        landmark_update = False
        if events[3] >= 0.0:
            k = int(events[3])
            if lost_open:  # found again: reset around the landmark sighted
                model.reset_position(x, P, lm_xy[k, 0], lm_xy[k, 1], reset_var)
                dx, dy = ts[world.T_X] - lm_xy[k, 0], ts[world.T_Y] - lm_xy[k, 1]
                resets += 1
                if dx * dx + dy * dy > model.CHI2_2D_2SIGMA * reset_var:
                    false_resets += 1  # the truth outside the reset's 2-sigma circle
                lost_open = False
                passed[k] = True
                landmark_update = True
            elif ekf.landmark_update_xy(x, P, lm_xy[k, 0], lm_xy[k, 1], lm_var, p[I_LM_GATE], work):
                lm_updates += 1
                passed[k] = True
                landmark_update = True
            else:
                l_rej += 1
        # The 2-sigma major axis only when a sample is due or it can be over a threshold:
        # its square is at most 4 chi2 (max(pxx, pyy) + |pxy|) (the larger eigenvalue's
        # bound); below every threshold any value under them decides the same (-1).
        bound = max(P[0, 0], P[1, 1]) + abs(P[0, 1])
        if ts[world.T_DRIVEN] >= trial.next_sample_m or bound > bound_max:
            major = model.major_axis_m(P)
        else:
            major = -1.0
        mode = law.next_mode(method, mode, major, p[I_HYBRID_SWITCH], landmark_update)
        status, trial = end_step(
            trial, samples, ts[world.T_DRIVEN], ts[world.T_X], ts[world.T_Y], x[0], x[1], major,
            step, study, p, carry_on,
        )  # fmt: skip
        if status >= 0:
            break
        if status == STEP_LOST:
            if not lost_open:
                lost_open = leg_lost = True
                final_lost_m = ts[world.T_DRIVEN]
                episodes += 1
                if episodes == 1:
                    first_lost_m = final_lost_m
        elif status == STEP_NEW_GOAL:
            if episodes > 0:
                goals_after += 1
            leg_lost = False
            if is_field:
                n_legs = field.record_leg(legs, n_legs, leg_m, True)
                old_x, old_y = trial.goal_x, trial.goal_y
                goal = world.node_at_distance(xs, ys, net, trial.goal, 200.0, 0.9)
                trial = with_goal(trial, goal, xs, ys)
                leg_m = math.hypot(trial.goal_x - old_x, trial.goal_y - old_y)
                n_active = field.place_goal_landmark(
                    goal, xs, ys, adj, lm_xy, node_start, node_lms, n_active, p
                )
            else:
                trial = next_goal(trial, xs, ys, net)
            passed[:] = False
        if events[4] > 0.0:
            # The intersection ahead: project the estimate to it, then decide.
            b = ns[world.R_B]
            n_exits = world.exits_at(adj, b, ns[world.R_A], dirs)
            to_b = events[5]
            ekf.sync_heading(x)  # the kept cos and sin afresh at each decision
            ix = x[0] + to_b * x[3]
            iy = x[1] + to_b * x[4]
            for e in range(n_exits):
                headings[e] = world.DIR_HEADING[dirs[e]]
            hs = headings[:n_exits]
            best, _k, _revisit, n_mem, _target = law.decide_exit(
                ix, iy, P[0, 0], P[0, 1], P[1, 1], hs, mem_xy, mem_h, mem_c, n_mem,
                passed[:n_active], lm_xy[:n_active], trial.goal_x, trial.goal_y, mode,
                decide_params, penalties, costs,
            )  # fmt: skip
            ns[world.R_C] = adj[b, dirs[best]]
    ns[world.R_RNG0], ns[world.R_RNG1] = rng.to_word(s0), rng.to_word(s1)
    if is_field:
        if status == OUTCOME_STUCK:  # the time limit, the protocol's normal end
            status = OUTCOME_TIMEOUT
        if status == OUTCOME_LOST or leg_lost:  # lost on this leg, never reached
            n_legs = field.record_leg(legs, n_legs, leg_m, False)
    if lost_open:  # the relocalising arm ended lost
        status = OUTCOME_LOST
    finish_trial(res, trial, status, ts, ns, x, step, lm_updates, c_rej, l_rej, i_rej)
    res[RES_GOAL_LANDMARKS] = n_active - n_base
    if carry_on:
        res[RES_LOST_EPISODES] = episodes
        res[RES_RELOCALISATIONS] = resets
        res[RES_FALSE_RELOCALISATIONS] = false_resets
        res[RES_GOALS_AFTER_LOST] = goals_after
        res[RES_LOST_AT_M] = first_lost_m  # where it was first lost (the paper's end)
        res[RES_FINAL_LOST_AT_M] = final_lost_m if lost_open else math.nan


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
