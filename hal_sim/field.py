"""The field protocol in the study engine (SPEC 5): successive goals, at most one landmark
placed for each, until lost or the time limit.

Compiled helpers for ``engine.run_trial`` (``study=STUDY_FIELD``):

* ``goal_slots``: the landmark database of ``world.place_landmarks`` with room for one
  landmark per node, so a goal's landmark can be added mid-trial without reallocating:
  each node's list gets one extra slot (-1: empty, skipped by ``world.world_step``);
* ``place_goal_landmark``: the landmark placed for a new goal, on one of the goal's streets
  within sighting range of it; none when that node already has one ("at most one");
* legs: each goal is a leg, recorded in the trial's sample row as +Euclidean start-goal
  metres when reached and -metres when the car got lost on the way (a leg cut by the time
  limit is not recorded: it neither failed nor succeeded).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hal_sim.params import I_FIELD_GOAL_LM, I_SIGHT_RANGE

EMPTY = -1


@njit(cache=True, error_model="numpy")
def goal_slots(
    lm_xy: np.ndarray, node_start: np.ndarray, node_lms: np.ndarray, n_nodes: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lm_xy with n_nodes spare rows, node_start, node_lms with one empty slot per node)."""
    count = lm_xy.shape[0]
    xy = np.full((count + n_nodes, 2), math.nan)
    xy[:count] = lm_xy
    start = np.empty(n_nodes + 1, dtype=np.int64)
    lms = np.empty(node_lms.shape[0] + n_nodes, dtype=np.int64)
    start[0] = 0
    k = 0
    for u in range(n_nodes):
        for j in range(node_start[u], node_start[u + 1]):
            lms[k] = node_lms[j]
            k += 1
        lms[k] = EMPTY
        k += 1
        start[u + 1] = k
    return xy, start, lms


@njit(cache=True, error_model="numpy")
def place_goal_landmark(
    goal: int,
    xs: np.ndarray,
    ys: np.ndarray,
    adj: np.ndarray,
    lm_xy: np.ndarray,
    node_start: np.ndarray,
    node_lms: np.ndarray,
    n_active: int,
    p: np.ndarray,
) -> int:
    """Place the landmark for ``goal`` (index ``n_active``); returns the new active count.

    On a random street leaving the goal, at a uniform distance within sighting range of the
    goal node (capped at the street's length), listed at the goal node: whoever drives a
    street of the goal passes it. Nothing when the protocol places none or the node has one.
    """
    slot = node_start[goal + 1] - 1
    if p[I_FIELD_GOAL_LM] <= 0.0 or node_lms[slot] != EMPTY:
        return n_active
    n_exits = 0
    for d in range(4):
        if adj[goal, d] >= 0:
            n_exits += 1
    if n_exits == 0:
        return n_active
    pick = np.random.randint(0, n_exits)
    v = -1
    for d in range(4):
        if adj[goal, d] >= 0:
            if pick == 0:
                v = adj[goal, d]
                break
            pick -= 1
    nx = xs.shape[0]
    gx, gy = xs[goal % nx], ys[goal // nx]
    vx, vy = xs[v % nx], ys[v // nx]
    length = math.hypot(vx - gx, vy - gy)
    f = np.random.random() * min(p[I_SIGHT_RANGE], length) / length
    lm_xy[n_active, 0] = gx + f * (vx - gx)
    lm_xy[n_active, 1] = gy + f * (vy - gy)
    node_lms[slot] = n_active
    return n_active + 1


@njit(cache=True, error_model="numpy")
def record_leg(legs: np.ndarray, n_legs: int, leg_m: float, reached: bool) -> int:
    """Leg ``n_legs`` into the row (if it has room); returns the new leg count."""
    if n_legs < legs.shape[0]:
        legs[n_legs] = leg_m if reached else -leg_m
    return n_legs + 1
