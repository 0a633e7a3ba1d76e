"""The planner without a goal (guidance/core/plan/planner.py): it still publishes the state
and says the uncertainty, and decides nothing, gives no chance and never arrives until a goal
comes (``GoalUpdate``); a checkpoint without a goal resumes as one."""

from __future__ import annotations

import json
import math
from collections.abc import Callable

import pytest

from guidance.core.messages import (
    GoalUpdate,
    HeadingFix,
    IntersectionScene,
    Method,
    Speech,
    WheelOdometry,
)
from guidance.core.pipeline import Outputs, Pipeline
from guidance.core.plan.navigator import Navigator, NavigatorConfig
from guidance.core.snapshot_check import SnapshotError

EXITS = (0.0, math.pi / 2, -math.pi / 2)
"""East (straight on), north, south: the car drives east."""
ROUTE_SPEECH = {Speech.TURN, Speech.ARRIVED, Speech.CHANCE, Speech.DIFFERENT_EXIT}
"""What the driver hears only of a trip to a goal (and the new goal itself)."""


def _spoken(outs: list[Outputs]) -> list[Speech]:
    return [pr.say.speech for o in outs for pr in o.prompts if pr.say is not None]


def _drive(p: Pipeline, t0: float, metres: float, *, report_every_m: float = 0.0) -> list[Outputs]:
    """``metres`` east at 10 m/s from message time ``t0`` (20 Hz odometry, a compass fix every
    third step), an intersection reported 60 m ahead every ``report_every_m`` (0: none)."""
    outs, t, driven, next_report = [], t0, 0.0, report_every_m
    step = 0.5
    for k in range(round(metres / step)):
        t += 0.05
        driven += step
        outs.append(p.feed(WheelOdometry(t, step, step)))
        if k % 3 == 0:
            outs.append(p.feed(HeadingFix(t, 0.0)))
        if report_every_m and driven >= next_report:
            next_report += report_every_m
            outs.append(p.feed(IntersectionScene(t, EXITS, distance_m=60.0)))
    return outs


@pytest.mark.parametrize("method", list(Method))
def test_with_no_goal_nothing_is_decided_until_a_goal_comes(
    make_pipeline: Callable[..., Pipeline], method: Method
) -> None:
    p = make_pipeline(goal_xy_m=None, navigator=NavigatorConfig(method=method))
    outs = _drive(p, 0.0, 400.0, report_every_m=100.0)
    reports = [o for o in outs if o.reason == "no_goal"]
    assert len(reports) == 4 and not any(o.accepted for o in reports)
    assert p.counts["reports_without_goal"] == 4
    states = [o for o in outs if o.state is not None]
    assert len(states) > 300 and all(o.chance is None for o in states)  # published, no chance
    assert not any(o.decisions or o.exits_taken or o.arrived for o in outs)
    assert not ROUTE_SPEECH & set(_spoken(outs))
    assert p.target() is None and not p.arrived
    # a goal arrives: said, and from then on the car is guided to it
    out = p.feed(GoalUpdate(40.0, 1000.0, 0.0, "remote"))
    assert out.accepted and _spoken([out]) == [Speech.NEW_DESTINATION]
    later = _drive(p, 40.0, 700.0, report_every_m=100.0)
    assert sum(len(o.decisions) for o in later) >= 3
    assert any(o.chance is not None for o in later if o.state is not None)
    assert any(o.arrived for o in later) and p.target() is not None


def test_a_checkpoint_without_a_goal_resumes_as_one(make_pipeline: Callable[..., Pipeline]) -> None:
    p = make_pipeline(goal_xy_m=None)
    _drive(p, 0.0, 150.0, report_every_m=100.0)
    snap = json.loads(json.dumps(p.snapshot()))
    assert snap["navigator"]["goal"] is None
    q = make_pipeline(goal_xy_m=None)
    q.restore(snap)
    a, b = _drive(p, 15.0, 200.0, report_every_m=50.0), _drive(q, 15.0, 200.0, report_every_m=50.0)
    assert [(o.accepted, o.reason, o.prompts) for o in a] == [
        (o.accepted, o.reason, o.prompts) for o in b
    ]
    assert p.estimate == q.estimate and p.navigator.memory() == q.navigator.memory()
    del snap["navigator"]["goal"]
    with pytest.raises(SnapshotError, match=r"navigator\.goal"):
        make_pipeline(goal_xy_m=None).restore(snap)


def test_a_navigator_without_a_goal_never_arrives_and_aims_nowhere() -> None:
    nav = Navigator(None)
    assert not any(nav.arrived((x, y)) for x in (-1e6, 0.0, 5.0) for y in (-1e6, 0.0, 5.0))
    with pytest.raises(ValueError, match="no goal"):
        nav.target((0.0, 0.0))
    memory = json.loads(json.dumps(nav.memory()))
    other = Navigator((100.0, 0.0))
    other.restore(memory)
    assert other.goal is None
    nav.set_goal((3.0, 4.0))
    assert nav.arrived((3.0, 4.0)) and nav.target((0.0, 0.0)).kind == "goal"
