"""Checking a pipeline snapshot (a checkpoint's ``pipeline``) before any of it is used (issue 14).

A checkpoint is a file from outside the process: it may be damaged, hand-edited, from another
version or written by a process that had already gone wrong. ``check_snapshot`` looks at every
value ``Pipeline.restore`` reads and raises ``SnapshotError`` (one line, naming the field) unless
each is of the right type (numbers are JSON numbers, never text or booleans), finite, within the
bounds the consumer needs (a covariance as the estimator judges one and the learned states
within their physical range: the first stage's ``state_limits.state_problem``, handed in by
the pipeline, so that the planner's checks here load nothing of ``core/localize``; a
position within ``MAX_OFFSET_M`` of the trip's start, a speed a car can drive) and of a
bounded size (the navigator's memory fits its arrays). Nothing is changed: ``restore`` runs
only after it passed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from guidance.errors import checked_number

StateJudge = Callable[[Sequence[float], np.ndarray, Sequence[float] | None], str | None]
"""Why an estimator state ``(x, P)`` with its ``prior_variances`` is not valid, or None
(``guidance.core.localize.state_limits.state_problem``)."""

MAX_OFFSET_M = 200_000.0
"""A restored position farther than this from the trip's start is not believed (an urban trip)."""
MAX_SIGMA_M = 100_000.0
"""Position standard deviations above this are not a state, they are a fault."""
MAX_SPEED_MPS = 90.0
"""The CAN driver's implausible-speed limit."""
MAX_COUNT = 10**9
MAX_TURN_SAMPLES = 10_000
MAX_ODOMETER_M = 1e8


class SnapshotError(ValueError):
    """A snapshot value that must not be restored; the message is one line naming the field."""


def _number(snap: Mapping[str, object], key: str, lo: float, hi: float, default: float) -> float:
    v = snap.get(key, default)
    return number(v, key, lo, hi)


