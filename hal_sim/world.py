"""The simulated world (SPEC section 4): city grid, vehicle, controllers and sensors.

Everything here is compiled with numba and draws from numba's random
generator, so one ``np.random.seed(seed)`` inside a compiled call fixes a whole
trial: the fast study engine (``hal_sim.engine``), the filterpy reference
engine (``hal_sim.reference``) and the in-car simulation (``hal_sim.simworld``)
step the same world with the same numbers.

City: streets on a grid; node ``n = j * nx + i`` sits at ``(xs[i], ys[j])``;
``adj[n, d]`` is the node reached by driving from n in direction d (0 east,
1 north, 2 west, 3 south) or -1 where that is not allowed (no street, dead end,
one-way against the traffic, or outside the strongly connected part).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from guidance.core.model import wrap_angle
from hal_sim.params import (
    I_CRUISE,
    I_DECISION_DIST,
    I_DT,
    I_MAX_ACCEL,
    I_MAX_STEER,
    I_SIGHT_RANGE,
    I_TRACK,
    I_TRUE_COMPASS_SIGMA,
    I_TRUE_QUANTUM,
    I_TRUE_SLIP,
    I_TURN_V,
    I_TYRE_ERR,
    I_WHEELBASE,
)

DIR_DX = np.array([1, 0, -1, 0])
DIR_DY = np.array([0, 1, 0, -1])
DIR_HEADING = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2])

# Truth state vector ``ts`` (floats).
T_X, T_Y, T_TH, T_V = 0, 1, 2, 3
T_CUM_L, T_CUM_R, T_CNT_L, T_CNT_R = 4, 5, 6, 7
T_PID_INT, T_PID_PREV, T_TYRE, T_DRIVEN, T_STEP = 8, 9, 10, 11, 12
T_SEG_H, T_SEG_UX, T_SEG_UY = 13, 14, 15
"""Heading and unit vector of the street being followed (a -> b), cached at each switch."""
N_TRUTH = 16
# Route state vector ``ns`` (ints): following a -> b, then c (-1 until decided).
R_A, R_B, R_C, R_PASS, R_TURNS = 0, 1, 2, 3, 4
N_ROUTE = 5

STEER_KP = 1.0
STEER_KI = 0.02
STEER_KD = 0.05
CROSS_TRACK_GAIN = 0.8
"""Stanley-style cross-track term: atan(k * e / (v + 1 m/s))."""
SPEED_KP = 0.8
SWITCH_RADIUS_M = 7.0
"""The controller starts following the next street this far before the corner."""
SQRT12 = math.sqrt(12.0)


@njit(cache=True, error_model="numpy")
def _street_positions(length_m: float, block_min: float, block_max: float) -> np.ndarray:
    n_max = int(length_m / block_min) + 2
    pos = np.empty(n_max)
    pos[0] = 0.0
    n = 1
    while n < n_max:
        nxt = pos[n - 1] + np.random.uniform(block_min, block_max)
        if nxt > length_m and n >= 3:
            break
        pos[n] = nxt
        n += 1
    return pos[:n].copy()


@njit(cache=True, error_model="numpy")
def _reach(adj: np.ndarray, nx: int, seed: int, forward: bool) -> np.ndarray:
    n_nodes = adj.shape[0]
    seen = np.zeros(n_nodes, dtype=np.bool_)
    stack = np.empty(n_nodes, dtype=np.int64)
    seen[seed] = True
    stack[0] = seed
    top = 1
    while top > 0:
        top -= 1
        u = stack[top]
        for d in range(4):
            if forward:
                v = adj[u, d]
                if v < 0:
                    continue
            else:
                # v -> u exists if the grid neighbour v in direction d drives back to u.
                i = u % nx + DIR_DX[d]
                j = u // nx + DIR_DY[d]
                if i < 0 or i >= nx or j < 0 or j >= n_nodes // nx:
                    continue
                v = j * nx + i
                if adj[v, (d + 2) % 4] != u:
                    continue
            if not seen[v]:
                seen[v] = True
                stack[top] = v
                top += 1
    return seen


@njit(cache=True, error_model="numpy")
def make_city(
    area_km2: float,
    aspect: float,
    block_min: float,
    block_max: float,
    dead_frac: float,
    oneway_frac: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A random grid city: (xs, ys, adj, in_network).

    Every node in the network reaches every other.
    """
    width = math.sqrt(area_km2 * aspect) * 1000.0
    height = area_km2 * 1e6 / width
    xs = _street_positions(width, block_min, block_max)
    ys = _street_positions(height, block_min, block_max)
    nx, ny = xs.shape[0], ys.shape[0]
    n = nx * ny
    adj = -np.ones((n, 4), dtype=np.int64)
    for j in range(ny):
        for i in range(nx):
            u = j * nx + i
            for d in range(4):
                ii, jj = i + DIR_DX[d], j + DIR_DY[d]
                if 0 <= ii < nx and 0 <= jj < ny:
                    adj[u, d] = jj * nx + ii
    # Dead ends: some nodes keep one street and lose the others (both ways).
    for u in range(n):
        if np.random.random() >= dead_frac:
            continue
        keep = np.random.randint(0, 4)
        for _ in range(4):
            if adj[u, keep] >= 0:
                break
            keep = (keep + 1) % 4
        # (A node whose neighbours have all cut it off keeps nothing; SCC pruning drops it.)
        for d in range(4):
            v = adj[u, d]
            if d != keep and v >= 0:
                adj[u, d] = -1
                adj[v, (d + 2) % 4] = -1
    # One-way streets: each remaining segment once (E and N of each node).
    for u in range(n):
        for d in range(2):
            v = adj[u, d]
            if v < 0 or adj[v, d + 2] != u:
                continue
            if np.random.random() < oneway_frac:
                if np.random.random() < 0.5:
                    adj[u, d] = -1
                else:
                    adj[v, d + 2] = -1
    # Keep the strongly connected part that holds a random node (retry for a big one).
    best = np.zeros(n, dtype=np.bool_)
    best_size = 0
    for _ in range(8):
        seed = np.random.randint(0, n)
        scc = _reach(adj, nx, seed, True) & _reach(adj, nx, seed, False)
        size = int(scc.sum())
        if size > best_size:
            best_size = size
            best = scc
        if size * 2 > n:
            break
    for u in range(n):
        for d in range(4):
            if not best[u] or (adj[u, d] >= 0 and not best[adj[u, d]]):
                adj[u, d] = -1
    return xs, ys, adj, best


