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
from hal_sim import car, city, rng
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

DIR_DX = city.DIR_DX
DIR_DY = city.DIR_DY
DIR_HEADING = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2])

# Truth state vector ``ts`` (floats).
T_X, T_Y, T_TH, T_V = 0, 1, 2, 3
T_CUM_L, T_CUM_R, T_CNT_L, T_CNT_R = 4, 5, 6, 7
T_PID_INT, T_PID_PREV, T_TYRE, T_DRIVEN, T_STEP = 8, 9, 10, 11, 12
T_SEG_H, T_SEG_UX, T_SEG_UY = 13, 14, 15
"""Heading and unit vector of the street being followed (a -> b), cached at each switch."""
T_COS, T_SIN = 16, 17
"""cos and sin of the heading ``T_TH``: turned by each step's arc (``bicycle_arc``), set from
the heading afresh at each street switch (the rounding they gather in between, a few 1e-15,
goes no further)."""
T_AX, T_AY, T_BX, T_BY = 18, 19, 20, 21
"""The positions of the street's ends a and b (``R_A``, ``R_B``), set with ``T_SEG_H`` at each
switch: a step needs them, not the node numbers' integer division by the grid's width."""
N_TRUTH = 22
# Route state vector ``ns`` (ints): following a -> b, then c (-1 until decided); and the
# step's random generator, its two words' bits (``hal_sim.rng``, drawn by ``draw_step``).
R_A, R_B, R_C, R_PASS, R_TURNS, R_RNG0, R_RNG1 = 0, 1, 2, 3, 4, 5, 6
N_ROUTE = 7

STEER_KP = 1.0
STEER_KI = 0.02
STEER_KD = 0.05
CROSS_TRACK_GAIN = 0.8
"""Stanley-style cross-track term: atan(k * e / (v + 1 m/s))."""
SPEED_KP = 0.8
SWITCH_RADIUS_M = 7.0
"""The controller starts following the next street this far before the corner."""
N_EVENTS = 16
"""``world_step``'s events vector: [0..6] the sensors and the route (see ``world_step``),
[EV_N_SIGHTED] how many landmarks came into sight this step, from [EV_SIGHTED] their indices."""
EV_N_SIGHTED = 7
EV_SIGHTED = 8
MAX_SIGHTED = N_EVENTS - EV_SIGHTED
# The city (``hal_sim.city``), under the names the engine and the tests use.
make_city = city.make_city
node_pos = city.node_pos
random_node = city.random_node
node_at_distance = city.node_at_distance
place_landmarks = city.place_landmarks
make_interference = city.make_interference


ARC_SERIES_MAX = 0.5
"""``arc_factors`` sums series below this turn of a step (rad); the car's largest is about
0.22 (1.2 m at full lock)."""


# The series of sin(t) / t (1, _S1 t^2, ...) and (1 - cos(t)) / t (_C0 t, _C1 t^3, ...).
_S1, _S2, _S3 = -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0
_S4, _S5, _S6 = 1.0 / 362880.0, -1.0 / 39916800.0, 1.0 / 6227020800.0
_C0, _C1, _C2, _C3 = 0.5, -1.0 / 24.0, 1.0 / 720.0, -1.0 / 40320.0
_C4, _C5, _C6 = 1.0 / 3628800.0, -1.0 / 479001600.0, 1.0 / 87178291200.0


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def arc_factors(t: float) -> tuple[float, float]:
    """(sin(t) / t, (1 - cos(t)) / t): by their series for |t| <= ARC_SERIES_MAX (the first
    term left out below 5e-17 of the sum), else by the library (t != 0)."""
    if abs(t) > ARC_SERIES_MAX:
        return math.sin(t) / t, (1.0 - math.cos(t)) / t
    # Estrin's scheme (u, u^2, u^4 in parallel): a shorter chain of dependent operations
    # than Horner's, as the world step's heading and position wait on it.
    u = t * t
    u2 = u * u
    u4 = u2 * u2
    sinc = (1.0 + _S1 * u) + u2 * (_S2 + _S3 * u) + u4 * ((_S4 + _S5 * u) + u2 * _S6)
    cosc = t * ((_C0 + _C1 * u) + u2 * (_C2 + _C3 * u) + u4 * ((_C4 + _C5 * u) + u2 * _C6))
    return sinc, cosc