def number(v: object, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """``v`` as a finite float in [lo, hi]; only JSON numbers (int or float, not bool)."""
    return checked_number(v, where, lo, hi, error=SnapshotError)


def integer(v: object, where: str, lo: int = 0, hi: int = MAX_COUNT) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise SnapshotError(f"{where} must be an integer, not {type(v).__name__}")
    if not lo <= v <= hi:
        raise SnapshotError(f"{where} is outside [{lo}, {hi}]")
    return v


def _list(v: object, where: str, max_len: int) -> Sequence[object]:
    if not isinstance(v, list | tuple):
        raise SnapshotError(f"{where} must be a list, not {type(v).__name__}")
    if len(v) > max_len:
        raise SnapshotError(f"{where} has {len(v)} entries, at most {max_len} allowed")
    return v


def _matrix(v: object, where: str, rows: int, cols: int, max_rows: int | None = None) -> np.ndarray:
    """A list of ``rows`` lists of ``cols`` finite numbers (rows may be any count up to
    ``max_rows`` when given)."""
    outer = _list(v, where, max_rows if max_rows is not None else rows)
    if max_rows is None and len(outer) != rows:
        raise SnapshotError(f"{where} must have {rows} rows, not {len(outer)}")
    out = np.zeros((len(outer), cols))
    for i, row in enumerate(outer):
        r = _list(row, f"{where}[{i}]", cols)
        if len(r) != cols:
            raise SnapshotError(f"{where}[{i}] must have {cols} values, not {len(r)}")
        for j, x in enumerate(r):
            out[i, j] = number(x, f"{where}[{i}][{j}]")
    return out


def check_state(
    x: object,
    P: object,
    n_state: int,
    start_xy: tuple[float, float],
    state_problem: StateJudge,
    prior_variances: Sequence[float] | None = None,
) -> None:
    """The estimator state: a vector of 3 or ``n_state`` numbers and its covariance, valid as
    the estimator judges one (``state_problem``: positive-definite but for the
    states whose ``prior_variances`` are zero by design, the learned states within their
    physical range)."""
    xs = _list(x, "x", n_state)
    if len(xs) not in (3, n_state):
        raise SnapshotError(f"x must have 3 or {n_state} values, not {len(xs)}")
    vec = [number(v, f"x[{i}]") for i, v in enumerate(xs)]
    off = math.hypot(vec[0] - start_xy[0], vec[1] - start_xy[1])
    if off > MAX_OFFSET_M:
        raise SnapshotError(
            f"x puts the car {off / 1000:.0f} km from the trip's start (at most "
            f"{MAX_OFFSET_M / 1000:.0f} km)"
        )
    if abs(vec[2]) > 100.0:
        raise SnapshotError(f"x[2] (heading) = {vec[2]:.6g} rad is not an angle")
    cov = _matrix(P, "P", len(vec), len(vec))
    if max(cov[0, 0], cov[1, 1]) > MAX_SIGMA_M**2:
        raise SnapshotError(f"P: a position sigma above {MAX_SIGMA_M:.0f} m")
    why = state_problem(vec, cov, prior_variances)
    if why is not None:
        raise SnapshotError(why)


def check_navigator(nav: object, n_landmarks: int, capacity: int, width: int) -> None:
    if not isinstance(nav, dict):
        raise SnapshotError(f"navigator must be a table, not {type(nav).__name__}")
    if "goal" not in nav:
        raise SnapshotError("navigator.goal is missing")
    if nav["goal"] is not None:  # null: no goal yet
        goal = _list(nav.get("goal"), "navigator.goal", 2)
        if len(goal) != 2:
            raise SnapshotError("navigator.goal must be [x, y] or null")
        for i, v in enumerate(goal):
            number(v, f"navigator.goal[{i}]", -1e9, 1e9)
    integer(nav.get("mode"), "navigator.mode", 0, 1)
    passed = _list(nav.get("passed"), "navigator.passed", n_landmarks)
    if len(passed) != n_landmarks or not all(isinstance(p, bool) for p in passed):
        raise SnapshotError(f"navigator.passed must be {n_landmarks} true/false values")
    xy = _matrix(nav.get("mem_xy"), "navigator.mem_xy", 0, 2, max_rows=capacity)
    n = len(xy)
    heads = _matrix(nav.get("mem_headings"), "navigator.mem_headings", n, width)
    del heads
    counts = _list(nav.get("mem_counts"), "navigator.mem_counts", n)
    if len(counts) != n:
        raise SnapshotError(f"navigator.mem_counts must have {n} rows")
    for i, row in enumerate(counts):
        r = _list(row, f"navigator.mem_counts[{i}]", width)
        if len(r) != width:
            raise SnapshotError(f"navigator.mem_counts[{i}] must have {width} values")
        for j, c in enumerate(r):
            integer(c, f"navigator.mem_counts[{i}][{j}]")


def check_turns(turns: object) -> None:
    if turns is None:
        return
    if not isinstance(turns, dict):
        raise SnapshotError(f"turns must be a table, not {type(turns).__name__}")
    _matrix(turns.get("samples", []), "turns.samples", 0, 2, max_rows=MAX_TURN_SAMPLES)
    if turns.get("last_raw") is not None:
        number(turns["last_raw"], "turns.last_raw")
    number(turns.get("unwrapped", 0.0), "turns.unwrapped")
    integer(turns.get("turns", 0), "turns.turns")


def check_decision(d: object, where: str) -> None:
    """A decision as a checkpoint holds it (``dataclasses.asdict`` of ``Decision``)."""
    if not isinstance(d, dict):
        raise SnapshotError(f"{where} must be a table")
    for key in ("t_s", "exit_heading_rad", "turn_rad", "target_x_m", "target_y_m"):
        number(d.get(key), f"{where}.{key}")
    integer(d.get("exit_index"), f"{where}.exit_index", 0, 64)
    integer(d.get("intersection_id"), f"{where}.intersection_id", -1, MAX_COUNT)
    for key in ("target_kind", "mode", "reason"):
        if not isinstance(d.get(key), str) or len(str(d.get(key))) > 200:
            raise SnapshotError(f"{where}.{key} must be a short text")
    if d.get("target_id") is not None:
        integer(d.get("target_id"), f"{where}.target_id", -(2**63), 2**63 - 1)
    if not isinstance(d.get("revisit"), bool):
        raise SnapshotError(f"{where}.revisit must be true or false")
    options = _list(d.get("options"), f"{where}.options", 64)
    names = ("heading_rad", "turn_rad", "angle_cost_rad", "penalty_rad", "cost_rad")
    for i, o in enumerate(options):
        if not isinstance(o, dict) or set(o) != {"index", *names}:
            raise SnapshotError(f"{where}.options[{i}] must have index and {names}")
        integer(o["index"], f"{where}.options[{i}].index", 0, 64)
        for key in names:
            number(o[key], f"{where}.options[{i}].{key}")
    if not 0 <= int(d["exit_index"]) < len(options):
        raise SnapshotError(f"{where}.exit_index is not one of its options")
    expected = {"t_s", "exit_index", "exit_heading_rad", "turn_rad", "options", "target_x_m",
                "target_y_m", "target_kind", "target_id", "intersection_id", "revisit", "mode",
                "reason"}  # fmt: skip
    if set(d) != expected:
        raise SnapshotError(f"{where} has unknown or missing fields")


def check_guide(guide: object) -> None:
    """The intersections ahead (``guidance.core.plan.guide.Guide.snapshot``)."""
    if guide is None:
        return
    if not isinstance(guide, dict):
        raise SnapshotError(f"guide must be a table, not {type(guide).__name__}")
    ahead = _list(guide.get("ahead", []), "guide.ahead", 4)
    for i, a in enumerate(ahead):
        if not isinstance(a, dict):
            raise SnapshotError(f"guide.ahead[{i}] must be a table")
        if a.get("decision") is not None:
            check_decision(a["decision"], f"guide.ahead[{i}].decision")
        exits = _list(a.get("exits_rad"), f"guide.ahead[{i}].exits_rad", 64)
        if not exits:
            raise SnapshotError(f"guide.ahead[{i}].exits_rad is empty")
        for h in exits:
            number(h, f"guide.ahead[{i}].exits_rad")
        announced = _list(a.get("announced", []), f"guide.ahead[{i}].announced", 8)
        if not all(isinstance(x, str) for x in announced):
            raise SnapshotError(f"guide.ahead[{i}].announced must hold names")
    _matrix(guide.get("history", []), "guide.history", 0, 4, max_rows=MAX_TURN_SAMPLES)
    integer(guide.get("reports", 0), "guide.reports")


def check_snapshot(
    snap: object,
    *,
    n_state: int,
    start_xy: tuple[float, float],
    n_landmarks: int,
    mem_capacity: int,
    mem_width: int,
    state_problem: StateJudge,
    prior_variances: Sequence[float] | None = None,
) -> None:
    """Raise ``SnapshotError`` unless every value ``Pipeline.restore`` reads is usable;
    ``state_problem`` and ``prior_variances``: the estimator's (``check_state``)."""
    if not isinstance(snap, dict):
        raise SnapshotError(f"the snapshot must be a table, not {type(snap).__name__}")
    check_state(snap.get("x"), snap.get("P"), n_state, start_xy, state_problem, prior_variances)
    if snap.get("last_t_s") is not None:
        _number(snap, "last_t_s", -1e12, 1e12, 0.0)
    check_navigator(snap.get("navigator"), n_landmarks, mem_capacity, mem_width)
    check_turns(snap.get("turns"))
    integer(snap.get("decisions", 0), "decisions")
    # The pipeline's own fields: PipelineState.from_snapshot checks each by its type.
    counts = snap.get("counts", {})
    if not isinstance(counts, dict) or len(counts) > 1000:
        raise SnapshotError("counts must be a table of at most 1000 names")
    for k, v in counts.items():
        integer(v, f"counts.{str(k)[:40]!r}")
    check_guide(snap.get("guide"))