@njit(cache=True, error_model="numpy")
def node_pos(xs: np.ndarray, ys: np.ndarray, n: int) -> tuple[float, float]:
    nx = xs.shape[0]
    return xs[n % nx], ys[n // nx]


@njit(cache=True, error_model="numpy")
def random_node(in_network: np.ndarray) -> int:
    idx = np.nonzero(in_network)[0]
    return int(idx[np.random.randint(0, idx.shape[0])])


@njit(cache=True, error_model="numpy")
def node_at_distance(
    xs: np.ndarray, ys: np.ndarray, in_network: np.ndarray, start: int, min_m: float, frac: float
) -> int:
    """A network node near a point at a random distance (uniform in [min_m, frac * diagonal])."""
    nx = xs.shape[0]
    sx, sy = xs[start % nx], ys[start // nx]
    diag = math.hypot(xs[-1] - xs[0], ys[-1] - ys[0])
    dist = np.random.uniform(min(min_m, frac * diag), frac * diag)
    best = -1
    for _ in range(20):
        phi = np.random.uniform(-math.pi, math.pi)
        px, py = sx + dist * math.cos(phi), sy + dist * math.sin(phi)
        if xs[0] <= px <= xs[-1] and ys[0] <= py <= ys[-1]:
            break
    px = min(max(px, xs[0]), xs[-1])
    py = min(max(py, ys[0]), ys[-1])
    best_d = math.inf
    for n in range(in_network.shape[0]):
        if not in_network[n] or n == start:
            continue
        d = (xs[n % nx] - px) ** 2 + (ys[n // nx] - py) ** 2
        if d < best_d:
            best_d = d
            best = n
    return best


@njit(cache=True, error_model="numpy")
def place_landmarks(
    xs: np.ndarray, ys: np.ndarray, adj: np.ndarray, in_network: np.ndarray, density_per_km2: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmarks along the streets: Poisson count for the area, uniform along random segments.

    Returns (lm_xy, node_start, node_lms): the landmarks near node n are
    ``node_lms[node_start[n]:node_start[n + 1]]`` (each landmark is listed at
    both ends of its segment), so sighting checks look at a handful, not all.
    """
    nx = xs.shape[0]
    n = adj.shape[0]
    area_km2 = (xs[-1] - xs[0]) * (ys[-1] - ys[0]) / 1e6
    count = np.random.poisson(density_per_km2 * area_km2) if density_per_km2 > 0 else 0
    lm_xy = np.empty((count, 2))
    ends = np.empty((count, 2), dtype=np.int64)
    k = 0
    while k < count:
        u = random_node(in_network)
        d = np.random.randint(0, 4)
        v = adj[u, d]
        if v < 0:
            continue
        f = np.random.random()
        ux, uy = xs[u % nx], ys[u // nx]
        vx, vy = xs[v % nx], ys[v // nx]
        lm_xy[k, 0] = ux + f * (vx - ux)
        lm_xy[k, 1] = uy + f * (vy - uy)
        ends[k, 0] = u
        ends[k, 1] = v
        k += 1
    counts = np.zeros(n + 1, dtype=np.int64)
    for k in range(count):
        counts[ends[k, 0] + 1] += 1
        counts[ends[k, 1] + 1] += 1
    node_start = np.cumsum(counts)
    fill = node_start[:-1].copy()
    node_lms = np.empty(2 * count, dtype=np.int64)
    for k in range(count):
        for e in range(2):
            u = ends[k, e]
            node_lms[fill[u]] = k
            fill[u] += 1
    return lm_xy, node_start, node_lms


@njit(cache=True, error_model="numpy")
def bicycle_step(
    x: float, y: float, theta: float, v: float, a: float, delta: float, dt: float, wheelbase: float
) -> tuple[float, float, float, float, float]:
    """Four-state kinematic bicycle (SPEC section 4). Returns (x, y, theta, v, dtheta).

    ``d = v dt + a dt^2 / 2``, ``rho = l / delta``, ``dtheta = d / rho``,
    ``dx = rho sin(dtheta)``, ``dy = rho (1 - cos(dtheta))`` (straight line as
    delta -> 0), rotated into the world by theta.
    """
    d = v * dt + 0.5 * a * dt * dt
    if abs(delta) < 1e-9:
        dth = 0.0
        dx = d
        dy = 0.0
    else:
        rho = wheelbase / delta
        dth = d / rho
        dx = rho * math.sin(dth)
        dy = rho * (1.0 - math.cos(dth))
    c = math.cos(theta)
    s = math.sin(theta)
    return x + dx * c - dy * s, y + dx * s + dy * c, theta + dth, v + a * dt, dth


@njit(cache=True, error_model="numpy")
def cross_track(x: float, y: float, ax: float, ay: float, ux: float, uy: float) -> float:
    """Signed distance of (x, y) from the line through a along unit vector u, positive left."""
    return -(x - ax) * uy + (y - ay) * ux


@njit(cache=True, error_model="numpy")
def steer_pid(
    ts: np.ndarray, ax: float, ay: float, h: float, ux: float, uy: float, p: np.ndarray
) -> float:
    """PID steering on heading error plus a Stanley cross-track term, clipped to the steering limit.

    Follows the line through ``(ax, ay)`` with heading ``h`` (unit vector ``(ux, uy)``).
    """
    e = cross_track(ts[T_X], ts[T_Y], ax, ay, ux, uy)
    err = wrap_angle(h - ts[T_TH]) - math.atan(CROSS_TRACK_GAIN * e / (ts[T_V] + 1.0))
    dt = p[I_DT]
    ts[T_PID_INT] = min(max(ts[T_PID_INT] + err * dt, -1.0), 1.0)
    deriv = (err - ts[T_PID_PREV]) / dt
    ts[T_PID_PREV] = err
    delta = STEER_KP * err + STEER_KI * ts[T_PID_INT] + STEER_KD * deriv
    lim = p[I_MAX_STEER]
    return min(max(delta, -lim), lim)


@njit(cache=True, error_model="numpy")
def speed_pid(v: float, v_target: float, p: np.ndarray) -> float:
    a = SPEED_KP * (v_target - v)
    lim = p[I_MAX_ACCEL]
    a = min(max(a, -lim), lim)
    if v + a * p[I_DT] < 0.0:
        a = -v / p[I_DT]
    return a


@njit(cache=True, error_model="numpy")
def exits_at(adj: np.ndarray, b: int, a: int, out_dirs: np.ndarray) -> int:
    """Directions one may leave node b by, arriving from a; U-turn only at a dead end."""
    n = 0
    back = -1
    for d in range(4):
        v = adj[b, d]
        if v < 0:
            continue
        if v == a:
            back = d
            continue
        out_dirs[n] = d
        n += 1
    if n == 0 and back >= 0:
        out_dirs[0] = back
        n = 1
    return n


@njit(cache=True, error_model="numpy")
def init_truth(
    xs: np.ndarray, ys: np.ndarray, adj: np.ndarray, start: int, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Car at node ``start`` facing a random allowed exit, at rest."""
    dirs = np.empty(4, dtype=np.int64)
    n = exits_at(adj, start, -1, dirs)
    d = dirs[np.random.randint(0, n)]
    ts = np.zeros(N_TRUTH)
    sx, sy = node_pos(xs, ys, start)
    ts[T_X] = sx
    ts[T_Y] = sy
    ts[T_TH] = DIR_HEADING[d]
    ts[T_TYRE] = np.random.normal(0.0, 1.0) * p[I_TYRE_ERR]
    ns = np.zeros(N_ROUTE, dtype=np.int64)
    ns[R_A] = start
    ns[R_B] = adj[start, d]
    ns[R_C] = -1
    _set_segment(ts, xs, ys, start, ns[R_B])
    return ts, ns


@njit(cache=True, error_model="numpy")
def _set_segment(ts: np.ndarray, xs: np.ndarray, ys: np.ndarray, a: int, b: int) -> None:
    nx = xs.shape[0]
    dx = xs[b % nx] - xs[a % nx]
    dy = ys[b // nx] - ys[a // nx]
    seg = math.hypot(dx, dy)
    ts[T_SEG_H] = math.atan2(dy, dx)
    ts[T_SEG_UX] = dx / seg
    ts[T_SEG_UY] = dy / seg


@njit(cache=True, error_model="numpy")
def _encoder(ts: np.ndarray, cum: int, cnt: int, d_true: float, p: np.ndarray) -> float:
    """One wheel: slip and tyre error on the true distance, then whole counts.

    Slip is drawn uniform with the documented standard deviation (a uniform
    draw costs a fifth of a normal one; over the hundreds of steps in a block
    the sum is Gaussian anyway, and the filter models only the variance).
    """
    q = p[I_TRUE_QUANTUM]
    slip = (np.random.random() - 0.5) * SQRT12 * p[I_TRUE_SLIP] * abs(d_true)
    ts[cum] += d_true * (1.0 + ts[T_TYRE]) + slip
    count = math.floor(ts[cum] / q)
    inc = (count - ts[cnt]) * q
    ts[cnt] = count
    return inc


@njit(cache=True, error_model="numpy")
def world_step(
    ts: np.ndarray,
    ns: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    lm_xy: np.ndarray,
    node_start: np.ndarray,
    node_lms: np.ndarray,
    lm_seen_pass: np.ndarray,
    p: np.ndarray,
    compass_due: bool,
    detection_rate: float,
    events: np.ndarray,
) -> None:
    """Advance the car one step along its route and produce the sensors' outputs.

    ``events`` (float[8]) receives: left and right wheel increments (m),
    compass heading (rad, NaN when none this step), sighted landmark index
    (-1 if none), 1.0 when the navigator must decide the exit at node b (its
    distance in [5]), 1.0 when the car has just passed node b (now a).
    """
    nx = xs.shape[0]
    ax, ay = xs[ns[R_A] % nx], ys[ns[R_A] // nx]
    bx, by = xs[ns[R_B] % nx], ys[ns[R_B] // nx]
    # Along-track distance left to node b.
    h_ab, ux, uy = ts[T_SEG_H], ts[T_SEG_UX], ts[T_SEG_UY]
    to_b = (bx - ts[T_X]) * ux + (by - ts[T_Y]) * uy
    c = ns[R_C]
    turning = False
    v = ts[T_V]
    brake = (v * v - p[I_TURN_V] ** 2) / (2.0 * p[I_MAX_ACCEL]) + 10.0
    near = to_b <= max(brake, 0.0) + 5.0
    if c >= 0 and (near or to_b <= SWITCH_RADIUS_M):
        cx, cy = xs[c % nx], ys[c // nx]
        h_bc = math.atan2(cy - by, cx - bx)
        turning = abs(wrap_angle(h_bc - h_ab)) > 0.3
        switch = SWITCH_RADIUS_M if turning else 0.0
        if abs(wrap_angle(h_bc - h_ab)) > 3.0:
            switch = 0.0  # U-turn at a dead end: drive to the end first
        if to_b <= switch:
            _set_segment(ts, xs, ys, ns[R_B], c)
            ns[R_A] = ns[R_B]
            ns[R_B] = c
            ns[R_C] = -1
            ns[R_PASS] += 1
            if turning:
                ns[R_TURNS] += 1
            events[6] = 1.0
            ax, ay, bx, by = bx, by, cx, cy
            h_ab, ux, uy = ts[T_SEG_H], ts[T_SEG_UX], ts[T_SEG_UY]
            to_b = (bx - ts[T_X]) * ux + (by - ts[T_Y]) * uy
            near = True
            c = -1
            turning = False
        else:
            events[6] = 0.0
    else:
        events[6] = 0.0
    # The driver asks for the next exit when the intersection comes into view.
    events[4] = 1.0 if (c < 0 and to_b <= p[I_DECISION_DIST]) else 0.0
    events[5] = to_b
    # Speed: slow for turns (and while the next exit is not known yet).
    v_target = p[I_CRUISE]
    if to_b <= max(brake, 0.0) + 5.0 and (c < 0 or turning):
        v_target = p[I_TURN_V]
    a = speed_pid(v, v_target, p)
    delta = steer_pid(ts, ax, ay, h_ab, ux, uy, p)
    x, y, th, v2, dth = bicycle_step(
        ts[T_X], ts[T_Y], ts[T_TH], v, a, delta, p[I_DT], p[I_WHEELBASE]
    )
    d = v * p[I_DT] + 0.5 * a * p[I_DT] ** 2
    ts[T_X] = x
    ts[T_Y] = y
    ts[T_TH] = wrap_angle(th)
    ts[T_V] = max(v2, 0.0)
    ts[T_DRIVEN] += d
    ts[T_STEP] += 1.0
    half = 0.5 * p[I_TRACK] * dth
    events[0] = _encoder(ts, T_CUM_L, T_CNT_L, d - half, p)
    events[1] = _encoder(ts, T_CUM_R, T_CNT_R, d + half, p)
    sigma = p[I_TRUE_COMPASS_SIGMA]
    if compass_due and sigma > 0.0:
        events[2] = wrap_angle(ts[T_TH] + np.random.normal(0.0, 1.0) * sigma)
    else:
        events[2] = math.nan
    # Landmarks near either end of the current street, once per pass of the car.
    events[3] = -1.0
    r2 = p[I_SIGHT_RANGE] ** 2
    for end in (ns[R_A], ns[R_B]):
        for k in range(node_start[end], node_start[end + 1]):
            lm = node_lms[k]
            if lm < 0 or lm_seen_pass[lm] == ns[R_PASS]:  # < 0: a field goal's empty slot
                continue
            dx = lm_xy[lm, 0] - ts[T_X]
            dy = lm_xy[lm, 1] - ts[T_Y]
            if dx * dx + dy * dy <= r2:
                lm_seen_pass[lm] = ns[R_PASS]
                if np.random.random() < detection_rate:
                    events[3] = float(lm)


@njit(cache=True, error_model="numpy")
def make_interference(adj: np.ndarray, frac: float, bias_min: float, bias_max: float) -> np.ndarray:
    """Magnetic interference zones: bias (rad) per directed block, NaN where there is none.

    Drawn only when ``frac > 0`` so the calibrated studies keep their random streams.
    """
    mag = np.full(adj.shape, np.nan)
    if frac <= 0.0:
        return mag
    for u in range(adj.shape[0]):
        for d in range(4):
            if adj[u, d] >= 0 and np.random.random() < frac:
                b = np.random.uniform(bias_min, bias_max)
                mag[u, d] = b if np.random.random() < 0.5 else -b
    return mag


@njit(cache=True, error_model="numpy")
def disturb_compass(
    mag: np.ndarray, adj: np.ndarray, ns: np.ndarray, reading: float, extra_sigma: float
) -> float:
    """The compass reading inside an interference zone on the current block (else unchanged)."""
    a, b = ns[R_A], ns[R_B]
    for d in range(4):
        if adj[a, d] == b:
            bias = mag[a, d]
            if math.isnan(bias):
                return reading
            return wrap_angle(reading + bias + np.random.normal(0.0, 1.0) * extra_sigma)
    return reading


@njit(cache=True, error_model="numpy")
def seed(s: int) -> None:
    """Seed numba's generator (one state per thread; independent of numpy's)."""
    np.random.seed(s)
