"""Intersection navigator (SPEC section 3): which exit to take, toward which target, and why.

Its values (``Method``, ``Landmark``, ``ExitOption``, ``Decision``) are in
``guidance.core.messages`` with the other values the core hands out; re-exported here.

The math (decision law, revisit matching, tabu penalties, landmark targets,
hybrid switching) is in ``guidance.law`` and shared with the study engine; this
class keeps the navigator's memory and returns each decision as a value that
can be spoken, published and logged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from guidance.config_tables import rule
from guidance.core import law, model
from guidance.core.messages import Decision, ExitOption, Landmark, Method, Target
from guidance.core.snapshot_check import integer


@dataclass(frozen=True, slots=True)
class NavigatorConfig:
    """The navigator's settings; each default and rule is the car's (``[navigation]`` reads
    these; ``read=False``: fixed by the program, recorded with the session)."""

    method: Method = Method.HYBRID
    """SPEC's best of the three: straight to the goal, landmark to landmark once the 2-sigma
    major axis exceeds ``hybrid_switch_m``."""
    tabu_step_rad: float = field(default=math.radians(60.0), metadata=rule(lo=0.0, degrees=True))
    """Penalty added per earlier use of the same exit at the same intersection."""
    lookahead_m: float = field(default=10.0, metadata=rule(positive=True))
    """Bearings are taken from this far along each exit ("after the intersection")."""
    arrival_radius_m: float = field(default=30.0, metadata=rule(positive=True))
    hybrid_switch_m: float = field(default=50.0, metadata=rule(positive=True))
    """Hybrid: landmarks when the major axis exceeds this, goal again after a fix below it."""
    landmark_pass_radius_m: float = field(default=20.0, metadata=rule(positive=True))
    """A landmark target counts as passed once the estimate comes this close (or it is seen)."""
    revisit_gate_chi2: float = field(
        default=model.CHI2_2D_2SIGMA, metadata=rule(positive=True, read=False)
    )
    """Revisit: a remembered intersection inside the current 2-sigma ellipse (86.5%)."""
    revisit_floor_sigma_m: float = field(default=8.0, metadata=rule(lo=0.0, read=False))
    """Floor on the revisit ellipse: an intersection is a patch of road, not a point."""
    exit_match_tol_rad: float = field(
        default=math.radians(30.0), metadata=rule(lo=0.0, read=False)
    )
    max_intersections: int = field(default=4096, metadata=rule(lo=1, hi=100_000, read=False))
    """Sizes the intersection memory's arrays."""
    max_exits: int = field(default=8, metadata=rule(lo=1, hi=64, read=False))


__all__ = ["Decision", "ExitOption", "Landmark", "Method", "Navigator", "NavigatorConfig"]


