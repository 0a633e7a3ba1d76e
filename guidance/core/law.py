"""The intersection decision law and the navigator's bookkeeping math (SPEC section 3).

Plain numba-compiled functions on floats and arrays: ``guidance.navigator``
wraps them for the in-car app, and ``hal_sim.engine`` calls the very same
functions inside its compiled trial loop.

Decision law::

    i* = argmin_i ( |wrap(theta_i - phi_i)| + gamma_i )

``theta_i`` is the heading after taking exit i, ``phi_i`` the bearing from the
estimated position just after the intersection (``lookahead_m`` along exit i)
to the target, ``gamma_i`` the tabu penalty: ``step * (times exit i was already
taken at this intersection)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from guidance.core.model import mahalanobis_sq_2d, wrap_angle

MODE_GOAL = 0
MODE_LANDMARK = 1

METHOD_STRAIGHT_TO_GOAL = 0
METHOD_LANDMARK_TO_LANDMARK = 1
METHOD_HYBRID = 2
METHOD_NAMES = ("straight_to_goal", "landmark_to_landmark", "hybrid")


@njit(cache=True, error_model="numpy")
def exit_costs(
    x: float,
    y: float,
    exit_headings: np.ndarray,
    target_x: float,
    target_y: float,
    penalties: np.ndarray,
    lookahead_m: float,
    out: np.ndarray,
) -> int:
    """Fill ``out[i]`` with the cost of exit i; return the index of the cheapest exit."""
    best = -1
    best_cost = math.inf
    for i in range(exit_headings.shape[0]):
        th = exit_headings[i]
        px = x + lookahead_m * math.cos(th)
        py = y + lookahead_m * math.sin(th)
        phi = math.atan2(target_y - py, target_x - px)
        c = abs(wrap_angle(th - phi)) + penalties[i]
        out[i] = c
        if c < best_cost:
            best_cost = c
            best = i
    return best


@njit(cache=True, error_model="numpy")
def match_intersection(
    x: float,
    y: float,
    pxx: float,
    pxy: float,
    pyy: float,
    mem_xy: np.ndarray,
    n_mem: int,
    gate_chi2: float,
    floor_var_m2: float,
) -> int:
    """Index of the remembered intersection this one is a revisit of, or -1.

    A remembered intersection matches when its squared Mahalanobis distance from
    the current estimate, under the current position covariance (plus a floor
    for the size of an intersection), is within ``gate_chi2``; the nearest such
    one wins. So recognition gets less selective as the ellipse grows.

    The squared distance is at least dx^2 / a and dy^2 / c (a, c the diagonal of the
    covariance plus the floor), so an intersection further than the gate along either axis
    is passed over without computing it: a long drive remembers thousands. The bounds carry
    a margin of 1e-9 over the rounding, so the same intersection wins as with every distance
    computed.
    """
    a = pxx + floor_var_m2
    b = pxy
    c = pyy + floor_var_m2
    det = a * c - b * b
    if det <= 0.0:
        return -1
    best = -1
    best_d2 = gate_chi2
    ax = best_d2 * a * (1.0 + 1e-9)
    cy = best_d2 * c * (1.0 + 1e-9)
    for k in range(n_mem):
        dx = mem_xy[k, 0] - x
        if dx * dx > ax:
            continue
        dy = mem_xy[k, 1] - y
        if dy * dy > cy:
            continue
        d2 = mahalanobis_sq_2d(dx, dy, a, b, c)
        if d2 <= best_d2:
            best_d2 = d2
            best = k
            ax = best_d2 * a * (1.0 + 1e-9)
            cy = best_d2 * c * (1.0 + 1e-9)
    return best


@njit(cache=True, error_model="numpy")
def exit_penalties(
    exit_headings: np.ndarray,
    mem_headings: np.ndarray,
    mem_counts: np.ndarray,
    k: int,
    step_rad: float,
    match_tol_rad: float,
    out: np.ndarray,
) -> None:
    """Tabu penalty per exit: ``step * count`` of the same exit taken before at intersection k."""
    for i in range(exit_headings.shape[0]):
        out[i] = 0.0
        if k < 0:
            continue
        for j in range(mem_headings.shape[1]):
            if mem_counts[k, j] > 0 and abs(wrap_angle(exit_headings[i] - mem_headings[k, j])) <= (
                match_tol_rad
            ):
                out[i] = step_rad * mem_counts[k, j]
                break


@njit(cache=True, error_model="numpy")
def record_exit(
    mem_headings: np.ndarray, mem_counts: np.ndarray, k: int, heading: float, match_tol_rad: float
) -> None:
    """Count one more use of the exit with ``heading`` at remembered intersection k."""
    free = -1
    for j in range(mem_headings.shape[1]):
        if mem_counts[k, j] > 0:
            if abs(wrap_angle(heading - mem_headings[k, j])) <= match_tol_rad:
                mem_counts[k, j] += 1
                return
        elif free < 0:
            free = j
    if free >= 0:
        mem_headings[k, free] = heading
        mem_counts[k, free] = 1


@njit(cache=True, error_model="numpy")
def remember_intersection(
    mem_xy: np.ndarray, mem_headings: np.ndarray, mem_counts: np.ndarray, n_mem: int,
    x: float, y: float,
) -> tuple[int, int]:  # fmt: skip
    """Store a new intersection; when memory is full, forget the oldest half first (a long
    drive: those are far behind). Returns (its index, the new count)."""
    if n_mem >= mem_xy.shape[0]:
        half = n_mem // 2
        keep = n_mem - half
        mem_xy[:keep] = mem_xy[half:n_mem]
        mem_headings[:keep] = mem_headings[half:n_mem]
        mem_counts[:keep] = mem_counts[half:n_mem]
        mem_xy[keep:n_mem] = 0.0
        mem_headings[keep:n_mem] = 0.0
        mem_counts[keep:n_mem] = 0
        n_mem = keep
    mem_xy[n_mem, 0] = x
    mem_xy[n_mem, 1] = y
    return n_mem, n_mem + 1


@njit(cache=True, error_model="numpy")
def mark_passed(x: float, y: float, lm_xy: np.ndarray, passed: np.ndarray, radius_m: float) -> None:
    """Mark the landmarks within ``radius_m`` of (x, y) as passed (they stop being targets)."""
    r2 = radius_m * radius_m
    for m in range(lm_xy.shape[0]):
        if (lm_xy[m, 0] - x) ** 2 + (lm_xy[m, 1] - y) ** 2 <= r2:
            passed[m] = True


@njit(cache=True, error_model="numpy")
def mark_passed_along(
    x0: float, y0: float, x1: float, y1: float, lm_xy: np.ndarray, passed: np.ndarray,
    radius_m: float,
) -> None:  # fmt: skip
    """Mark the landmarks within ``radius_m`` of the road from (x0, y0) to (x1, y1): the car
    passes them on its way to an intersection still ahead."""
    dx, dy = x1 - x0, y1 - y0
    L2 = dx * dx + dy * dy
    r2 = radius_m * radius_m
    for m in range(lm_xy.shape[0]):
        px, py = lm_xy[m, 0] - x0, lm_xy[m, 1] - y0
        u = 0.0 if L2 <= 0.0 else min(1.0, max(0.0, (px * dx + py * dy) / L2))
        ex, ey = px - u * dx, py - u * dy
        if ex * ex + ey * ey <= r2:
            passed[m] = True


@njit(cache=True, error_model="numpy")
def choose_exit(
    ix: float,
    iy: float,
    headings: np.ndarray,
    mem_headings: np.ndarray,
    mem_counts: np.ndarray,
    k: int,
    passed: np.ndarray,
    lm_xy: np.ndarray,
    goal_x: float,
    goal_y: float,
    mode: int,
    params: np.ndarray,
    penalties_out: np.ndarray,
    costs_out: np.ndarray,
) -> tuple[int, int]:
    """The law at an intersection at (ix, iy) that is remembered intersection k (-1: new):
    tabu penalties, passed landmarks marked in ``passed``, the target, every exit's cost.
    Returns (best exit, target landmark index or -1 for the goal). Changes no memory."""
    tabu, tol, pass_r, lookahead = params[2], params[3], params[4], params[5]
    exit_penalties(headings, mem_headings, mem_counts, k, tabu, tol, penalties_out)
    tx, ty = goal_x, goal_y
    target = -1
    if mode == MODE_LANDMARK and lm_xy.shape[0] > 0:
        mark_passed(ix, iy, lm_xy, passed, pass_r)
        target = landmark_target(ix, iy, goal_x, goal_y, lm_xy, passed)
        if target >= 0:
            tx, ty = lm_xy[target, 0], lm_xy[target, 1]
    best = exit_costs(ix, iy, headings, tx, ty, penalties_out, lookahead, costs_out)
    return best, target


@njit(cache=True, error_model="numpy")
def evaluate_exit(
    ix: float,
    iy: float,
    pxx: float,
    pxy: float,
    pyy: float,
    headings: np.ndarray,
    mem_xy: np.ndarray,
    mem_headings: np.ndarray,
    mem_counts: np.ndarray,
    n_mem: int,
    passed: np.ndarray,
    lm_xy: np.ndarray,
    goal_x: float,
    goal_y: float,
    mode: int,
    params: np.ndarray,
    penalties_out: np.ndarray,
    costs_out: np.ndarray,
) -> tuple[int, int, int]:
    """The decision for an intersection still ahead, predicted at (ix, iy): the same law as
    ``decide_exit`` without remembering anything (the car re-evaluates it as it approaches
    and ``commit_exit`` records the exit it took once it is there). ``passed`` is marked:
    pass a copy to keep it. Returns (best exit, remembered intersection or -1, target)."""
    k = match_intersection(ix, iy, pxx, pxy, pyy, mem_xy, n_mem, params[0], params[1])
    best, target = choose_exit(
        ix, iy, headings, mem_headings, mem_counts, k, passed, lm_xy, goal_x, goal_y, mode,
        params, penalties_out, costs_out,
    )  # fmt: skip
    return best, k, target


@njit(cache=True, error_model="numpy")
def commit_exit(
    ix: float,
    iy: float,
    pxx: float,
    pxy: float,
    pyy: float,
    heading_taken: float,
    mem_xy: np.ndarray,
    mem_headings: np.ndarray,
    mem_counts: np.ndarray,
    n_mem: int,
    params: np.ndarray,
) -> tuple[int, bool, int]:
    """The car went through an intersection at (ix, iy) by the exit ``heading_taken``:
    recognise a revisit or remember a new intersection, count the exit (the tabu memory).
    Returns (intersection index, revisit, new memory count)."""
    k = match_intersection(ix, iy, pxx, pxy, pyy, mem_xy, n_mem, params[0], params[1])
    revisit = k >= 0
    if not revisit:
        k, n_mem = remember_intersection(mem_xy, mem_headings, mem_counts, n_mem, ix, iy)
    record_exit(mem_headings, mem_counts, k, heading_taken, params[3])
    return k, revisit, n_mem


@njit(cache=True, error_model="numpy")
def decide_exit(
    ix: float,
    iy: float,
    pxx: float,
    pxy: float,
    pyy: float,
    headings: np.ndarray,
    mem_xy: np.ndarray,
    mem_headings: np.ndarray,
    mem_counts: np.ndarray,
    n_mem: int,
    passed: np.ndarray,
    lm_xy: np.ndarray,
    goal_x: float,
    goal_y: float,
    mode: int,
    params: np.ndarray,
    penalties_out: np.ndarray,
    costs_out: np.ndarray,
) -> tuple[int, int, bool, int, int]:
    """The whole SPEC 3 step at an intersection reached at (ix, iy) with position covariance
    (pxx, pxy, pyy), decided and taken at once (the study engine, whose car always follows):
    recognise a revisit, remember a new intersection, tabu penalties, mark passed landmarks
    and pick the target, cost every exit, record the chosen one (``choose_exit`` between
    ``commit_exit``'s two halves, so the car's evaluate-then-commit is the same law).

    ``params`` = (revisit gate chi2, revisit floor variance m^2, tabu step rad, exit match
    tolerance rad, landmark pass radius m, lookahead m) (``DECIDE_PARAMS``).
    Returns (best exit, intersection index, revisit, new memory count, target landmark index
    or -1 for the goal).
    """
    k = match_intersection(ix, iy, pxx, pxy, pyy, mem_xy, n_mem, params[0], params[1])
    revisit = k >= 0
    if not revisit:
        k, n_mem = remember_intersection(mem_xy, mem_headings, mem_counts, n_mem, ix, iy)
    best, target = choose_exit(
        ix, iy, headings, mem_headings, mem_counts, k, passed, lm_xy, goal_x, goal_y, mode,
        params, penalties_out, costs_out,
    )  # fmt: skip
    record_exit(mem_headings, mem_counts, k, headings[best], params[3])
    return best, k, revisit, n_mem, target


DECIDE_PARAMS = ("revisit_gate_chi2", "revisit_floor_var_m2", "tabu_step_rad",
                 "exit_match_tol_rad", "landmark_pass_radius_m", "lookahead_m")  # fmt: skip
"""The order of ``decide_exit``'s ``params``."""