# fdlibm's arctangent (s_atan.c): its reduction of |x| to [0, 7/16] and its polynomial.
_AT = (
    3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01,
    -1.11111104054623557880e-01, 9.09088713343650656196e-02, -7.69187620504482999495e-02,
    6.66107313738753120669e-02, -5.83357013379057348645e-02, 4.97687799461593236017e-02,
    -3.65315727442169155270e-02, 1.62858201153657823623e-02,
)  # fmt: skip
_AT_HI = (4.63647609000806093515e-01, 7.85398163397448278999e-01, 9.82793723247329054082e-01)
_AT_LO = (2.26987774529616870924e-17, 3.06161699786838301793e-17, 1.39033110312309984516e-17)
_PI_2_HI, _PI_2_LO = 1.57079632679489655800e00, 6.12323399573676603587e-17


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def atan(x: float) -> float:
    """The arctangent, inline: fdlibm's reduction and polynomial (under an ulp; the library's
    call and its chain of dependent operations were a sixth of the world step), the
    polynomial by Estrin's scheme. No reduction (no division) for |x| < 7/16, the steering's
    usual argument."""
    ax = abs(x)
    if ax < 0.4375:
        r = x
        hi = lo = 0.0
        reduced = False
    else:  # (NaN too: NaN out)
        reduced = True
        if ax < 0.6875:
            r, hi, lo = (2.0 * ax - 1.0) / (2.0 + ax), _AT_HI[0], _AT_LO[0]
        elif ax < 1.1875:
            r, hi, lo = (ax - 1.0) / (ax + 1.0), _AT_HI[1], _AT_LO[1]
        elif ax < 2.4375:
            r, hi, lo = (ax - 1.5) / (1.0 + 1.5 * ax), _AT_HI[2], _AT_LO[2]
        else:
            r, hi, lo = -1.0 / ax, _PI_2_HI, _PI_2_LO
    z = r * r
    w = z * z
    w2 = w * w
    w4 = w2 * w2
    a = _AT
    s1 = z * ((a[0] + a[2] * w) + w2 * (a[4] + a[6] * w) + w4 * (a[8] + a[10] * w))
    s2 = w * ((a[1] + a[3] * w) + w2 * (a[5] + a[7] * w) + w4 * a[9])
    if not reduced:
        return r - r * (s1 + s2)
    t = hi - ((r * (s1 + s2) - lo) - r)
    return t if x >= 0.0 else -t


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def bicycle_arc(
    x: float, y: float, c: float, s: float, d: float, delta: float, wheelbase: float
) -> tuple[float, float, float, float, float]:
    """The kinematic bicycle's move by ``d`` at steering ``delta`` from (x, y) heading
    (cos, sin) = (c, s): (x, y, dtheta, cos, sin) after it (see ``bicycle_step``).

    ``dtheta = d delta / l``; the arc's chord in the car's frame is ``d (sin(dtheta) /
    dtheta, (1 - cos(dtheta)) / dtheta)`` (``arc_factors``: no trigonometry), and the new
    heading's cos and sin are the old ones turned by dtheta."""
    if abs(delta) < 1e-9:
        return x + d * c, y + d * s, 0.0, c, s
    dth = delta * (d / wheelbase)  # d / l first: the steering waits on the step before
    sinc, cosc = arc_factors(dth)
    dx = d * sinc
    dy = d * cosc
    sd = dth * sinc  # sin(dth)
    cd = 1.0 - dth * cosc  # cos(dth)
    return x + dx * c - dy * s, y + dx * s + dy * c, dth, c * cd - s * sd, s * cd + c * sd


