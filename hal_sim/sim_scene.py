"""The devices that only the simulated world (``hal_sim.sim_world.SimWorld``) can provide.

Two ``RoadwayScene``/source objects sit on top of it:

* ``SimScene`` is the roadway scene from the city graph: it emits ``IntersectionScene`` with
  the true exits and the distance to the intersection, and the simulated driver follows the
  navigator's decision (``follow``);
* ``SimSightings`` stands in for the camera and the landmark matcher until the image-based
  recogniser is plugged in: each sighting event of the world (a landmark within the sighting
  range, kept with the detection rate) becomes a ``LandmarkFix`` with ``sigma_m`` from the
  sim parameters. It is labelled ``sim_sightings`` in logs and stats, never "camera".
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from typing import Any

from guidance.core.messages import Approach, IntersectionScene, LandmarkFix
from hal_sim import world
from hal_sim.sim_world import SimWorld, StepEvents


class SimScene:
    """``RoadwayScene`` from the city graph: exits of the next intersection, with its distance."""

    name = "sim_scene"

    def __init__(self, world_: SimWorld) -> None:
        self.world = world_
        self._sink: Callable[[Any], None] | None = None
        self._counts: Counter[str] = Counter()
        self.approaching = False
        self._next_update_t = -math.inf

    def start(self, sink: Callable[[Any], None]) -> None:
        self._sink = sink

    def stop(self) -> None:
        self._sink = None

    def stats(self) -> dict[str, int]:
        return dict(self._counts)

    def announce(self, ev: StepEvents) -> IntersectionScene:
        """Tell the app about the intersection ahead (call when ``ev.decide``)."""
        exits = self.world.exits()
        msg = IntersectionScene(ev.t_s, tuple(exits), ev.to_intersection_m)
        self._counts["intersections"] += 1
        if self._sink is not None:
            self._sink(msg)
        return msg

    def follow(self, exit_index: int) -> None:
        """The simulated driver does as told."""
        self._counts["followed"] += 1
        self.world.take_exit(exit_index)
        self.approaching = True

    def update(self, ev: StepEvents, every_s: float = 0.5) -> None:
        """While driving up to a decided intersection, tell the app how far it is (the second
        announcement is timed on it); stop once the car has passed it."""
        if ev.passed:
            self.approaching = False
            return
        decided = int(self.world.ns[world.R_C]) >= 0  # the next exit is chosen: approaching it
        if (self.approaching or decided) and ev.t_s >= self._next_update_t:
            self._next_update_t = ev.t_s + every_s
            if self._sink is not None:
                self._sink(Approach(ev.t_s, ev.to_intersection_m))


class SimSightings:
    """Landmark fixes from the world's sighting events (a stand-in for camera + matcher)."""

    name = "sim_sightings"

    def __init__(self, world_: SimWorld) -> None:
        self.world = world_
        self.sigma_m = world_.sim.landmark_sigma_m
        self._sink: Callable[[LandmarkFix], None] | None = None
        self._counts: Counter[str] = Counter()

    def start(self, sink: Callable[[LandmarkFix], None]) -> None:
        self._sink = sink

    def stop(self) -> None:
        self._sink = None

    def stats(self) -> dict[str, int]:
        return dict(self._counts)

    def sighted(self, t_s: float, k: int) -> LandmarkFix:
        x, y = self.world.lm_xy[k]
        fix = LandmarkFix(t_s, k, float(x), float(y), self.sigma_m)
        self._counts["sightings"] += 1
        if self._sink is not None:
            self._sink(fix)
        return fix
