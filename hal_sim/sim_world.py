"""The simulated world for ``guidance sim``: ``SimWorld`` steps the compiled world of
``hal_sim.world`` (city, car, PID driver, encoders, compass noise, landmark sightings) with one
seed, and exposes per step what the simulated hardware must send: rear-wheel speeds (for the CAN
frames), the compass heading (for the NMEA sentences), a landmark sighting, and "an intersection
is coming, with these exits" (``hal_sim.sim_scene`` turns those into the scene and sightings).

The route (decisions taken so far, by step) is kept, so a world can be rebuilt exactly after a
crash by replaying the same seed and the same decisions (``replay_to``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.plan.navigator import Landmark, NavigatorConfig
from hal_sim import world
from hal_sim.params import I_COMPASS_PERIOD, I_DETECT, I_DT, SimParams, pack


@dataclass(frozen=True, slots=True)
class StepEvents:
    """What the world's sensors produced in one step (time ``t_s`` at its end)."""

    t_s: float
    step: int
    left_mps: float
    right_mps: float
    heading_rad: float | None
    """Compass reading in the filter frame (truth + noise), None when none is due."""
    landmark: int | None
    decide: bool
    to_intersection_m: float
    passed: bool = False
    """The car has just passed the intersection it was driving to."""


@dataclass(frozen=True, slots=True)
class WorldSpec:
    """How the city, start and goal are drawn (``guidance sim`` options)."""

    seed: int = 7
    area_km2: float = 9.0
    goal_min_m: float = 1200.0
    goal_max_m: float = 2500.0
    density_per_km2: float = 1.0
    detection_rate: float = 0.6