@njit(cache=True, error_model="numpy")
def bicycle_step(
    x: float, y: float, theta: float, v: float, a: float, delta: float, dt: float, wheelbase: float
) -> tuple[float, float, float, float, float]:
    """Four-state kinematic bicycle (SPEC section 4). Returns (x, y, theta, v, dtheta).

    ``d = v dt + a dt^2 / 2``, ``rho = l / delta``, ``dtheta = d / rho``,
    ``dx = rho sin(dtheta)``, ``dy = rho (1 - cos(dtheta))`` (straight line as
    delta -> 0), rotated into the world by theta (``bicycle_arc``, which the world step
    uses with the heading's cos and sin kept).
    """
    d = v * dt + 0.5 * a * dt * dt
    x2, y2, dth, _c, _s = bicycle_arc(x, y, math.cos(theta), math.sin(theta), d, delta, wheelbase)
    return x2, y2, theta + dth, v + a * dt, dth


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def cross_track(x: float, y: float, ax: float, ay: float, ux: float, uy: float) -> float:
    """Signed distance of (x, y) from the line through a along unit vector u, positive left."""
    return -(x - ax) * uy + (y - ay) * ux


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def steer_pid(
    x: float, y: float, theta: float, v: float, integral: float, prev: float,
    ax: float, ay: float, h: float, ux: float, uy: float, dt: float, lim: float,
) -> tuple[float, float, float]:  # fmt: skip
    """PID steering on heading error plus a Stanley cross-track term, clipped to the steering
    limit ``lim``: (steering, the error's integral, the error) from the car at (x, y) heading
    ``theta`` at speed v, and the integral and the error of the step before.

    Follows the line through ``(ax, ay)`` with heading ``h`` (unit vector ``(ux, uy)``).
    Scalars only, inlined: the world step's state stays in registers.
    """
    # The divisions by the speed and the step take no state of this step: the step's chain
    # (position, cross-track error, arctangent, steering, arc, position) waits on none.
    gain = CROSS_TRACK_GAIN / (v + 1.0)
    kd = STEER_KD / dt
    e = cross_track(x, y, ax, ay, ux, uy)
    err = wrap_angle(h - theta) - atan(gain * e)
    integral = min(max(integral + err * dt, -1.0), 1.0)
    delta = STEER_KP * err + STEER_KI * integral + kd * (err - prev)  # kd (err - prev): KD deriv
    return min(max(delta, -lim), lim), integral, err


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def speed_pid(v: float, v_target: float, max_accel: float, dt: float) -> float:
    """Proportional speed control, clipped to the acceleration limit, never below rest."""
    a = SPEED_KP * (v_target - v)
    a = min(max(a, -max_accel), max_accel)
    if v + a * dt < 0.0:
        a = -v / dt
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
    """Car at node ``start`` facing a random allowed exit, at rest; the step's generator seeded
    from numba's (``hal_sim.rng``)."""
    dirs = np.empty(4, dtype=np.int64)
    n = exits_at(adj, start, -1, dirs)
    d = dirs[np.random.randint(0, n)]
    ts = np.zeros(N_TRUTH)
    sx, sy = node_pos(xs, ys, start)
    ts[T_X] = sx
    ts[T_Y] = sy
    ts[T_TH] = DIR_HEADING[d]
    ts[T_COS] = math.cos(ts[T_TH])
    ts[T_SIN] = math.sin(ts[T_TH])
    ts[T_TYRE] = np.random.normal(0.0, 1.0) * p[I_TYRE_ERR]
    ns = np.zeros(N_ROUTE, dtype=np.int64)
    ns[R_A] = start
    ns[R_B] = adj[start, d]
    ns[R_C] = -1
    s0, s1 = rng.seed_state(np.random.randint(0, 1 << 62))
    ns[R_RNG0] = rng.to_word(s0)
    ns[R_RNG1] = rng.to_word(s1)
    _set_segment(ts, xs, ys, start, ns[R_B])
    return ts, ns


@njit(cache=True, error_model="numpy")
def street_heading(dx: float, dy: float) -> float:
    """``atan2(dy, dx)``, exactly, for a street of extent (dx, dy): the grid city's streets
    are along the axes, whose headings need no arctangent (``DIR_HEADING``, the doubles
    atan2 returns there)."""
    if dy == 0.0 and dx != 0.0:
        return math.copysign(0.0 if dx > 0.0 else math.pi, dy)  # atan2(-0.0, -1) is -pi
    if dx == 0.0 and dy != 0.0:
        return 0.5 * math.pi if dy > 0.0 else -0.5 * math.pi
    return math.atan2(dy, dx)


@njit(cache=True, error_model="numpy")
def segment(dx: float, dy: float) -> tuple[float, float, float]:
    """Heading and unit vector of a street a -> b from its extent (scalars: see step_core)."""
    seg = math.hypot(dx, dy)
    return street_heading(dx, dy), dx / seg, dy / seg


