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
import random
from collections import Counter
from collections.abc import Callable
from typing import Any

from guidance.core.co_driver import EXIT_TOKENS
from guidance.core.messages import Approach, IntersectionScene, LandmarkFix, reset_sigma_m
from guidance.core.model import wrap_angle
from hal_sim import world
from hal_sim.sim_world import SimWorld, StepEvents


class SimScene:
    """``RoadwayScene`` from the city graph, and the simulated driver who follows the advice.

    Each intersection is reported once, when it comes into view (``decision_distance_m``), with
    its true exits and its distance (``due_report``); with ``report_next``, the one after it is
    reported too as soon as it is in view behind it (``due_next``), so a "then" can be said.
    The driver follows the exit the car plans for each report (``follow``, every step: a
    changed instruction is followed until the car is through). ``exits_line`` is the same
    intersection as a co-driver would type it, relative to the road it is approached on."""

    name = "sim_scene"

    def __init__(
        self, world_: SimWorld, report_next: bool = True, drive_on_seed: int | None = None
    ) -> None:
        self.world = world_
        self.report_next = report_next
        self._drive_on = None if drive_on_seed is None else random.Random(drive_on_seed)
        """A driver told nothing by the corner (``OWN_CHOICE_M``: a car that started anywhere,
        before its first landmark; an intersection the car could no longer place after a CAN
        gap) chooses an exit at random, never back the way it came unless it must: with
        None, the car drives on past the corner, off the streets."""
        self._to_b = math.inf
        self._sink: Callable[[Any], None] | None = None
        self._counts: Counter[str] = Counter()
        self.approaching = False
        self._next_update_t = -math.inf
        self._b = -1
        """The world's next node, once reported (or taken over from ``_next``)."""
        self._seq: int | None = None
        """The car's report number for ``_b``."""
        self._followed: int | None = None
        self._own = False
        """The exit followed is the driver's own choice (``drive_on_seed``), not a plan."""
        self._next: tuple[int, int | None] | None = None
        """(node, report number) of the intersection after ``_b``, reported ahead."""

    def start(self, sink: Callable[[Any], None]) -> None:
        self._sink = sink

    def stop(self) -> None:
        self._sink = None

    def stats(self) -> dict[str, int]:
        return dict(self._counts)

    def send(self, msg: Any) -> None:
        if self._sink is not None:
            self._sink(msg)

    def due_report(self, ev: StepEvents) -> IntersectionScene | None:
        """The intersection ahead, the first time it is in view (None: nothing new to report;
        one already reported behind the previous one is taken over, not reported again)."""
        b = int(self.world.ns[world.R_B])
        if b == self._b:
            return None
        if self._next is not None and self._next[0] == b:
            self.world.exits()
            self._b, self._seq, self._followed = b, self._next[1], None
            self._next = None
            return None
        if not ev.decide:
            return None
        self._b, self._seq, self._followed, self._next = b, None, None, None
        msg = IntersectionScene(ev.t_s, tuple(self.world.exits()), ev.to_intersection_m)
        self._counts["intersections"] += 1
        return msg

    def reported(self, seq: int) -> None:
        """The car took the last ``due_report`` as its report ``seq``."""
        self._seq = seq

    def exits_line(self) -> str:
        """The intersection ahead as a co-driver types it ("l s r"), relative to the road it
        is approached on (the street the car is on now, even while it is still turning in)."""
        road = float(self.world.ts[world.T_SEG_H])
        words = []
        for h in self.world.exits():
            rel = wrap_angle(h - road)
            words.append(min(_TYPED, key=lambda k: abs(wrap_angle(_TYPED[k] - rel))))
        return " ".join(words)

    def follow(self, planned: Callable[[int], int | None]) -> None:
        """The simulated driver does as told: the exit the car plans now for the intersection
        ahead (until the world has committed to it)."""
        if int(self.world.ns[world.R_B]) != self._b:
            return
        exit_index = None if self._seq is None else planned(self._seq)
        self._own = False
        if exit_index is None and self._drive_on is not None and self._to_b <= OWN_CHOICE_M:
            if self._followed is not None:
                self._own = True  # still the driver's own choice: nothing planned yet
                return
            exit_index, self._own = self._own_choice(self._drive_on), True
        if exit_index is None or exit_index == self._followed:
            return
        if self._followed is not None:
            self._counts["changed"] += 1
        self._counts["followed"] += 1
        self._followed = exit_index
        self.world.take_exit(exit_index)
        self.approaching = True

    def _own_choice(self, rng: random.Random) -> int | None:
        exits = self.world.exits()
        road = float(self.world.ts[world.T_SEG_H])
        ahead = [i for i, h in enumerate(exits) if abs(wrap_angle(h - road)) < 2.5]
        return rng.choice(ahead or list(range(len(exits)))) if exits else None

    def due_next(self, ev: StepEvents) -> IntersectionScene | None:
        """With ``report_next``: the intersection after the one ahead, once the driver knows
        which way to leave that one and it is in view too."""
        if not self.report_next or self._followed is None or self._next is not None or self._own:
            return None  # (the road beyond an exit the driver chose alone may not be taken)
        c = int(self.world.ns[world.R_C])
        if c < 0:
            return None
        b = self._b
        bx, by = world.node_pos(self.world.xs, self.world.ys, b)
        cx, cy = world.node_pos(self.world.xs, self.world.ys, c)
        dist = ev.to_intersection_m + math.hypot(cx - bx, cy - by)
        if dist > self.world.sim.decision_distance_m:
            return None
        headings = self.world.exits_of(c, b)
        self._next = (c, None)
        self._counts["intersections"] += 1
        return IntersectionScene(ev.t_s, tuple(headings), dist)

    def reported_next(self, seq: int) -> None:
        if self._next is not None:
            self._next = (self._next[0], seq)

    def update(self, ev: StepEvents, every_s: float = 0.5) -> None:
        """While driving up to a decided intersection, tell the app how far it is (the second
        announcement is timed on it); stop once the car has passed it."""
        self._to_b = ev.to_intersection_m
        if ev.passed:
            self.approaching = False
            return
        decided = int(self.world.ns[world.R_C]) >= 0  # the next exit is chosen: approaching it
        if (self.approaching or decided) and ev.t_s >= self._next_update_t:
            self._next_update_t = ev.t_s + every_s
            self.send(Approach(ev.t_s, ev.to_intersection_m))