class Navigator:
    """Holds the goal, the landmarks, the intersection memory and the method's mode. With no
    goal (None, until ``set_goal``) it never arrives and has nothing to decide for: ``target``,
    ``decide`` and ``evaluate`` raise ``ValueError`` (the planner asks none of them then)."""

    def __init__(
        self,
        goal_xy: tuple[float, float] | None,
        config: NavigatorConfig | None = None,
        landmarks: Sequence[Landmark] = (),
    ) -> None:
        self.config = config or NavigatorConfig()
        self.goal = _point(goal_xy)
        self.landmarks = tuple(landmarks)
        self._lm_xy = np.array([[lm.x_m, lm.y_m] for lm in self.landmarks], dtype=float).reshape(
            -1, 2
        )
        self._passed = np.zeros(len(self.landmarks), dtype=np.bool_)
        n, k = self.config.max_intersections, self.config.max_exits
        self._mem_xy = np.zeros((n, 2))
        self._mem_headings = np.zeros((n, k))
        self._mem_counts = np.zeros((n, k), dtype=np.int64)
        self._n_mem = 0
        self._mode = (
            law.MODE_LANDMARK
            if self.config.method is Method.LANDMARK_TO_LANDMARK
            else (law.MODE_GOAL)
        )
        self.decisions = 0
        c = self.config
        self._params = law.decide_params(
            c.revisit_gate_chi2, c.revisit_floor_sigma_m, c.tabu_step_rad,
            c.exit_match_tol_rad, c.landmark_pass_radius_m, c.lookahead_m,
        )  # fmt: skip

    # -- goal and landmarks ---------------------------------------------------
    def set_goal(self, goal_xy: tuple[float, float]) -> None:
        """A new goal (field protocol or a remote command): forget passed landmarks."""
        self.goal = _point(goal_xy)
        self._passed[:] = False

    @property
    def mode(self) -> str:
        return "landmark" if self._mode == law.MODE_LANDMARK else "goal"

    def arrived(self, x: Sequence[float] | np.ndarray) -> bool:
        """Within the arrival radius of the goal (``x``: the position first, x then y); never
        with no goal."""
        if self.goal is None:
            return False
        return math.hypot(self.goal[0] - x[0], self.goal[1] - x[1]) <= self.config.arrival_radius_m

    def update_mode(self, major_axis_m: float, landmark_update: bool = False) -> None:
        """Hybrid switching; call after each estimator step that matters (cheap)."""
        self._mode = law.next_mode(
            self.config.method.code,
            self._mode,
            major_axis_m,
            self.config.hybrid_switch_m,
            landmark_update,
        )

    def on_landmark_fix(self, landmark_id: int, major_axis_m: float) -> None:
        """A landmark was seen: it is passed, and hybrid may return to the goal."""
        for k, lm in enumerate(self.landmarks):
            if lm.id == landmark_id:
                self._passed[k] = True
        self.update_mode(major_axis_m, landmark_update=True)

    def target(self, x: Sequence[float] | np.ndarray) -> Target:
        """The current target (a view: the goal, or the landmark the car aims at from ``x``).

        Landmarks within the pass radius of ``x`` count as passed for this answer only: the
        navigator marks them passed at the next decision (``law.decide_exit``), as the study
        engine does, so showing the target never changes what the car decides."""
        gx, gy = self._goal()
        if self._mode == law.MODE_LANDMARK and len(self.landmarks):
            passed = self._passed.copy()
            law.mark_passed(float(x[0]), float(x[1]), self._lm_xy, passed,
                            self.config.landmark_pass_radius_m)  # fmt: skip
            k = law.landmark_target(float(x[0]), float(x[1]), gx, gy, self._lm_xy, passed)
            if k >= 0:
                lm = self.landmarks[k]
                return Target(lm.x_m, lm.y_m, "landmark", lm.id)
        return Target(gx, gy, "goal", None)

    # -- the decision -------------------------------------------------------
    def decide(
        self, t_s: float, x: np.ndarray, P: np.ndarray, exit_headings: Sequence[float]
    ) -> Decision:
        """Choose an exit at an intersection reached at estimate ``x`` with covariance ``P``,
        and record it as taken (``law.decide_exit``: the study engine's step, for a car that
        decides at the intersection and always follows)."""
        headings = self._headings(exit_headings)
        gx, gy = self._goal()
        self.update_mode(float(model.major_axis_m(P)))
        penalties = np.zeros(len(headings))
        costs = np.zeros(len(headings))
        best, k, revisit, self._n_mem, target = law.decide_exit(
            float(x[0]), float(x[1]), float(P[0, 0]), float(P[0, 1]), float(P[1, 1]),
            headings, self._mem_xy, self._mem_headings, self._mem_counts, self._n_mem,
            self._passed, self._lm_xy, gx, gy, self._mode, self._params,
            penalties, costs,
        )  # fmt: skip
        self.decisions += 1
        heading = float(x[model.STATE_THETA])
        return self._decision(t_s, heading, headings, penalties, costs, best, k, revisit,
                              target)  # fmt: skip

    def evaluate(
        self,
        t_s: float,
        at_xy: tuple[float, float],
        P: np.ndarray,
        exit_headings: Sequence[float],
        approach_heading_rad: float,
        from_xy: tuple[float, float] | None = None,
    ) -> Decision:
        """The decision for an intersection still ahead, predicted at ``at_xy`` and approached
        on a road of heading ``approach_heading_rad`` (the turns are relative to it), from the
        car at ``from_xy`` (the landmarks it passes on the way are passed by then). Nothing
        is remembered (``law.evaluate_exit``): the car re-evaluates as it approaches and
        ``commit`` records the exit it took once it is through."""
        headings = self._headings(exit_headings)
        gx, gy = self._goal()
        penalties = np.zeros(len(headings))
        costs = np.zeros(len(headings))
        passed = self._passed.copy()
        if from_xy is not None and len(self.landmarks):
            law.mark_passed_along(float(from_xy[0]), float(from_xy[1]), float(at_xy[0]),
                                  float(at_xy[1]), self._lm_xy, passed,
                                  self.config.landmark_pass_radius_m)  # fmt: skip
        best, k, target = law.evaluate_exit(
            float(at_xy[0]), float(at_xy[1]), float(P[0, 0]), float(P[0, 1]), float(P[1, 1]),
            headings, self._mem_xy, self._mem_headings, self._mem_counts, self._n_mem,
            passed, self._lm_xy, gx, gy, self._mode,
            self._params, penalties, costs,
        )  # fmt: skip
        return self._decision(t_s, approach_heading_rad, headings, penalties, costs, best, k,
                              k >= 0, target)  # fmt: skip

    def commit(self, xy: tuple[float, float], P: np.ndarray, heading_taken_rad: float) -> int:
        """The car went through an intersection at ``xy`` (the estimate when it got there) by
        the exit of heading ``heading_taken_rad``: remembered, landmarks there passed, the exit
        counted for the tabu law (``law.commit_exit``). Returns the intersection's index."""
        x, y = float(xy[0]), float(xy[1])
        k, _revisit, self._n_mem = law.commit_exit(
            x, y, float(P[0, 0]), float(P[0, 1]), float(P[1, 1]),
            float(model.wrap_angle(heading_taken_rad)), self._mem_xy, self._mem_headings,
            self._mem_counts, self._n_mem, self._params,
        )  # fmt: skip
        if len(self.landmarks):
            law.mark_passed(x, y, self._lm_xy, self._passed, self.config.landmark_pass_radius_m)
        self.decisions += 1
        return int(k)

    def _goal(self) -> tuple[float, float]:
        if self.goal is None:
            raise ValueError("the navigator has no goal: nothing to aim or decide for")
        return self.goal

    @staticmethod
    def _headings(exit_headings: Sequence[float]) -> np.ndarray:
        if not exit_headings:
            raise ValueError("an intersection needs at least one exit")
        return np.array([model.wrap_angle(float(h)) for h in exit_headings])

    def _decision(
        self,
        t_s: float,
        heading: float,
        headings: np.ndarray,
        penalties: np.ndarray,
        costs: np.ndarray,
        best: int,
        k: int,
        revisit: bool,
        target: int,
    ) -> Decision:
        if target >= 0:
            lm = self.landmarks[target]
            tx, ty, kind, tid = lm.x_m, lm.y_m, "landmark", lm.id
        else:
            (tx, ty), kind, tid = self._goal(), "goal", None
        options = tuple(
            ExitOption(
                index=i,
                heading_rad=float(h),
                turn_rad=float(model.wrap_angle(h - heading)),
                angle_cost_rad=float(costs[i] - penalties[i]),
                penalty_rad=float(penalties[i]),
                cost_rad=float(costs[i]),
            )
            for i, h in enumerate(headings)
        )
        chosen = options[best]
        reason = (
            f"exit {best} toward {kind}"
            + (f" {tid}" if tid is not None else "")
            + f": angle {math.degrees(chosen.angle_cost_rad):.0f} deg"
            + (f" + tabu {math.degrees(chosen.penalty_rad):.0f} deg" if chosen.penalty_rad else "")
            + (" (revisit)" if revisit else "")
        )
        return Decision(
            t_s=t_s,
            exit_index=best,
            exit_heading_rad=chosen.heading_rad,
            turn_rad=chosen.turn_rad,
            options=options,
            target_x_m=tx,
            target_y_m=ty,
            target_kind=kind,
            target_id=tid,
            intersection_id=int(k),
            revisit=revisit,
            mode=self.mode,
            reason=reason,
        )

    @property
    def remembered_intersections(self) -> int:
        return self._n_mem

    # -- checkpointing --------------------------------------------------------
    def memory(self) -> dict[str, object]:
        """The navigator's memory as plain data (for checkpoints)."""
        n = self._n_mem
        return {
            "goal": None if self.goal is None else list(self.goal),
            "mode": self._mode,
            "passed": self._passed.tolist(),
            "mem_xy": self._mem_xy[:n].tolist(),
            "mem_headings": self._mem_headings[:n].tolist(),
            "mem_counts": self._mem_counts[:n].tolist(),
        }

    def restore(self, memory: dict[str, object]) -> None:
        goal = memory["goal"]
        assert goal is None or isinstance(goal, list)
        self.goal = None if goal is None else (float(goal[0]), float(goal[1]))
        self._mode = integer(memory["mode"], "navigator.mode", hi=1)
        self._passed[:] = np.asarray(memory["passed"], dtype=np.bool_)
        xy = np.asarray(memory["mem_xy"], dtype=float).reshape(-1, 2)
        n = len(xy)
        width = self._mem_headings.shape[1]
        self._n_mem = n
        self._mem_xy[:n] = xy
        self._mem_headings[:n] = np.asarray(memory["mem_headings"], dtype=float).reshape(n, width)
        self._mem_counts[:n] = np.asarray(memory["mem_counts"], dtype=np.int64).reshape(n, width)
        self._mem_counts[n:] = 0


def _point(xy: tuple[float, float] | None) -> tuple[float, float] | None:
    return None if xy is None else (float(xy[0]), float(xy[1]))
