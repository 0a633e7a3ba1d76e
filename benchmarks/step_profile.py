"""Where a study step's time goes: each part of ``engine.run_trial`` timed alone, compiled.

Prints ns per step for: the random numbers a step draws (two uniforms for wheel slip, a
normal for the compass 60 % of steps; ``hal_sim.rng``, and numba's generator for comparison),
a library sine and cosine, the bicycle arc, the steering's arctangent (and the library's); the
world step (car, controllers, encoders, compass, landmark sightings; exits chosen at random, no
estimator); the EKF predict; the compass update; the major axis; the navigator's decision (per
decision); a trial's set-up; and the whole trial step, for comparison. Loops are written as
``engine.drive`` is (arrays as arguments, draws in the loop), so that each part is charged
what it costs in a trial. Each figure is the median of ``--repeat`` runs of CPU time. The
machine may be shared: compare figures from one run.

    .venv/bin/python benchmarks/step_profile.py [--steps 2000000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

# isort: off
import guidance  # noqa: F401  (first: it points numba's cache at a folder keyed by the sources)
from numba import njit

# isort: on
from guidance.core import law, model
from guidance.core.plan.navigator import Method, NavigatorConfig
from hal_sim import ekf, engine, params, rng, studies, world
from hal_sim.params import I_COMPASS_PERIOD, I_DETECT, I_QUANTUM, I_SLIP, I_TRACK, SimParams

ENGINE_FLAGS = {"error_model": "numpy", "fastmath": {"contract", "arcp"}}
"""``engine.drive``'s compile flags, for the loops below that inline the engine's steps."""


@njit(cache=True)
def draws(n: int) -> float:
    """A step's draws as ``world.draw_step`` makes them (words in registers)."""
    s0, s1 = rng.seed_state(1)
    acc = 0.0
    for i in range(n):
        u_l, u_r, g, s0, s1 = world.draw_step(i % 5 < 3, 1.0, s0, s1)
        acc += u_l + u_r + g
    return acc


@njit(cache=True)
def uniforms(n: int) -> float:
    s0, s1 = rng.seed_state(1)
    acc = 0.0
    for _ in range(n):
        u, s0, s1 = rng.uniform(s0, s1)
        acc += u
    return acc


@njit(cache=True)
def normals(n: int) -> float:
    s0, s1 = rng.seed_state(1)
    acc = 0.0
    for _ in range(n):
        z, s0, s1 = rng.normal(s0, s1)
        acc += z
    return acc


@njit(cache=True)
def mt_uniforms(n: int) -> float:
    acc = 0.0
    for _ in range(n):
        acc += np.random.random()
    return acc


@njit(cache=True)
def mt_normals(n: int) -> float:
    acc = 0.0
    for _ in range(n):
        acc += np.random.normal(0.0, 1.0)
    return acc


@njit(cache=True)
def sincos(n: int) -> float:
    """One library sine and cosine of the same angle (the predict's)."""
    acc = 0.0
    th = 0.1
    for i in range(n):
        th = th + 1e-7 * (i % 7) + acc * 1e-30
        acc += math.cos(th) * 0.5 + math.sin(th)
    return acc


@njit(cache=True, **ENGINE_FLAGS)
def arcs(n: int) -> float:
    """The world's bicycle arc (series, the heading's cos and sin turned)."""
    x, y, c, s = 0.0, 0.0, 1.0, 0.0
    for i in range(n):
        x, y, _dth, c, s = world.bicycle_arc(x, y, c, s, 1.1, 0.01 * (i % 7) - 0.03, 2.946)
    return x + y + c + s


@njit(cache=True, **ENGINE_FLAGS)
def atans(n: int) -> float:
    """The steering's arctangent (cross-track term: ``world.atan``, inline)."""
    acc = 0.0
    for i in range(n):
        acc += world.atan(0.8 * (0.01 * (i % 101) - 0.5) / 12.0 + acc * 1e-30)
    return acc


@njit(cache=True)
def lib_atans(n: int) -> float:
    """The library's arctangent, the same arguments (the steering's before issue 26's fourth
    round)."""
    acc = 0.0
    for i in range(n):
        acc += math.atan(0.8 * (0.01 * (i % 101) - 0.5) / 12.0 + acc * 1e-30)
    return acc


@njit(cache=True)
def setups(seeds: np.ndarray, study: int, density: float, p: np.ndarray) -> float:
    """A trial's set-up alone: the city, landmarks, start, goal, the car."""
    acc = 0.0
    for s in seeds:
        acc += engine.setup_trial(s, study, density, p)[10]
    return acc