OWN_CHOICE_M = 20.0
"""A simulated driver told nothing chooses alone this far before the corner (``SimScene``)."""

_TYPED = {tok: EXIT_TOKENS[tok] for tok in ("s", "l", "r", "u", "bl", "br", "hl", "hr")}
"""The co-driver's short tokens and their angles (rad, left positive), from the parser's table."""


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

    def sighted(self, t_s: float, k: int, *, relocalised: bool = False) -> LandmarkFix:
        """Landmark ``k`` sighted (``sighting_fix``)."""
        fix = sighting_fix(self.world, t_s, k, relocalised)
        self._counts["sightings"] += 1
        if self._sink is not None:
            self._sink(fix)
        return fix


def sighting_fix(world_: Any, t_s: float, k: int, relocalised: bool) -> LandmarkFix:
    """The fix a sighting of landmark ``k`` gives the car: ``landmark_sigma_m`` (the sighting
    range and the landmark's sigma); ``relocalised`` (the car is lost and looks for itself):
    the sighting stands for a whole-database search's find, its sigma ``reset_sigma_m`` (the
    simulated landmarks stand exactly where the database says)."""
    x, y = world_.lm_xy[k]
    sim = world_.sim
    sigma = reset_sigma_m(sim.sighting_range_m, 0.0) if relocalised else sim.landmark_sigma_m
    return LandmarkFix(t_s, k, float(x), float(y), sigma, relocalised)
