"""The simulated world: city invariants, the bicycle model, the PID controllers, the sensors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from guidance.core.plan.navigator import NavigatorConfig
from hal_sim import city, engine, params, world
from hal_sim.params import SimParams


def _city(seed: int, area: float = 4.0, dead: float = 0.04, oneway: float = 0.12):
    world.seed(seed)
    return world.make_city(area, 1.0, 50.0, 300.0, dead, oneway)


def _reach_all(adj: np.ndarray, nx: int, start: int, forward: bool) -> np.ndarray:
    return city._reach(adj, city.grid_adjacency(nx, adj.shape[0] // nx), start, forward)


@pytest.mark.parametrize("seed", range(8))
def test_city_network_is_strongly_connected(seed: int) -> None:
    xs, _ys, adj, net = _city(seed)
    nx = len(xs)
    nodes = np.nonzero(net)[0]
    assert len(nodes) > 0.5 * adj.shape[0]
    fwd = _reach_all(adj, nx, int(nodes[0]), True)
    bwd = _reach_all(adj, nx, int(nodes[0]), False)
    assert fwd[net].all() and bwd[net].all()
    # nothing leads out of the network
    assert not (adj[~net] >= 0).any()
    targets = adj[net][adj[net] >= 0]
    assert net[targets].all()


def test_city_generation_terminates_when_dead_ends_isolate_a_node() -> None:
    # A range-study trial once hung here: a dead-end node whose neighbours had
    # already cut every street to it. Dense dead ends make that common.
    for seed in range(300):
        _xs, _ys, _adj, net = _city(seed, area=1.0, dead=0.5)
        assert net.sum() >= 2


def test_city_blocks_area_dead_ends_and_one_ways() -> None:
    one_way = two_way = dead_ends = nodes = 0
    for seed in range(20):
        xs, ys, adj, net = _city(seed, area=9.0)
        gaps = np.concatenate([np.diff(xs), np.diff(ys)])
        assert gaps.min() >= 50.0 and gaps.max() <= 300.0
        area = (xs[-1] - xs[0]) * (ys[-1] - ys[0]) / 1e6
        assert 9.0 * 0.8 < area <= 9.0 * 1.05
        nx = len(xs)
        nodes += int(net.sum())
        for u in np.nonzero(net)[0]:
            out = [d for d in range(4) if adj[u, d] >= 0]
            neighbours = {int(adj[u, d]) for d in out}
            # streets in either direction touching u
            inc = set()
            for d in range(4):
                i, j = u % nx + world.DIR_DX[d], u // nx + world.DIR_DY[d]
                if 0 <= i < nx and 0 <= j < len(ys):
                    v = j * nx + i
                    if adj[v, (d + 2) % 4] == u:
                        inc.add(v)
            if len(neighbours | inc) == 1:
                dead_ends += 1
            for d in (0, 1):
                v = adj[u, d]
                back = -1
                i, j = u % nx + world.DIR_DX[d], u // nx + world.DIR_DY[d]
                if 0 <= i < nx and 0 <= j < len(ys):
                    back = adj[j * nx + i, d + 2]
                if v >= 0 and back == u:
                    two_way += 1
                elif (v >= 0) != (back == u):
                    one_way += 1
    frac = one_way / (one_way + two_way)
    assert 0.08 < frac < 0.18, frac  # 12 % of the segments left after dead ends
    assert 0.02 < dead_ends / nodes < 0.06, dead_ends / nodes  # 4 % asked for


def test_landmark_density() -> None:
    counts, areas = [], []
    for seed in range(30):
        xs, ys, adj, net = _city(seed, area=4.0)
        world.seed(1000 + seed)
        lm, _start, node_lms = world.place_landmarks(xs, ys, adj, net, 5.0)
        counts.append(len(lm))
        areas.append((xs[-1] - xs[0]) * (ys[-1] - ys[0]) / 1e6)
        # each landmark lies on a street and is listed at both ends of it
        assert len(node_lms) == 2 * len(lm)
        on_x = np.isclose(lm[:, 0][:, None], xs[None, :]).any(axis=1)
        on_y = np.isclose(lm[:, 1][:, None], ys[None, :]).any(axis=1)
        assert (on_x | on_y).all()
    density = sum(counts) / sum(areas)
    assert 4.5 < density < 5.5


def test_bicycle_straight_line() -> None:
    x, y, th, v = 1.0, 2.0, 0.3, 10.0
    for _ in range(100):
        x, y, th, v, _ = world.bicycle_step(x, y, th, v, 0.0, 0.0, 0.1, 2.946)
    assert (x, y) == pytest.approx((1.0 + 100 * math.cos(0.3), 2.0 + 100 * math.sin(0.3)))
    assert th == pytest.approx(0.3)
    # and with acceleration: d = v t + a t^2 / 2
    x, y, th, v = 0.0, 0.0, 0.0, 0.0
    for _ in range(50):
        x, y, th, v, _ = world.bicycle_step(x, y, th, v, 2.0, 0.0, 0.1, 2.946)
    assert x == pytest.approx(0.5 * 2.0 * 5.0**2) and v == pytest.approx(10.0)


@pytest.mark.parametrize("delta", [0.1, -0.3, 0.5])
def test_bicycle_constant_steering_is_a_circle(delta: float) -> None:
    L = 2.946
    rho = L / delta  # SPEC 4: rho = l / delta
    x, y, th, v = 0.0, 0.0, 0.0, 5.0
    cx, cy = 0.0, rho  # centre of the circle for heading 0 at the origin
    for _ in range(400):
        x, y, th, v, _ = world.bicycle_step(x, y, th, v, 0.0, delta, 0.05, L)
        assert math.hypot(x - cx, y - cy) == pytest.approx(abs(rho), rel=1e-9)
    assert th == pytest.approx(400 * 5.0 * 0.05 / rho)


def test_atan_within_an_ulp_of_the_library() -> None:
    """The steering's inline arctangent (fdlibm's reduction, Estrin's scheme) against numpy's,
    across its reduction's intervals and their ends, tiny and huge arguments."""
    gen = np.random.default_rng(1)
    xs = np.concatenate(
        [
            gen.uniform(-3.0, 3.0, 20_000),
            gen.normal(0.0, 1e-3, 2_000),
            10.0 ** gen.uniform(-300.0, 300.0, 2_000) * gen.choice([-1.0, 1.0], 2_000),
            np.array([0.0, 0.4375, 0.6875, 1.1875, 2.4375, -0.4375, -2.4375, 1e300, -1e300]),
        ]
    )
    got = np.array([world.atan(float(x)) for x in xs])
    want = np.arctan(xs)
    assert np.all(np.abs(got - want) <= np.spacing(np.abs(want)))
    assert world.atan(math.inf) == pytest.approx(math.pi / 2) and math.isnan(world.atan(math.nan))


