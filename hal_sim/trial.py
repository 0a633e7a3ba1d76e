"""One study trial's world and bookkeeping, shared by the compiled loop (``hal_sim.engine``)
and the filterpy reference (``hal_sim.reference``): setup, the result vector, the lost /
arrival / timeout checks and the next goal. ``hal_sim.engine`` re-exports every name."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from guidance.core.plan.navigator import NavigatorConfig
from hal_sim import field, world
from hal_sim.params import (
    I_AREA_MAX,
    I_AREA_MIN,
    I_ARRIVE,
    I_BLOCK_MAX,
    I_BLOCK_MIN,
    I_DEAD_FRAC,
    I_DT,
    I_FIELD_STEPS,
    I_LM_CAP_EXTRA,
    I_LM_CAP_FACTOR,
    I_LOST,
    I_MAG_BIAS_MAX,
    I_MAG_BIAS_MIN,
    I_MAG_FRAC,
    I_ONEWAY_FRAC,
    I_RANGE_CAP,
    I_SAMPLE_FIRST,
    I_TURN_V,
)

STUDY_RANGE = 0
STUDY_LANDMARKS = 1
STUDY_FIELD = 2
STUDY_CHANCE = 3
"""The landmark study whose sample row holds, after the major axis at each sample distance, the
estimated distance to the goal at the same moment (``hal_sim.chance``: the chance-of-success
table's trials). It is the landmark study in every other way: same world, goal, cap and end."""

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
    RES_GOAL_LANDMARKS,
    RES_LOST_EPISODES,
    RES_RELOCALISATIONS,
    RES_FALSE_RELOCALISATIONS,
    RES_GOALS_AFTER_LOST,
    RES_FINAL_LOST_AT_M,
    N_RESULT,
) = range(24)
N_PAPER_RESULT = RES_LOST_EPISODES
"""The results of a trial under the paper's definition (it ends at lost): ``trials.csv``'s
columns unless the study runs the relocalising arm (``SimParams.relocalise``), whose counts
follow: lost episodes, relocalisations, false relocalisations (the truth outside the reset's
2-sigma ellipse), goals reached after first lost, and where the episode still open at the
end began (NaN: the trial ended found). ``lost_at_m`` is where it was first lost."""
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
    "goal_landmarks",
    "lost_episodes",
    "relocalisations",
    "false_relocalisations",
    "goals_after_lost",
    "final_lost_at_m",
)

MAX_MEMORY = NavigatorConfig().max_intersections
"""The intersections a trial remembers: the car's own default (``law.decide_exit`` forgets the
oldest half when full, so the engine and the car must agree on the size)."""
MAX_EXITS = 4
"""The grid city's intersections have at most four exits."""


@njit(cache=True, error_model="numpy")
def sample_distance_m(i: int, n: int, p: np.ndarray) -> float:
    """Where sample i of n is taken: log-spaced from the first sample distance to the range cap."""
    first = p[I_SAMPLE_FIRST]
    return first * (p[I_RANGE_CAP] / first) ** (i / (n - 1))


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
    if study == STUDY_FIELD:
        lm_xy, node_start, node_lms = field.goal_slots(lm_xy, node_start, node_lms, adj.shape[0])
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


class Trial(NamedTuple):
    """One trial's bookkeeping between steps, shared by the compiled loop and ``hal_sim.reference``.

    Scalars only, and replaced rather than changed (``end_step`` returns the
    next one): in the compiled loop they stay in registers, where an array would
    cost two reference counts a step.
    """

    goal: int  # the goal's node
    goal_x: float
    goal_y: float
    cap_m: float  # the distance cap: timeout
    max_steps: int  # beyond this many steps the trial is stuck
    next_sample: int  # index of the next major-axis sample
    next_sample_m: float  # where it is taken (inf when all are taken)
    max_err2: float  # the largest squared true position error so far
    true_lost_at_m: float  # where the truth got lost (TRUE_LOST_FRACTION); NaN: not yet
    goals: int  # goals reached


