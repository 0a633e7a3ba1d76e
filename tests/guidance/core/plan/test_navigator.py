"""Navigator tests: the decision law, tabu penalties, revisits, targets, hybrid switching."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from guidance.core.plan.navigator import Landmark, Method, Navigator, NavigatorConfig

NORTH, EAST, WEST, SOUTH = math.pi / 2, 0.0, math.pi, -math.pi / 2


def _P(sigma_m: float, heading_sigma_rad: float = 0.02) -> np.ndarray:
    return np.diag([sigma_m**2, sigma_m**2, heading_sigma_rad**2])


def test_spec_three_way_example_straight_wins() -> None:
    """Driving north; goal ahead and to the right, more ahead than right: straight wins."""
    nav = Navigator(goal_xy=(150.0, 400.0))
    d = nav.decide(0.0, np.array([0.0, 0.0, NORTH]), _P(2.0), [NORTH, EAST])
    assert d.exit_index == 0
    assert d.turn_rad == pytest.approx(0.0)
    assert d.options[0].cost_rad < d.options[1].cost_rad
    assert d.target_kind == "goal" and "exit 0" in d.reason
    # and with the goal more to the right than ahead, the right turn wins
    d2 = Navigator(goal_xy=(400.0, 150.0)).decide(
        0.0, np.array([0.0, 0.0, NORTH]), _P(2.0), [NORTH, EAST]
    )
    assert d2.exit_index == 1 and d2.turn_rad == pytest.approx(-math.pi / 2)


def test_any_number_of_exits_at_any_angles() -> None:
    nav = Navigator(goal_xy=(-100.0, 100.0))
    exits = [math.radians(a) for a in (10, 70, 130, 200, 290)]
    d = nav.decide(0.0, np.array([0.0, 0.0, 0.0]), _P(1.0), exits)
    assert d.exit_index == 2  # 130 deg is closest to the 135 deg bearing
    assert len(d.options) == 5


@pytest.mark.parametrize("step_deg", [30.0, 60.0, 100.0])
def test_repeated_decision_loses_after_k_visits(step_deg: float) -> None:
    """Straight costs ~a, right ~b > a: straight is taken ceil((b - a) / step) times, then right."""
    cfg = NavigatorConfig(tabu_step_rad=math.radians(step_deg), lookahead_m=0.0)
    nav = Navigator(goal_xy=(300.0, 1000.0), config=cfg)
    x = np.array([0.0, 0.0, NORTH])
    first = nav.decide(0.0, x, _P(2.0), [NORTH, EAST])
    a, b = first.options[0].angle_cost_rad, first.options[1].angle_cost_rad
    k_expected = math.ceil((b - a) / cfg.tabu_step_rad)
    choices = [first.exit_index] + [
        nav.decide(float(t), x, _P(2.0), [NORTH, EAST]).exit_index for t in range(1, 6)
    ]
    assert choices[:k_expected] == [0] * k_expected
    assert choices[k_expected] == 1
    assert nav.remembered_intersections == 1


def _drive_graph(
    nav: Navigator,
    graph: dict[str, list[tuple[float, str]]],
    pos: dict[str, tuple[float, float]],
    start: str,
    heading: float,
    goal: str,
    max_decisions: int,
) -> list[str]:
    node, path = start, [start]
    for t in range(max_decisions):
        x, y = pos[node]
        state = np.array([x, y, heading])
        if nav.arrived(state) or node == goal:
            return path
        exits = graph[node]
        d = nav.decide(float(t), state, _P(3.0), [h for h, _ in exits])
        heading, node = exits[d.exit_index]
        path.append(node)
    return path


def test_car_circling_a_block_escapes() -> None:
    """A one-way ring the law alone would circle forever; the tabu penalty breaks out."""
    pos = {
        "A": (0.0, 0.0),
        "B": (100.0, 0.0),
        "C": (100.0, 100.0),
        "D": (0.0, 100.0),
        "E": (-100.0, 0.0),
        "F": (-100.0, 400.0),
        "G": (300.0, 400.0),
    }
    graph = {
        "A": [(EAST, "B"), (WEST, "E")],
        "B": [(NORTH, "C")],
        "C": [(WEST, "D")],
        "D": [(SOUTH, "A")],
        "E": [(NORTH, "F")],
        "F": [(EAST, "G")],
    }
    no_tabu = Navigator(goal_xy=pos["G"], config=NavigatorConfig(tabu_step_rad=0.0))
    assert _drive_graph(no_tabu, graph, pos, "A", EAST, "G", 40)[-1] != "G"
    nav = Navigator(goal_xy=pos["G"])
    path = _drive_graph(nav, graph, pos, "A", EAST, "G", 40)
    assert path[-1] == "G"
    assert path.count("A") <= 4


def test_revisit_recognised_inside_the_ellipse_not_a_fixed_radius() -> None:
    nav = Navigator(goal_xy=(0.0, 1000.0))
    nav.decide(0.0, np.array([0.0, 0.0, NORTH]), _P(2.0), [NORTH, EAST])
    # 60 m away with a tight ellipse: a new intersection
    d = nav.decide(1.0, np.array([60.0, 0.0, NORTH]), _P(2.0), [NORTH, EAST])
    assert not d.revisit
    # the same 60 m with a 40 m sigma: inside the ellipse, a revisit of the nearest one
    d = nav.decide(2.0, np.array([55.0, 0.0, NORTH]), _P(40.0), [NORTH, EAST])
    assert d.revisit and d.intersection_id == 1


def test_landmark_to_landmark_picks_one_nearer_the_goal_never_behind() -> None:
    lms = [
        Landmark(1, -40.0, 0.0),
        Landmark(2, 300.0, 50.0),
        Landmark(3, 600.0, 0.0),
        Landmark(4, 100.0, -900.0),
    ]
    nav = Navigator((1000.0, 0.0), NavigatorConfig(method=Method.LANDMARK_TO_LANDMARK), lms)
    tgt = nav.target(np.array([0.0, 0.0, 0.0]))
    kind, tid = tgt.kind, tgt.id
    assert (kind, tid) == ("landmark", 2)
    nav.on_landmark_fix(2, 30.0)
    assert nav.target(np.array([300.0, 50.0, 0.0])).id == 3
    # passed by proximity too
    assert nav.target(np.array([595.0, 0.0, 0.0])).kind == "goal"
    for lm_id in (1, 4):
        assert lm_id not in {
            nav.target(np.array([float(x), 0.0, 0.0])).id for x in range(0, 600, 50)
        }


def test_landmark_to_landmark_falls_back_to_goal() -> None:
    nav = Navigator(
        (1000.0, 0.0),
        NavigatorConfig(method=Method.LANDMARK_TO_LANDMARK),
        [Landmark(1, -500.0, 0.0)],
    )
    assert nav.target(np.array([0.0, 0.0, 0.0])).kind == "goal"


def test_hybrid_switches_at_50m_and_back_after_a_landmark_update() -> None:
    lms = [Landmark(1, 300.0, 0.0)]
    nav = Navigator((1000.0, 0.0), NavigatorConfig(method=Method.HYBRID), lms)
    x = np.array([0.0, 0.0, 0.0])
    nav.update_mode(40.0)
    assert nav.mode == "goal" and nav.target(x).kind == "goal"
    nav.update_mode(55.0)
    assert nav.mode == "landmark" and nav.target(x).kind == "landmark"
    nav.update_mode(45.0)  # shrinking without a landmark update does not switch back
    assert nav.mode == "landmark"
    nav.on_landmark_fix(1, 60.0)  # an update that leaves it above 50 m: still landmarks
    assert nav.mode == "landmark"
    nav.on_landmark_fix(1, 30.0)
    assert nav.mode == "goal"
    # and decide() itself switches on the estimate's major axis
    d = nav.decide(0.0, x, _P(20.0), [EAST, NORTH])  # major axis 4*20 = 80 m
    assert d.mode == "landmark"


def test_arrival_radius() -> None:
    nav = Navigator((100.0, 0.0), NavigatorConfig(arrival_radius_m=25.0))
    assert nav.arrived(np.array([80.0, 0.0, 0.0]))
    assert not nav.arrived(np.array([70.0, 0.0, 0.0]))


def test_memory_round_trip() -> None:
    nav = Navigator((0.0, 1000.0))
    for t in range(3):
        nav.decide(float(t), np.array([0.0, 0.0, NORTH]), _P(2.0), [NORTH, EAST])
    other = Navigator((5.0, 5.0))
    other.restore(nav.memory())
    x = np.array([0.0, 0.0, NORTH])
    assert (
        other.decide(9.0, x, _P(2.0), [NORTH, EAST]).options
        == nav.decide(9.0, x, _P(2.0), [NORTH, EAST]).options
    )


def test_no_exits_is_an_error() -> None:
    with pytest.raises(ValueError):
        Navigator((0.0, 0.0)).decide(0.0, np.zeros(3), _P(1.0), [])


def test_empty_memory_round_trip() -> None:
    # A checkpoint taken before the first intersection holds no memory at all.
    nav = Navigator((0.0, 1000.0))
    other = Navigator((5.0, 5.0))
    other.restore(json.loads(json.dumps(nav.memory())))
    assert other.memory() == nav.memory()
    x = np.array([0.0, 0.0, NORTH])
    assert (
        other.decide(1.0, x, _P(2.0), [NORTH, EAST]).options
        == nav.decide(1.0, x, _P(2.0), [NORTH, EAST]).options
    )


def test_showing_the_target_never_changes_what_the_navigator_decides() -> None:
    """target() is a view (the display asks it ten times a second when outputs are on): a
    landmark it treats as passed is marked passed only by the next decision, as in the study
    engine, so a car with telemetry decides exactly as one without."""
    lms = [Landmark(1, 300.0, 0.0), Landmark(2, 600.0, 0.0)]
    cfg = NavigatorConfig(method=Method.LANDMARK_TO_LANDMARK)
    shown, quiet = Navigator((1000.0, 0.0), cfg, lms), Navigator((1000.0, 0.0), cfg, lms)
    assert shown.target(np.array([298.0, 0.0, 0.0])).id == 2  # landmark 1 is being passed
    assert shown.memory() == quiet.memory()
    P = np.diag([25.0, 25.0, 0.01])
    for nav in (shown, quiet):
        nav.decide(1.0, np.array([298.0, 0.0, 0.0]), P, [0.0, math.pi / 2])
    assert shown.memory() == quiet.memory()
    assert shown.memory()["passed"] == [True, False]  # the decision marked it