@njit(cache=True, error_model="numpy", inline="always")
def set_street(ts: np.ndarray, ax: float, ay: float, bx: float, by: float) -> None:
    """The street a -> b the car is on, in the truth vector: its ends (``T_AX`` .. ``T_BY``)
    and its heading and unit vector (``T_SEG_*``). The one place they are set: at a trial's
    start and at each switch of ``step_core``."""
    ts[T_SEG_H], ts[T_SEG_UX], ts[T_SEG_UY] = segment(bx - ax, by - ay)
    ts[T_AX], ts[T_AY], ts[T_BX], ts[T_BY] = ax, ay, bx, by


@njit(cache=True, error_model="numpy")
def _set_segment(ts: np.ndarray, xs: np.ndarray, ys: np.ndarray, a: int, b: int) -> None:
    nx = xs.shape[0]
    set_street(ts, xs[a % nx], ys[a // nx], xs[b % nx], ys[b // nx])


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp"})
def _encoder(
    ts: np.ndarray, cum: int, cnt: int, d_true: float, u: float, inv_q: float, p: np.ndarray
) -> float:
    """One wheel of the paper's car, by the one sensor-error model (``hal_sim.car``): slip
    (from the uniform draw ``u``) and tyre error on the true distance, then whole counts
    (``inv_q`` is 1 / ``p[I_TRUE_QUANTUM]``: a product, where a division would hold up the
    step's chain: the arc's turn, the wheel's distance, its counts, the predict)."""
    ts[cum] += car.wheel_travel(d_true, ts[T_TYRE], car.slip_noise(u, p[I_TRUE_SLIP], d_true))
    ts[cnt], inc = car.quantise(ts[cum], ts[cnt], inv_q, p[I_TRUE_QUANTUM])
    return inc


@njit(cache=True, error_model="numpy")
def _release_here(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, e: np.ndarray,
    f: np.ndarray, g: np.ndarray, h: np.ndarray, i: np.ndarray, j: np.ndarray,
) -> None:  # fmt: skip
    """Nothing: see the end of ``step_core``."""


@njit(cache=True, error_model="numpy", inline="always", fastmath={"contract", "arcp"})
def step_core(
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
    u_left: float,
    u_right: float,
    gauss: float,
    events: np.ndarray,
) -> None:
    """``world_step`` without its random draws, which come in as numbers: the uniforms of
    the two wheels' slip and the compass's standard normal (used when the compass is due).

    A function that takes arrays and draws random numbers increfs and decrefs every array
    argument at every call (numba's reference-count pruning gives up at the generator's
    calls): 20 atomic operations a step here. Drawn by the caller (``world_step``, or the
    compiled trial loop directly), the step passes its arrays for free. Newly sighted
    landmarks are listed in ``events[EV_N_SIGHTED]`` and after it; the caller draws their
    detection (``detect``).

    Inlined (numba) into its callers, ``engine.drive`` and ``world_step``: a call passed its
    ten arrays as some seventy machine words at every step. The inlined body is compiled
    with the caller's flags: both callers take ``fastmath={"contract", "arcp"}``.
    """
    nx = xs.shape[0]
    ax, ay, bx, by = ts[T_AX], ts[T_AY], ts[T_BX], ts[T_BY]
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
        h_bc = street_heading(cx - bx, cy - by)
        turning = abs(wrap_angle(h_bc - h_ab)) > 0.3
        switch = SWITCH_RADIUS_M if turning else 0.0
        if abs(wrap_angle(h_bc - h_ab)) > 3.0:
            switch = 0.0  # U-turn at a dead end: drive to the end first
        if to_b <= switch:
            set_street(ts, bx, by, cx, cy)
            ts[T_COS] = math.cos(ts[T_TH])
            ts[T_SIN] = math.sin(ts[T_TH])
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
    a = speed_pid(v, v_target, p[I_MAX_ACCEL], p[I_DT])
    dt = p[I_DT]
    delta, ts[T_PID_INT], ts[T_PID_PREV] = steer_pid(
        ts[T_X], ts[T_Y], ts[T_TH], v, ts[T_PID_INT], ts[T_PID_PREV], ax, ay, h_ab, ux, uy, dt,
        p[I_MAX_STEER],
    )  # fmt: skip
    d = v * dt + 0.5 * a * dt * dt
    x, y, dth, ts[T_COS], ts[T_SIN] = bicycle_arc(
        ts[T_X], ts[T_Y], ts[T_COS], ts[T_SIN], d, delta, p[I_WHEELBASE]
    )
    ts[T_X] = x
    ts[T_Y] = y
    ts[T_TH] = wrap_angle(ts[T_TH] + dth)
    ts[T_V] = max(v + a * dt, 0.0)
    ts[T_DRIVEN] += d
    ts[T_STEP] += 1.0
    half = 0.5 * p[I_TRACK] * dth
    inv_q = 1.0 / p[I_TRUE_QUANTUM]
    events[0] = _encoder(ts, T_CUM_L, T_CNT_L, d - half, u_left, inv_q, p)
    events[1] = _encoder(ts, T_CUM_R, T_CNT_R, d + half, u_right, inv_q, p)
    sigma = p[I_TRUE_COMPASS_SIGMA]
    if compass_due and sigma > 0.0:
        events[2] = car.compass_reading(ts[T_TH], 0.0, gauss, sigma)
    else:
        events[2] = math.nan
    # Landmarks near either end of the current street, once per pass of the car.
    events[3] = -1.0
    n_sighted = 0
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
                if n_sighted < MAX_SIGHTED:
                    events[EV_SIGHTED + n_sighted] = float(lm)
                    n_sighted += 1
    events[EV_N_SIGHTED] = n_sighted
    # Every array used once more here, so numba releases them all in this last block: its
    # reference-count pruning can then pair each release with the acquire at entry and drop
    # both (otherwise xs and ys, last used in branches, keep all ten).
    _release_here(ts, ns, xs, ys, lm_xy, node_start, node_lms, lm_seen_pass, p, events)


@njit(cache=True, error_model="numpy", inline="always")
def draw_step(
    compass_due: bool, compass_sigma: float, s0: np.uint64, s1: np.uint64
) -> tuple[float, float, float, np.uint64, np.uint64]:
    """A step's draws before the sightings, from the generator's words (s0, s1)
    (``hal_sim.rng``), in order: the left and right wheels' slip uniforms, then the
    compass's standard normal when one is due (the true compass sigma,
    ``p[I_TRUE_COMPASS_SIGMA]``, is positive). Returns them and the new words. Scalars only:
    see ``step_core``; the compiled trial loop keeps the words in registers, ``world_step``
    in ``ns[R_RNG0]`` and ``ns[R_RNG1]``."""
    u_left, s0, s1 = rng.uniform(s0, s1)
    u_right, s0, s1 = rng.uniform(s0, s1)
    gauss = 0.0
    if compass_due and compass_sigma > 0.0:
        gauss, s0, s1 = rng.normal(s0, s1)
    return u_left, u_right, gauss, s0, s1


@njit(cache=True, error_model="numpy")
def detect(events: np.ndarray, detection_rate: float) -> None:
    """Each landmark sighted this step is detected with ``detection_rate``: ``events[3]`` is
    the last one detected (-1: none). Call only when ``events[EV_N_SIGHTED] > 0``."""
    for j in range(int(events[EV_N_SIGHTED])):
        if np.random.random() < detection_rate:
            events[3] = events[EV_SIGHTED + j]


@njit(cache=True, error_model="numpy", fastmath={"contract", "arcp"})
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

    ``events`` (float[N_EVENTS]) receives: left and right wheel increments (m),
    compass heading (rad, NaN when none this step), sighted landmark index
    (-1 if none), 1.0 when the navigator must decide the exit at node b (its
    distance in [5]), 1.0 when the car has just passed node b (now a); and the
    landmarks sighted this step (``EV_N_SIGHTED``). The draws are ``draw_step``'s, then
    ``detect``'s; the compiled trial loop makes the same three calls itself. ``step_core`` is
    inlined into both, so both are compiled with the same flags (``engine.drive``'s).
    """
    u_left, u_right, gauss, s0, s1 = draw_step(
        compass_due, p[I_TRUE_COMPASS_SIGMA], rng.from_word(ns[R_RNG0]), rng.from_word(ns[R_RNG1])
    )
    ns[R_RNG0] = rng.to_word(s0)
    ns[R_RNG1] = rng.to_word(s1)
    step_core(
        ts, ns, xs, ys, lm_xy, node_start, node_lms, lm_seen_pass, p, compass_due,
        u_left, u_right, gauss, events,
    )  # fmt: skip
    if events[EV_N_SIGHTED] > 0:
        detect(events, detection_rate)


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
