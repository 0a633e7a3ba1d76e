"""The decision law and its bookkeeping (guidance.core.law), called directly: the numba
functions the Navigator and the study engine share (SPEC section 3)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from guidance.core import law
from guidance.core.model import CHI2_2D_2SIGMA, mahalanobis_sq_2d

TOL = math.radians(20.0)
STEP = math.radians(45.0)


def _memory(n: int = 4, exits: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros((n, 2)), np.zeros((n, exits)), np.zeros((n, exits), dtype=np.int64)


def test_exit_costs_pick_the_exit_pointing_at_the_target() -> None:
    # SPEC's three-way example: target due east, exits east, north and west.
    headings = np.array([0.0, math.pi / 2, math.pi])
    out = np.empty(3)
    best = law.exit_costs(0.0, 0.0, headings, 1000.0, 0.0, np.zeros(3), 20.0, out)
    assert best == 0
    assert out[0] == pytest.approx(0.0)
    # the north exit, looked at from 20 m along it, points 1.1 degrees past 90 from the target
    assert out[1] == pytest.approx(math.pi / 2 + math.atan2(20.0, 1000.0))


def test_a_penalty_moves_the_choice_to_the_next_best_exit() -> None:
    headings = np.array([0.0, math.pi / 2])
    out = np.empty(2)
    penalties = np.array([math.pi, 0.0])
    assert law.exit_costs(0.0, 0.0, headings, 1000.0, 0.0, penalties, 20.0, out) == 1


def test_match_intersection_gates_on_the_ellipse_not_a_radius() -> None:
    mem_xy, _, _ = _memory()
    mem_xy[0] = (30.0, 0.0)
    # 30 m east: inside a wide east-west ellipse (sigma_x 20 m), outside a narrow one (5 m)
    assert law.match_intersection(0.0, 0.0, 400.0, 0.0, 25.0, mem_xy, 1, CHI2_2D_2SIGMA, 0.0) == 0
    assert law.match_intersection(0.0, 0.0, 25.0, 0.0, 400.0, mem_xy, 1, CHI2_2D_2SIGMA, 0.0) == -1
    # an entry beyond the count is not memory
    assert law.match_intersection(0.0, 0.0, 400.0, 0.0, 25.0, mem_xy, 0, CHI2_2D_2SIGMA, 0.0) == -1


def test_match_intersection_refuses_a_degenerate_covariance() -> None:
    mem_xy, _, _ = _memory()
    assert law.match_intersection(0.0, 0.0, 0.0, 0.0, 0.0, mem_xy, 1, 9.0, 0.0) == -1


def test_record_exit_counts_uses_of_the_same_exit_within_the_tolerance() -> None:
    _, mem_h, mem_c = _memory()
    law.record_exit(mem_h, mem_c, 0, 0.0, TOL)
    law.record_exit(mem_h, mem_c, 0, math.radians(10.0), TOL)  # the same exit, measured again
    law.record_exit(mem_h, mem_c, 0, math.pi / 2, TOL)
    assert mem_c[0, 0] == 2 and mem_c[0, 1] == 1
    pen = np.empty(3)
    law.exit_penalties(np.array([0.0, math.pi / 2, math.pi]), mem_h, mem_c, 0, STEP, TOL, pen)
    np.testing.assert_allclose(pen, [2 * STEP, STEP, 0.0])
    law.exit_penalties(np.array([0.0]), mem_h, mem_c, -1, STEP, TOL, pen[:1])
    assert pen[0] == 0.0  # a new intersection has no penalties


def test_evaluate_remembers_nothing_and_commit_counts_the_exit_really_taken() -> None:
    """The car's two halves of the law (issue 20): ``evaluate_exit`` for an intersection ahead
    leaves the memory as it was; ``commit_exit`` at the intersection remembers it (or finds
    the revisit) and counts the exit taken, which need not be the advised one."""
    mem_xy, mem_h, mem_c = _memory()
    params = np.array([CHI2_2D_2SIGMA, 64.0, math.radians(60.0), TOL, 20.0, 10.0])
    headings = np.array([0.0, math.pi / 2])
    pen, cost = np.empty(2), np.empty(2)
    passed = np.zeros(0, dtype=np.bool_)
    lm = np.zeros((0, 2))
    best, k, target = law.evaluate_exit(0.0, 0.0, 4.0, 0.0, 4.0, headings, mem_xy, mem_h, mem_c,
                                        0, passed, lm, 100.0, 0.0, law.MODE_GOAL, params, pen,
                                        cost)  # fmt: skip
    assert best == 0 and k == -1 and target == -1 and mem_c.sum() == 0
    k, revisit, n = law.commit_exit(0.0, 0.0, 4.0, 0.0, 4.0, math.pi / 2, mem_xy, mem_h, mem_c,
                                    0, params)  # fmt: skip
    assert (k, revisit, n) == (0, False, 1)
    assert mem_c[0].sum() == 1 and mem_h[0, int(np.argmax(mem_c[0]))] == pytest.approx(math.pi / 2)
    best, k, _ = law.evaluate_exit(
        1.0, 0.0, 4.0, 0.0, 4.0, headings, mem_xy, mem_h, mem_c, n, passed, lm, 100.0, 0.0,
        law.MODE_GOAL, params, pen, cost,
    )  # fmt: skip
    assert k == 0 and pen[1] == pytest.approx(math.radians(60.0)) and mem_c.sum() == 1
    k, revisit, n = law.commit_exit(2.0, 0.0, 4.0, 0.0, 4.0, 0.0, mem_xy, mem_h, mem_c, n, params)
    assert (k, revisit, n) == (0, True, 1) and mem_c[0].sum() == 2


def test_remember_forgets_the_oldest_half_when_memory_is_full() -> None:
    mem_xy, mem_h, mem_c = _memory(n=4)
    n = 0
    for i in range(4):
        k, n = law.remember_intersection(mem_xy, mem_h, mem_c, n, float(i), 0.0)
        assert k == i
    k, n = law.remember_intersection(mem_xy, mem_h, mem_c, n, 99.0, 0.0)
    assert (k, n) == (2, 3)
    np.testing.assert_allclose(mem_xy[:3, 0], [2.0, 3.0, 99.0])


def test_decide_exit_recognises_a_revisit_and_penalises_the_exit_taken_before() -> None:
    mem_xy, mem_h, mem_c = _memory()
    headings = np.array([0.0, math.pi / 2, -math.pi / 2])
    params = np.array([CHI2_2D_2SIGMA, 100.0, STEP, TOL, 30.0, 20.0])
    pen, cost = np.empty(3), np.empty(3)
    no_lm = np.zeros((0, 2))
    passed = np.zeros(0, dtype=np.bool_)
    args = (no_lm, 1000.0, 0.0, law.MODE_GOAL, params, pen, cost)
    best, k, revisit, n, target = law.decide_exit(
        0.0, 0.0, 25.0, 0.0, 25.0, headings, mem_xy, mem_h, mem_c, 0, passed, *args
    )
    assert (best, k, revisit, n, target) == (0, 0, False, 1, -1)
    # Back at the same place: a revisit. East costs one tabu step (45 deg) more per use; north
    # and south cost 91.1 deg (90 + the lookahead's 1.1), so east wins until it has been taken
    # three times (135 deg), and the fourth visit turns off.
    choices = []
    for visit in range(2, 5):
        best, k, revisit, n, _ = law.decide_exit(
            3.0, 0.0, 25.0, 0.0, 25.0, headings, mem_xy, mem_h, mem_c, n, passed, *args
        )
        assert (k, revisit, n) == (0, True, 1)
        assert pen[0] == pytest.approx((visit - 1) * STEP)
        choices.append(best)
    assert choices[:2] == [0, 0] and choices[2] != 0


def test_decide_exit_aims_at_the_nearest_landmark_nearer_the_goal_and_marks_passed_ones() -> None:
    mem_xy, mem_h, mem_c = _memory()
    headings = np.array([0.0, math.pi / 2])
    params = np.array([CHI2_2D_2SIGMA, 100.0, STEP, TOL, 30.0, 20.0])
    lm_xy = np.array([[10.0, 0.0], [0.0, 300.0]])  # the first is within the pass radius
    passed = np.zeros(2, dtype=np.bool_)
    best, _, _, _, target = law.decide_exit(
        0.0, 0.0, 25.0, 0.0, 25.0, headings, mem_xy, mem_h, mem_c, 0, passed,
        lm_xy, 0.0, 1000.0, law.MODE_LANDMARK, params, np.empty(2), np.empty(2),
    )  # fmt: skip
    assert passed.tolist() == [True, False]
    assert target == 1 and best == 1


def test_landmark_target_never_points_away_from_the_goal() -> None:
    lm_xy = np.array([[-50.0, 0.0], [400.0, 0.0]])
    passed = np.zeros(2, dtype=np.bool_)
    assert law.landmark_target(0.0, 0.0, 1000.0, 0.0, lm_xy, passed) == 1
    passed[1] = True
    assert law.landmark_target(0.0, 0.0, 1000.0, 0.0, lm_xy, passed) == -1


@pytest.mark.parametrize(
    ("method", "mode", "axis", "update", "want"),
    [
        (law.METHOD_STRAIGHT_TO_GOAL, law.MODE_LANDMARK, 500.0, False, law.MODE_GOAL),
        (law.METHOD_LANDMARK_TO_LANDMARK, law.MODE_GOAL, 0.0, False, law.MODE_LANDMARK),
        (law.METHOD_HYBRID, law.MODE_GOAL, 51.0, False, law.MODE_LANDMARK),
        (law.METHOD_HYBRID, law.MODE_LANDMARK, 40.0, False, law.MODE_LANDMARK),
        (law.METHOD_HYBRID, law.MODE_LANDMARK, 40.0, True, law.MODE_GOAL),
    ],
)
def test_next_mode_hybrid_switches_on_the_major_axis(
    method: int, mode: int, axis: float, update: bool, want: int
) -> None:
    assert law.next_mode(method, mode, axis, 50.0, update) == want


def _landmark_target_by_hypot(x, y, gx, gy, lm_xy, passed):  # type: ignore[no-untyped-def]
    """landmark_target as first written: two hypotenuses per landmark."""
    d_goal = math.hypot(gx - x, gy - y)
    best, best_d = -1, math.inf
    for k in range(lm_xy.shape[0]):
        if passed[k] or math.hypot(gx - lm_xy[k, 0], gy - lm_xy[k, 1]) >= d_goal:
            continue
        d = math.hypot(lm_xy[k, 0] - x, lm_xy[k, 1] - y)
        if d < best_d:
            best_d, best = d, k
    return best


def _match_by_distance(x, y, pxx, pxy, pyy, mem_xy, n_mem, gate, floor):  # type: ignore[no-untyped-def]
    """match_intersection as first written: every remembered intersection's distance."""
    a, b, c = pxx + floor, pxy, pyy + floor
    if a * c - b * b <= 0.0:
        return -1
    best, best_d2 = -1, gate
    for k in range(n_mem):
        d2 = mahalanobis_sq_2d(mem_xy[k, 0] - x, mem_xy[k, 1] - y, a, b, c)
        if d2 <= best_d2:
            best_d2, best = d2, k
    return best