STEP_ON = -1
"""``end_step``: the trial goes on."""
STEP_NEW_GOAL = -2
"""``end_step``: a goal was reached and the trial goes on (range study): draw the next goal
with ``next_goal`` and forget the passed landmarks. Any other status is the outcome."""
STEP_LOST = -3
"""``end_step`` with ``carry_on``: the estimate is lost and the trial goes on (the
relocalising arm, ``SimParams.relocalise``)."""


@njit(cache=True, error_model="numpy")
def begin_trial(
    study: int,
    goal: int,
    area: float,
    n_landmarks: int,
    xs: np.ndarray,
    ys: np.ndarray,
    ts: np.ndarray,
    p: np.ndarray,
    samples: np.ndarray,
) -> tuple[np.ndarray, Trial]:
    """(result vector, bookkeeping) of a trial from ``setup_trial``; ``samples`` set to NaN.

    The result holds what is known at the start (distances to the goal, area,
    landmarks); ``finish_trial`` fills in the rest.
    """
    res = np.full(N_RESULT, math.nan)
    samples[:] = math.nan
    nx = xs.shape[0]
    gx, gy = xs[goal % nx], ys[goal // nx]
    sx, sy = ts[world.T_X], ts[world.T_Y]
    res[RES_EUCLID_M] = math.hypot(gx - sx, gy - sy)
    res[RES_MANHATTAN_M] = abs(gx - sx) + abs(gy - sy)
    res[RES_AREA_KM2] = area
    res[RES_N_LANDMARKS] = n_landmarks
    res[RES_GOAL_LANDMARKS] = 0.0  # the field study's run_trial counts them
    for i in range(RES_LOST_EPISODES, RES_FINAL_LOST_AT_M):  # the relocalising arm's counts
        res[i] = 0.0
    if study == STUDY_RANGE:
        cap = p[I_RANGE_CAP]
    elif study == STUDY_FIELD:
        cap = math.inf  # the time limit ends it: OUTCOME_TIMEOUT at I_FIELD_STEPS
    else:
        cap = p[I_LM_CAP_FACTOR] * res[RES_MANHATTAN_M] + p[I_LM_CAP_EXTRA]
    if study == STUDY_FIELD:
        max_steps = int(p[I_FIELD_STEPS])
    else:
        max_steps = int(STUCK_FACTOR * cap / (p[I_TURN_V] * p[I_DT])) + 1000
    n = samples.shape[0] // 2 if study == STUDY_CHANCE else samples.shape[0]
    first_m = sample_distance_m(0, n, p) if n > 0 else math.inf
    none = 0
    return res, Trial(goal, gx, gy, cap, max_steps, none, first_m, 0.0, math.nan, none)


@njit(cache=True, error_model="numpy", inline="always")
def end_step(
    trial: Trial,
    samples: np.ndarray,
    driven_m: float,
    true_x: float,
    true_y: float,
    est_x: float,
    est_y: float,
    major: float,
    step: int,
    study: int,
    p: np.ndarray,
    carry_on: bool = False,
) -> tuple[int, Trial]:
    """The trial's bookkeeping after the estimator's updates of one step: (status, next Trial).

    In order: the true error (and where the truth got lost), the major-axis
    samples due by the distance driven, then the end of the trial: lost (major
    axis over the limit), arrived (the estimate within the arrival radius of the
    goal: the landmark study ends, the range study goes on, ``STEP_NEW_GOAL``),
    timeout (the distance cap), stuck (``Trial.max_steps``). The status is
    ``STEP_ON``, ``STEP_NEW_GOAL`` or the outcome; lost is ``STEP_LOST`` when the trial
    ``carry_on`` (the relocalising arm: no arrival while lost, the limits still hold).

    Inlined into the compiled loop; it takes scalars and the loop's own argument
    arrays only, as other arrays would be reference-counted at every step.
    """
    max_err2 = trial.max_err2
    true_lost_at_m = trial.true_lost_at_m
    ex, ey = true_x - est_x, true_y - est_y
    err2 = ex * ex + ey * ey
    if err2 > max_err2:
        max_err2 = err2
        if err2 > (TRUE_LOST_FRACTION * p[I_LOST]) ** 2 and math.isnan(true_lost_at_m):
            true_lost_at_m = driven_m
    next_sample = trial.next_sample
    next_sample_m = trial.next_sample_m
    n = samples.shape[0]
    while driven_m >= next_sample_m:
        if study == STUDY_CHANCE:
            n = samples.shape[0] // 2
            samples[n + next_sample] = math.hypot(est_x - trial.goal_x, est_y - trial.goal_y)
        samples[next_sample] = major
        next_sample += 1
        next_sample_m = sample_distance_m(next_sample, n, p) if next_sample < n else math.inf
    goals = trial.goals
    status = STEP_ON
    if major > p[I_LOST]:
        status = STEP_LOST if carry_on else OUTCOME_LOST
    elif (est_x - trial.goal_x) ** 2 + (est_y - trial.goal_y) ** 2 <= p[I_ARRIVE] ** 2:
        goals += 1
        one_goal = study in (STUDY_LANDMARKS, STUDY_CHANCE)
        status = OUTCOME_ARRIVED if one_goal else STEP_NEW_GOAL
    if status < 0:
        if driven_m >= trial.cap_m:
            status = OUTCOME_TIMEOUT
        elif step >= trial.max_steps:
            status = OUTCOME_STUCK
    return status, Trial(
        trial.goal, trial.goal_x, trial.goal_y, trial.cap_m, trial.max_steps,
        next_sample, next_sample_m, max_err2, true_lost_at_m, goals,
    )  # fmt: skip


@njit(cache=True, error_model="numpy")
def with_goal(trial: Trial, goal: int, xs: np.ndarray, ys: np.ndarray) -> Trial:
    """The same trial heading for ``goal``."""
    nx = xs.shape[0]
    return Trial(
        goal, xs[goal % nx], ys[goal // nx], trial.cap_m, trial.max_steps, trial.next_sample,
        trial.next_sample_m, trial.max_err2, trial.true_lost_at_m, trial.goals,
    )  # fmt: skip


@njit(cache=True, error_model="numpy")
def next_goal(trial: Trial, xs: np.ndarray, ys: np.ndarray, net: np.ndarray) -> Trial:
    """The range study's next goal: a random node of the network other than the one reached."""
    goal = world.random_node(net)
    while goal == trial.goal:
        goal = world.random_node(net)
    return with_goal(trial, goal, xs, ys)


@njit(cache=True, error_model="numpy")
def finish_trial(
    res: np.ndarray,
    trial: Trial,
    outcome: int,
    ts: np.ndarray,
    ns: np.ndarray,
    x: np.ndarray,
    step: int,
    lm_updates: int,
    compass_rejects: int,
    landmark_rejects: int,
    interference_rejects: int,
) -> None:
    """The rest of the result vector at the end of a trial; the counts are the estimator's."""
    res[RES_OUTCOME] = outcome
    res[RES_DRIVEN_M] = ts[world.T_DRIVEN]
    if outcome == OUTCOME_LOST:
        res[RES_LOST_AT_M] = ts[world.T_DRIVEN]
    res[RES_TRUE_LOST_AT_M] = trial.true_lost_at_m
    res[RES_TURNS] = ns[world.R_TURNS]
    res[RES_FINAL_ERR_M] = math.hypot(ts[world.T_X] - x[0], ts[world.T_Y] - x[1])
    res[RES_GOALS] = trial.goals
    res[RES_STEPS] = step
    res[RES_MAX_ERR_M] = math.sqrt(trial.max_err2)
    res[RES_LANDMARK_UPDATES] = lm_updates
    res[RES_COMPASS_REJECTS] = compass_rejects
    res[RES_LANDMARK_REJECTS] = landmark_rejects
    res[RES_INTERFERENCE_REJECTS] = interference_rejects