@njit(cache=True)
def predicts(n: int, p: np.ndarray) -> float:
    return _predicts(n, p, ekf.state(0.0, 0.0, 0.0), np.eye(3))


@njit(cache=True, **ENGINE_FLAGS)
def _predicts(n: int, p: np.ndarray, x: np.ndarray, P: np.ndarray) -> float:
    for i in range(n):
        dl = 1.1 + 0.02 * (i % 3)
        ekf.predict(x, P, dl, 1.1, p[I_TRACK], p[I_QUANTUM], p[I_SLIP])
        if i % 1000 == 0:
            P[:, :] = np.eye(3)
    return P[0, 0]


@njit(cache=True)
def compass_updates(n: int, p: np.ndarray) -> float:
    return _compass_updates(n, p, ekf.state(0.0, 0.0, 0.0), np.eye(3) * 0.01, np.array([1.0, 0.0]))


@njit(cache=True)
def _compass_updates(n: int, p: np.ndarray, x: np.ndarray, P: np.ndarray, det: np.ndarray) -> float:
    acc = 0.0
    for i in range(n):
        acc += ekf.compass_update(x, P, 0.01 * (i % 7), 0.02, p, det)
        P[0, 0] += 0.01
        P[2, 2] += 1e-4
    return acc


@njit(cache=True)
def majors(n: int) -> float:
    P = np.eye(3)
    acc = 0.0
    for i in range(n):
        P[0, 0] = 1.0 + i * 1e-6
        acc += model.major_axis_m(P)
    return acc


@njit(cache=True)
def world_only(seed: int, p: np.ndarray, n: int) -> tuple[int, int]:
    """The world stepped alone, exits at random; returns (steps, decisions)."""
    xs, ys, adj, _n, lm_xy, node_start, node_lms, ts, ns, _g, _a, _m = engine.setup_trial(
        seed, engine.STUDY_RANGE, 0.0, p
    )
    lm_seen = -np.ones(lm_xy.shape[0], dtype=np.int64)
    events = np.zeros(world.N_EVENTS)
    dirs = np.empty(4, dtype=np.int64)
    return _world_loop(xs, ys, adj, lm_xy, node_start, node_lms, ts, ns, lm_seen, events, dirs,
                       p, n)  # fmt: skip


@njit(cache=True, **ENGINE_FLAGS)
def _world_loop(
    xs: np.ndarray, ys: np.ndarray, adj: np.ndarray, lm_xy: np.ndarray,
    node_start: np.ndarray, node_lms: np.ndarray, ts: np.ndarray, ns: np.ndarray,
    lm_seen: np.ndarray, events: np.ndarray, dirs: np.ndarray, p: np.ndarray, n: int,
) -> tuple[int, int]:  # fmt: skip
    """As ``engine.drive`` steps the world: arrays as arguments, draws in the loop."""
    period = p[I_COMPASS_PERIOD]
    decisions = 0
    s0, s1 = rng.from_word(ns[world.R_RNG0]), rng.from_word(ns[world.R_RNG1])
    for step in range(n):
        due = math.floor((step + 1) / period) > math.floor(step / period)
        u_l, u_r, g, s0, s1 = world.draw_step(due, p[params.I_TRUE_COMPASS_SIGMA], s0, s1)
        world.step_core(
            ts, ns, xs, ys, lm_xy, node_start, node_lms, lm_seen, p, due, u_l, u_r, g, events
        )
        if events[world.EV_N_SIGHTED] > 0:
            world.detect(events, p[I_DETECT])
        if events[4] > 0.0:
            k = world.exits_at(adj, ns[world.R_B], ns[world.R_A], dirs)
            ns[world.R_C] = adj[ns[world.R_B], dirs[np.random.randint(0, k)]]
            decisions += 1
    return n, decisions