class SimWorld:
    """One seeded city and car, stepped by ``step``; the truth for plots and errors."""

    def __init__(
        self,
        spec: WorldSpec,
        sim: SimParams,
        est: EstimatorConfig,
        nav: NavigatorConfig,
        true_compass_two_sigma_deg: float | None = -1.0,
    ) -> None:
        self.spec = spec
        self.sim = sim
        self.est = est
        self.nav = nav
        self.p = pack(sim, est, nav, spec.detection_rate, true_compass_two_sigma_deg)
        world.seed(spec.seed)
        aspect = float(np.random.default_rng(spec.seed).uniform(0.8, 1.25))
        self.xs, self.ys, self.adj, self.net = world.make_city(
            spec.area_km2, aspect, sim.block_m_min, sim.block_m_max, sim.dead_end_frac,
            sim.one_way_frac,
        )  # fmt: skip
        self.lm_xy, self.node_start, self.node_lms = world.place_landmarks(
            self.xs, self.ys, self.adj, self.net, spec.density_per_km2
        )
        self.start = world.random_node(self.net)
        self.goal_node = self._pick_goal(spec)
        self._goal_rng = np.random.default_rng([spec.seed, 2])
        self.ts, self.ns = world.init_truth(self.xs, self.ys, self.adj, self.start, self.p)
        self.start_heading_rad = float(self.ts[world.T_TH])
        self.lm_seen = -np.ones(len(self.lm_xy), dtype=np.int64)
        self._events = np.zeros(world.N_EVENTS)
        self._dirs = np.empty(4, dtype=np.int64)
        self.step_count = 0
        self.dt_s = float(self.p[I_DT])
        self.route: list[tuple[int, int]] = []
        """(step, node chosen) for each decision: with the seed, enough to rebuild the world."""
        self._pending_dirs: list[int] = []

    def _pick_goal(self, spec: WorldSpec) -> int:
        """The first goal: a node between goal_min_m and goal_max_m from the start."""
        sx, sy = world.node_pos(self.xs, self.ys, self.start)
        return self._goal_around(float(sx), float(sy), np.random.default_rng(spec.seed + 1))

    def new_goal(self) -> None:
        """The field protocol's next goal, around where the car is now."""
        cx, cy, _ = self.truth
        self.goal_node = self._goal_around(cx, cy, self._goal_rng)

    def _goal_around(self, x: float, y: float, rng: np.random.Generator) -> int:
        """A random network node between goal_min_m and goal_max_m (Euclidean) from (x, y);
        in a city too small for that, the farthest node."""
        nx = self.xs.shape[0]
        idx = np.nonzero(self.net)[0]
        d = np.hypot(self.xs[idx % nx] - x, self.ys[idx // nx] - y)
        ok = idx[(d >= self.spec.goal_min_m) & (d <= self.spec.goal_max_m)]
        if len(ok) == 0:
            return int(idx[int(np.argmax(d))])
        return int(ok[rng.integers(len(ok))])

    # -- views --------------------------------------------------------------------------------
    @property
    def t_s(self) -> float:
        return self.step_count * self.dt_s

    @property
    def truth(self) -> tuple[float, float, float]:
        return float(self.ts[world.T_X]), float(self.ts[world.T_Y]), float(self.ts[world.T_TH])

    @property
    def driven_m(self) -> float:
        return float(self.ts[world.T_DRIVEN])

    @property
    def start_pose(self) -> tuple[float, float, float]:
        sx, sy = world.node_pos(self.xs, self.ys, self.start)
        return float(sx), float(sy), self.start_heading_rad

    @property
    def goal_xy(self) -> tuple[float, float]:
        gx, gy = world.node_pos(self.xs, self.ys, self.goal_node)
        return float(gx), float(gy)

    def landmarks(self) -> tuple[Landmark, ...]:
        return tuple(
            Landmark(k, float(self.lm_xy[k, 0]), float(self.lm_xy[k, 1]), landmark_name(k))
            for k in range(len(self.lm_xy))
        )

    def streets(self) -> list[tuple[float, float, float, float]]:
        """Street segments (x0, y0, x1, y1) of the network, for plots."""
        nx = self.xs.shape[0]
        out = []
        for u in range(self.adj.shape[0]):
            for d in range(4):
                v = int(self.adj[u, d])
                if v > u or (v >= 0 and self.adj[v, (d + 2) % 4] != u):
                    out.append(
                        (float(self.xs[u % nx]), float(self.ys[u // nx]),
                         float(self.xs[v % nx]), float(self.ys[v // nx]))
                    )  # fmt: skip
        return out

    # -- stepping -------------------------------------------------------------------------------
    def step(self) -> StepEvents:
        """Advance one ``dt``; the car follows its route (decided exits) with the PID driver."""
        period = float(self.p[I_COMPASS_PERIOD])
        s = self.step_count
        due = math.floor((s + 1) / period) > math.floor(s / period)
        ev = self._events
        world.world_step(
            self.ts, self.ns, self.xs, self.ys, self.lm_xy, self.node_start, self.node_lms,
            self.lm_seen, self.p, due, self.p[I_DETECT], ev,
        )  # fmt: skip
        self.step_count += 1
        dt = self.dt_s
        return StepEvents(
            t_s=self.t_s,
            step=self.step_count,
            left_mps=float(ev[0]) / dt,
            right_mps=float(ev[1]) / dt,
            heading_rad=None if math.isnan(ev[2]) else float(ev[2]),
            landmark=int(ev[3]) if ev[3] >= 0.0 else None,
            decide=ev[4] > 0.0,
            to_intersection_m=float(ev[5]),
            passed=ev[6] > 0.0,
        )

    def exits(self) -> list[float]:
        """Headings (filter frame) of the exits of the intersection ahead."""
        n = world.exits_at(self.adj, int(self.ns[world.R_B]), self.ns[world.R_A], self._dirs)
        self._pending_dirs = [int(self._dirs[e]) for e in range(n)]
        return [float(world.DIR_HEADING[d]) for d in self._pending_dirs]

    def exits_of(self, node: int, came_from: int) -> list[float]:
        """Headings of the exits of ``node`` reached from ``came_from`` (an intersection
        further ahead), in the order ``exits()`` will give them there."""
        dirs = np.empty(4, dtype=np.int64)
        n = world.exits_at(self.adj, int(node), int(came_from), dirs)
        return [float(world.DIR_HEADING[int(dirs[e])]) for e in range(n)]

    def take_exit(self, index: int) -> None:
        """The simulated driver commits to exit ``index`` of the last ``exits()``."""
        b = int(self.ns[world.R_B])
        node = int(self.adj[b, self._pending_dirs[index]])
        self.ns[world.R_C] = node
        self.route.append((self.step_count, node))

    def replay_to(self, step: int, route: Sequence[Sequence[int]]) -> None:
        """Rebuild the world at ``step`` from the seed and the route (checkpoint resume)."""
        pending = {int(s): int(n) for s, n in route}
        while self.step_count < step:
            self.step()
            node = pending.get(self.step_count)
            if node is not None:
                self.ns[world.R_C] = node
                self.route.append((self.step_count, node))


_PLACES = ("bakery", "town hall", "red church", "post office", "library", "clock tower",
           "fire station", "old mill", "bank", "theatre", "fountain", "school", "museum",
           "hotel", "pharmacy", "market hall", "bridge", "cinema")  # fmt: skip
_STREETS = ("Elm", "Oak", "Main", "Mill", "Park", "Lake", "Hill", "Church", "King", "Queen",
            "Bridge", "Station", "Market")  # fmt: skip


def landmark_name(k: int) -> str:
    """A name a driver can hear for simulated landmark k ("the bakery on Elm Street")."""
    place = _PLACES[k % len(_PLACES)]
    street = _STREETS[(k // len(_PLACES)) % len(_STREETS)]
    return f"the {place} on {street} Street"
