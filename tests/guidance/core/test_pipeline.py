"""The pure pipeline (guidance.core.pipeline), fed messages by hand: which exit was taken,
announcement timing, arrival and a new goal, checkpoints that give the same future."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from guidance.core.messages import (
    Approach,
    GoalUpdate,
    HeadingFix,
    IntersectionScene,
    WheelOdometry,
)
from guidance.core.pipeline import Pipeline


def test_no_turn_after_the_intersection_means_straight_on(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    p = make_pipeline(goal_xy_m=(0.0, 1000.0), straight_after_m=20.0)
    out = p.feed(IntersectionScene(0.0, (math.pi / 2, 0.0), distance_m=30.0))
    assert out.decisions[0].exit_index == 0 and out.prompts[0].text == "In 30 metres, turn left"
    taken = []
    for k in range(60):
        taken += p.feed(WheelOdometry(0.1 * (k + 1), 1.0, 1.0)).exits_taken
    assert len(taken) == 1
    assert taken[0].exit_index == 1 and not taken[0].followed and taken[0].source == "no_turn"


def test_detected_turn_confirms_the_advice(make_pipeline: Callable[..., Pipeline]) -> None:
    p = make_pipeline(goal_xy_m=(0.0, 1000.0))
    p.feed(IntersectionScene(0.0, (math.pi / 2, 0.0), distance_m=10.0))
    taken = []
    t = 0.0
    track = p.config.estimator.track_m
    for k in range(60):  # 10 m straight, a 90-degree left over 10 m, then straight on
        dth = math.pi / 2 / 10 if 10 <= k < 20 else 0.0
        t += 0.1
        out = p.feed(WheelOdometry(t, 1.0 - 0.5 * track * dth, 1.0 + 0.5 * track * dth))
        taken += out.exits_taken
    assert len(taken) == 1 and taken[0].followed and taken[0].source == "detected"


def test_goal_update_and_arrival(make_pipeline: Callable[..., Pipeline]) -> None:
    p = make_pipeline(goal_xy_m=(50.0, 0.0), stop_at_arrival=False)
    arrived = []
    for k in range(40):
        out = p.feed(WheelOdometry(0.1 * (k + 1), 1.0, 1.0))
        arrived += [pr.text for pr in out.prompts if pr.kind == "arrived"]
    assert arrived == ["You have arrived at your destination"]
    out = p.feed(GoalUpdate(4.1, 500.0, 0.0))
    assert out.prompts[0].text == "New destination set" and not p.arrived
    out = p.feed(GoalUpdate(4.2, 600.0, 0.0, "remote"))  # from the network: said as such
    assert out.prompts[0].text == "New destination set remotely"


def test_snapshot_restore_gives_the_same_future(make_pipeline: Callable[..., Pipeline]) -> None:
    """A restored pipeline computes exactly what the original does from then on."""
    a = make_pipeline(goal_xy_m=(0.0, 1000.0))
    msgs: list[Any] = [WheelOdometry(0.1 * (k + 1), 1.0, 1.02) for k in range(30)]
    msgs.insert(10, IntersectionScene(1.05, (math.pi / 2, 0.0, -math.pi / 2), 20.0))
    for m in msgs:
        a.feed(m)
    b = make_pipeline(goal_xy_m=(0.0, 1000.0))
    b.restore(a.snapshot())
    more: list[Any] = [WheelOdometry(3.0 + 0.1 * k, 1.0, 1.0) for k in range(40)]
    more.insert(5, IntersectionScene(3.45, (math.pi / 2, 0.0), 15.0))
    for m in more:
        oa, ob = a.feed(m), b.feed(m)
        assert [d.exit_index for d in oa.decisions] == [d.exit_index for d in ob.decisions]
        assert [e.exit_index for e in oa.exits_taken] == [e.exit_index for e in ob.exits_taken]
    assert np.array_equal(a.localizer.estimator.x, b.localizer.estimator.x)
    assert np.array_equal(a.localizer.estimator.P, b.localizer.estimator.P)
    assert a.navigator.memory() == b.navigator.memory()


def test_known_distance_gives_an_early_and_a_just_before_announcement(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """Organic Maps timing: early (30 s ahead, 200 m at least) and again within 8 s."""
    p = make_pipeline(goal_xy_m=(0.0, 2000.0))
    t = 0.0
    for _ in range(20):  # cruise at 11 m/s
        t += 0.1
        p.feed(WheelOdometry(t, 1.1, 1.1))
    out = p.feed(IntersectionScene(t, (math.pi / 2, 0.0), distance_m=400.0))
    said = [pr.text for pr in out.prompts]
    assert said == ["In 400 metres, turn left"]
    distance = 400.0
    while distance > 20.0:
        t += 0.1
        distance -= 1.1
        said += [pr.text for pr in p.feed(WheelOdometry(t, 1.1, 1.1)).prompts]
        said += [pr.text for pr in p.feed(HeadingFix(t, 0.0)).prompts]  # compass: east
        said += [pr.text for pr in p.feed(Approach(t, distance)).prompts]
    assert said == ["In 400 metres, turn left", "In 90 metres, turn left"]  # 8 s x 11 m/s


def test_straight_on_is_announced_once(make_pipeline: Callable[..., Pipeline]) -> None:
    p = make_pipeline(goal_xy_m=(2000.0, 0.0))
    for k in range(20):
        p.feed(WheelOdometry(0.1 * (k + 1), 1.1, 1.1))
    said = [pr.text for pr in p.feed(IntersectionScene(2.0, (math.pi / 2, 0.0), 300.0)).prompts]
    for k in range(250):
        t = 2.1 + 0.1 * k
        said += [pr.text for pr in p.feed(WheelOdometry(t, 1.1, 1.1)).prompts]
        said += [pr.text for pr in p.feed(HeadingFix(t, 0.0)).prompts]
        said += [pr.text for pr in p.feed(Approach(t, 300.0 - 1.1 * k)).prompts]
    assert said == ["In 90 metres, continue straight"]  # once, at the final announcement (8 s)


def test_restore_after_a_reboot_does_not_carry_the_old_clock(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """The laptop's monotonic clock restarts with it: a checkpoint's times must not make every
    new input 'out of order'. Within one clock (the simulation) they are kept."""
    a = make_pipeline()
    for k in range(30):
        a.feed(WheelOdometry(1000.0 + 0.1 * k, 1.0, 1.0))
    snap = a.snapshot()
    rebooted = make_pipeline()
    rebooted.restore(snap, same_clock=False)
    assert rebooted.feed(WheelOdometry(5.0, 1.0, 1.0)).accepted
    assert rebooted.estimate.odometer_m == pytest.approx(31.0)
    same = make_pipeline()
    same.restore(snap)
    assert same.feed(WheelOdometry(5.0, 1.0, 1.0)).reason == "out_of_order"
    before = rebooted.estimate.ellipse.major_axis_m
    rebooted.localizer.widen(40.0)  # 4 s down at 10 m/s: 40 m more 2-sigma radius
    major = rebooted.estimate.ellipse.major_axis_m  # the full axis: twice the 2-sigma radius
    assert major == pytest.approx(2 * math.hypot(before / 2, 40.0), rel=0.05)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("arrived", "false", "arrived must be true or false"),
        ("prompt_count", -1, "prompt_count is outside"),
        ("odometer_m", 1e300, "odometer_m must be a finite number >= 0 and <= 1e\\+08"),
        ("speed_mps", float("nan"), "speed_mps must be a finite number"),
        ("warned", "compass", "warned must be a list"),
        ("warned", ["x" * 65], "warned must hold input names"),
        ("landmark_said", {"town hall": 1.0}, "is not a landmark id"),
        ("landmark_said", {"4": float("inf")}, "landmark_said\\[4\\] must be a finite number"),
    ],
)
def test_a_checkpoint_with_a_bad_state_field_is_refused_and_nothing_changes(
    make_pipeline: Callable[..., Pipeline], key: str, value: object, message: str
) -> None:
    """Every PipelineState field is checked by its type (no second list to forget one)."""
    from guidance.core.snapshot_check import SnapshotError

    a = make_pipeline()
    for k in range(10):
        a.feed(WheelOdometry(0.1 * (k + 1), 1.0, 1.0))
    snap = {**a.snapshot(), key: value}
    b = make_pipeline()
    before = (b.localizer.estimator.x.copy(), b.estimate.odometer_m)
    with pytest.raises(SnapshotError, match=message):
        b.restore(snap)
    assert np.array_equal(b.localizer.estimator.x, before[0]) and b.estimate.odometer_m == before[1]


def test_the_whole_state_is_in_the_checkpoint_and_what_a_restart_forgets_is_named(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """ARCHITECTURE-2 change 5: the warnings said, the landmark names said (with their message
    times) and the waiting notice are checkpointed; the transient part is a ``Transient``."""
    from dataclasses import asdict

    from guidance.core.pipeline_state import LocalizeState, PipelineState, PlanState, Transient

    a = make_pipeline()
    for k in range(10):
        a.feed(WheelOdometry(0.1 * (k + 1), 1.0, 1.0))
    a.st.warned.append("compass")
    a.planner.st.landmark_said["4"] = 0.5
    snap = a.snapshot()
    states = (a.st, a.localizer.st, a.planner.st)
    for st in states:
        assert {f: snap[f] for f in asdict(st)} == asdict(st)
    same = make_pipeline()
    same.restore(snap)
    assert (same.st, same.localizer.st, same.planner.st) == states
    assert same.st.warned == ["compass"]
    rebooted = make_pipeline()
    rebooted.restore(snap, same_clock=False)
    assert rebooted.planner.st.landmark_said == {} and rebooted.st.warned == ["compass"]
    tr = rebooted.localizer.tr
    assert isinstance(tr, Transient) and tr.held_odometry is None
    assert PipelineState.from_snapshot(snap) == a.st
    assert LocalizeState.from_snapshot(snap) == a.localizer.st
    assert PlanState.from_snapshot(snap) == a.planner.st