def _distance_to_segment(x: float, y: float, ax: float, ay: float, bx: float, by: float) -> float:
    sx, sy = bx - ax, by - ay
    t = min(max(((x - ax) * sx + (y - ay) * sy) / (sx * sx + sy * sy), 0.0), 1.0)
    return math.hypot(x - ax - t * sx, y - ay - t * sy)


def test_pid_keeps_the_car_within_a_lane_of_the_route() -> None:
    """Distance from the car to its route (this street or the last one) stays under 3.5 m."""
    sim = SimParams()
    p = params.pack(sim, params.estimator_config(sim, 20.0), NavigatorConfig(), 1.0)
    worst = 0.0
    turns = 0
    for seed in range(5):
        xs, ys, adj, _net, lm, ns0, nl, ts, ns, _goal, _, _ = engine.setup_trial(seed, 0, 0.0, p)
        seen = -np.ones(len(lm), dtype=np.int64)
        ev = np.zeros(world.N_EVENTS)
        dirs = np.empty(4, dtype=np.int64)
        nx = len(xs)

        def pos(n: int) -> tuple[float, float]:
            return float(xs[n % nx]), float(ys[n // nx])  # noqa: B023

        prev = (int(ns[world.R_A]), int(ns[world.R_B]))
        turnaround = False
        for step in range(6000):
            before = (int(ns[world.R_A]), int(ns[world.R_B]))
            world.world_step(ts, ns, xs, ys, lm, ns0, nl, seen, p, True, 1.0, ev)
            if ev[4] > 0:
                n = world.exits_at(adj, ns[world.R_B], ns[world.R_A], dirs)
                ns[world.R_C] = adj[ns[world.R_B], dirs[step % n]]
            if ev[6] > 0:
                prev = before
                turns += 1
                # Back the way it came (a dead end): the simulator turns around on an arc at
                # full lock (~11 m across, where a real driver makes a three-point turn), so
                # the lane criterion does not apply on that street.
                turnaround = prev[0] == int(ns[world.R_B])
            if turnaround:
                continue
            cur = (int(ns[world.R_A]), int(ns[world.R_B]))
            d = min(_distance_to_segment(ts[0], ts[1], *pos(a), *pos(b)) for a, b in (cur, prev))
            worst = max(worst, d)
    assert turns > 50
    assert worst < 3.5, f"car strayed {worst:.2f} m from the route"


def test_wheel_encoders_quantise_and_integrate() -> None:
    """Whole counts: the sum of increments equals the true distance within one count."""
    sim = SimParams(wheel_slip_frac=0.0)
    p = params.pack(sim, params.estimator_config(sim, 20.0), NavigatorConfig(), 1.0)
    xs, ys, _adj, _net, lm, ns0, nl, ts, ns, _goal, _, _ = engine.setup_trial(3, 0, 0.0, p)
    seen = -np.ones(len(lm), dtype=np.int64)
    ev = np.zeros(world.N_EVENTS)
    total = np.zeros(2)
    for _ in range(300):
        world.world_step(ts, ns, xs, ys, lm, ns0, nl, seen, p, False, 1.0, ev)
        total += ev[:2]
        q = ev[:2] / sim.wheel_quantum_m
        assert np.allclose(q, np.round(q))
    driven = ts[world.T_DRIVEN]
    assert abs(total.mean() - driven) <= sim.wheel_quantum_m