def test_the_shortcut_scans_give_the_answers_of_the_full_ones() -> None:
    """landmark_target's squared distances and match_intersection's axis bounds change no
    answer (ties on a grid, NaN goals and landmarks included)."""
    rng = np.random.default_rng(26)
    for trial in range(400):
        n = int(rng.integers(0, 40))
        lm = rng.integers(-5, 6, (n, 2)).astype(float) * 50.0  # a grid: exact ties
        if n and trial % 7 == 0:
            lm[0] = np.nan
        passed = rng.random(n) < 0.2
        x, y = (float(v) for v in rng.integers(-5, 6, 2) * 50.0)
        gx, gy = (
            (math.nan, math.nan) if trial % 11 == 0 else (float(v) for v in rng.normal(0, 300, 2))
        )
        assert law.landmark_target(x, y, gx, gy, lm, passed) == _landmark_target_by_hypot(
            x, y, gx, gy, lm, passed
        )
        mem = rng.normal(0.0, 200.0, (max(n, 1), 2))
        pxx, pyy = (float(v) for v in rng.uniform(1.0, 5000.0, 2))
        pxy = float(rng.uniform(-0.9, 0.9)) * math.sqrt(pxx * pyy)
        args = (x, y, pxx, pxy, pyy, mem, mem.shape[0], 9.21, 64.0)
        assert law.match_intersection(*args) == _match_by_distance(*args)