@njit(cache=True)
def decisions(n: int, p: np.ndarray) -> int:
    """decide_exit in a remembered neighbourhood, as during a range trial."""
    mem_xy = np.zeros((engine.MAX_MEMORY, 2))
    mem_h = np.zeros((engine.MAX_MEMORY, engine.MAX_EXITS))
    mem_c = np.zeros((engine.MAX_MEMORY, engine.MAX_EXITS), dtype=np.int64)
    n_mem = 0
    passed = np.zeros(0, dtype=np.bool_)
    lm_xy = np.zeros((0, 2))
    hs = np.array([0.0, math.pi / 2, -math.pi / 2])
    penalties = np.empty(4)
    costs = np.empty(4)
    dp = np.array([9.21, 100.0, 0.5, 0.6, 30.0, 60.0])
    acc = 0
    for i in range(n):
        ix = 150.0 * (i % 40)
        iy = 150.0 * ((i // 40) % 40)
        best, _k, _r, n_mem, _t = law.decide_exit(
            ix, iy, 400.0, 10.0, 400.0, hs, mem_xy, mem_h, mem_c, n_mem, passed, lm_xy,
            5000.0, 3000.0, law.MODE_GOAL, dp, penalties, costs,
        )  # fmt: skip
        acc += best
    return acc


def _median_ns(fn: object, per: float, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()  # type: ignore[operator]
        times.append(time.process_time() - t0)
    return float(np.median(times)) / per * 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--trials", type=int, default=100)
    args = ap.parse_args()
    n, rep = args.steps, args.repeat
    sim = SimParams()
    p = params.pack(sim, params.estimator_config(sim, 30.0), NavigatorConfig(), 1.0)
    seeds = studies.trial_seeds(3, 0, 0, args.trials)
    # compile
    draws(10), uniforms(10), normals(10), predicts(10, p), compass_updates(10, p), majors(10)
    mt_uniforms(10), mt_normals(10), sincos(10), arcs(10), atans(10), lib_atans(10)
    world_only(1, p, 10), decisions(10, p), setups(seeds[:1], engine.STUDY_LANDMARKS, 1.0, p)
    code = Method.STRAIGHT_TO_GOAL.code
    engine.run_batch(seeds[:1], engine.STUDY_RANGE, code, 0.0, p, params.N_SAMPLES)
    steps, dec = world_only(1, p, n)
    rows = [
        ("uniform draw (hal_sim.rng)", _median_ns(lambda: uniforms(n), n, rep)),
        ("normal draw (hal_sim.rng)", _median_ns(lambda: normals(n), n, rep)),
        ("uniform draw (numba's Mersenne Twister)", _median_ns(lambda: mt_uniforms(n), n, rep)),
        ("normal draw (numba's Mersenne Twister)", _median_ns(lambda: mt_normals(n), n, rep)),
        ("a step's draws (2 uniform + 0.6 normal)", _median_ns(lambda: draws(n), n, rep)),
        ("library sin + cos of one angle", _median_ns(lambda: sincos(n), n, rep)),
        ("bicycle arc (series, turned cos/sin)", _median_ns(lambda: arcs(n), n, rep)),
        ("steering atan (world.atan, inline)", _median_ns(lambda: atans(n), n, rep)),
        ("library atan", _median_ns(lambda: lib_atans(n), n, rep)),
        ("world step (no estimator)", _median_ns(lambda: world_only(1, p, n), n, rep)),
        ("EKF predict", _median_ns(lambda: predicts(n, p), n, rep)),
        ("compass update (per update)", _median_ns(lambda: compass_updates(n, p), n, rep)),
        ("major axis", _median_ns(lambda: majors(n), n, rep)),
        ("decision (per decision)", _median_ns(lambda: decisions(n // 20, p), n // 20, rep)),
    ]
    res, _ = engine.run_batch(seeds, engine.STUDY_RANGE, code, 0.0, p, params.N_SAMPLES)
    total_steps = float(res[:, engine.RES_STEPS].sum())
    whole = _median_ns(
        lambda: engine.run_batch(seeds, engine.STUDY_RANGE, code, 0.0, p, params.N_SAMPLES),
        total_steps,
        max(1, rep // 2),
    )
    n_setup = max(50, args.trials)
    setup_us = [
        _median_ns(lambda s=s, d=d: setups(seeds[:n_setup], s, d, p), n_setup, rep) / 1000.0
        for s, d in ((engine.STUDY_RANGE, 0.0), (engine.STUDY_LANDMARKS, 10.0))
    ]
    print(f"decisions per step: {dec / steps:.4f}; compass updates per step: 0.6")
    print(f"  trial set-up: range {setup_us[0]:.0f} us, landmarks at 10/km2 {setup_us[1]:.0f} us")
    for name, ns in rows:
        print(f"  {name:42s} {ns:7.1f} ns")
    print(f"  {'whole trial step (range, compass 30 deg)':42s} {whole:7.1f} ns")


if __name__ == "__main__":
    main()