@njit(cache=True, error_model="numpy")
def decide_params(
    revisit_gate_chi2: float,
    revisit_floor_sigma_m: float,
    tabu_step_rad: float,
    exit_match_tol_rad: float,
    landmark_pass_radius_m: float,
    lookahead_m: float,
) -> np.ndarray:
    """``decide_exit``'s ``params`` in the order of ``DECIDE_PARAMS``: built here once, for the
    navigator (from ``NavigatorConfig``) and the study engine (from its packed parameters)."""
    return np.array([revisit_gate_chi2, revisit_floor_sigma_m**2, tabu_step_rad,
                     exit_match_tol_rad, landmark_pass_radius_m, lookahead_m])  # fmt: skip


@njit(cache=True, error_model="numpy")
def landmark_target(
    x: float,
    y: float,
    goal_x: float,
    goal_y: float,
    lm_xy: np.ndarray,
    passed: np.ndarray,
) -> int:
    """Nearest not-yet-passed landmark that is closer to the goal than the car, or -1 (the goal).

    Distances compared as ``math.hypot`` gives them; squared first, the hypotenuse computed
    only when the squares are within 1e-12 of a tie (the same answer, without two
    hypotenuses per landmark at every decision). NaN compares as there: a NaN goal skips no
    landmark (the nearest one is the target), a NaN landmark is never the target.
    """
    d_goal = math.hypot(goal_x - x, goal_y - y)
    g2 = d_goal * d_goal
    g2_hi = g2 * (1.0 + 1e-12)
    g2_lo = g2 * (1.0 - 1e-12)
    best = -1
    best_d = math.inf
    b2_hi = math.inf
    b2_lo = math.inf
    for k in range(lm_xy.shape[0]):
        if passed[k]:
            continue
        ux, uy = goal_x - lm_xy[k, 0], goal_y - lm_xy[k, 1]
        u2 = ux * ux + uy * uy
        if u2 >= g2_hi or (u2 > g2_lo and math.hypot(ux, uy) >= d_goal):
            continue
        vx, vy = lm_xy[k, 0] - x, lm_xy[k, 1] - y
        v2 = vx * vx + vy * vy
        if not v2 < b2_hi or (v2 > b2_lo and math.hypot(vx, vy) >= best_d):
            continue
        best_d = math.hypot(vx, vy)
        best = k
        b2 = best_d * best_d
        b2_hi = b2 * (1.0 + 1e-12)
        b2_lo = b2 * (1.0 - 1e-12)
    return best


@njit(cache=True, error_model="numpy")
def next_mode(
    method: int, mode: int, major_axis_m: float, switch_m: float, landmark_update: bool
) -> int:
    """Which target mode the method uses now (hybrid switches on the major axis)."""
    if method == METHOD_STRAIGHT_TO_GOAL:
        return MODE_GOAL
    if method == METHOD_LANDMARK_TO_LANDMARK:
        return MODE_LANDMARK
    if mode == MODE_GOAL and major_axis_m > switch_m:
        return MODE_LANDMARK
    if mode == MODE_LANDMARK and landmark_update and major_axis_m <= switch_m:
        return MODE_GOAL
    return mode
