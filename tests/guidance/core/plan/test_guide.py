"""The intersections ahead (guidance/core/plan/guide.py), fed by hand: the co-driver who reports
early, a report during a turn, a changed instruction said as a change, "then", checkpoints, a
report taken back ("cancel")."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from guidance.core.co_driver import parse_line, to_scene
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import (
    Approach,
    CancelReport,
    ExitTaken,
    GoalUpdate,
    HeadingFix,
    IntersectionScene,
    Prompt,
    WheelOdometry,
)
from guidance.core.pipeline import Pipeline
from guidance.core.plan.road import Ahead, announce_target

NORTH, EAST, SOUTH, WEST = math.pi / 2, 0.0, -math.pi / 2, math.pi


class Drive:
    """A car on the pure pipeline: metres at a speed, turns over a distance, compass fixes."""

    def __init__(self, p: Pipeline, speed_mps: float = 8.0, dt: float = 0.05) -> None:
        self.p, self.v, self.dt = p, speed_mps, dt
        self.t = 0.0
        self.heading = float(p.localizer.estimator.x[2])
        self.prompts: list[Prompt] = []
        self.taken: list[ExitTaken] = []

    def feed(self, msg: object) -> None:
        out = self.p.feed(msg)  # type: ignore[arg-type]
        self.prompts += out.prompts
        self.taken += out.exits_taken

    def drive(self, metres: float, turn_rad: float = 0.0) -> None:
        """``metres`` of road, turning by ``turn_rad`` evenly over it."""
        steps = max(1, round(metres / (self.v * self.dt)))
        d, dth = metres / steps, turn_rad / steps
        track = self.p.config.estimator.track_m
        for k in range(steps):
            self.t += self.dt
            self.heading += dth
            self.feed(WheelOdometry(self.t, d - 0.5 * track * dth, d + 0.5 * track * dth))
            if k % 3 == 0:
                self.feed(HeadingFix(self.t, math.remainder(self.heading, 2 * math.pi)))

    def silence(self, seconds: float, turn_rad: float = 0.0) -> None:
        """A CAN gap: ``seconds`` of compass alone (6 Hz) while the car drives on, turning by
        ``turn_rad`` over the middle third; then the wheels again (the first increment is held
        until the second confirms the new time base)."""
        t0, n = self.t, round(seconds * 6.0)
        for k in range(1, n + 1):
            frac = min(1.0, max(0.0, 3.0 * k / n - 1.0))
            heading = self.heading + turn_rad * frac
            self.feed(HeadingFix(t0 + k / 6.0, math.remainder(heading, 2 * math.pi)))
        self.heading += turn_rad
        self.t = t0 + seconds
        step = self.v * self.dt
        for _ in range(2):
            self.t += self.dt
            self.feed(WheelOdometry(self.t, step, step))

    def type(self, line: str) -> None:
        typed = parse_line(line)
        assert typed is not None
        self.feed(to_scene(typed, self.t, float(self.p.localizer.estimator.x[2])))

    def said(self) -> list[str]:
        return [p.text for p in self.prompts if p.kind == "turn"]


def test_an_early_report_waits_for_the_turn_and_gives_no_false_different_exit(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """Issue 20: the co-driver types "l s r" right after the previous intersection; the car
    drives 4 s at 29 km/h to the next one and turns left as advised. Before: after 25 m the
    decision was taken as "went straight" (a false "Different exit taken", a tabu memory of an
    exit never taken) and the real turn found nothing pending."""
    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)), speed_mps=8.0)
    car.drive(20.0)
    car.type("l s r")
    assert car.said() == ["At the next intersection, turn left"]
    car.drive(32.0)  # 4 s at 29 km/h: nothing is resolved by distance alone
    assert car.taken == []
    car.drive(12.0, NORTH)  # the turn, as advised
    car.drive(20.0)
    assert len(car.taken) == 1 and car.taken[0].followed and car.taken[0].source == "detected"
    assert car.p.navigator.remembered_intersections == 1


def test_straight_on_is_known_once_the_next_intersection_is_reported(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    car = Drive(make_pipeline(goal_xy_m=(1000.0, 0.0)))
    car.type("l s r")
    assert car.said() == ["Continue straight"]
    car.drive(60.0)
    car.type("l r")  # the next one: the car is at or past the first
    assert car.taken == []
    car.drive(12.0)
    assert len(car.taken) == 1 and car.taken[0].followed and car.taken[0].source == "passed"


def test_a_report_typed_during_a_turn_is_taken_against_the_road_after_it(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """The co-driver types the next intersection as the car turns into the new street: its
    directions are relative to that street (north), not to the heading halfway through."""
    car = Drive(make_pipeline(goal_xy_m=(-900.0, 300.0)))
    car.type("l s r")  # a goal to the west-north-west: left at the first
    assert car.said() == ["At the next intersection, turn left"]
    car.drive(30.0)
    car.drive(6.0, NORTH / 2)  # halfway into the left turn...
    car.type("l s")  # ...the next one: left = west, straight = north (not north-west, north-east)
    car.drive(6.0, NORTH / 2)
    car.drive(20.0)
    assert len(car.taken) == 1 and car.taken[0].followed
    d = car.p.last_decision
    assert d is not None
    assert sorted(round(math.degrees(o.heading_rad)) for o in d.options) == [90, 180]
    assert car.said()[-1] == "At the next intersection, turn left"  # west, toward the goal


def test_a_changed_instruction_is_said_as_a_change_once_and_the_car_follows_it(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    car = Drive(make_pipeline(goal_xy_m=(400.0, 1000.0)), speed_mps=11.0)
    car.feed(IntersectionScene(car.t, (NORTH, SOUTH), 300.0))
    car.drive(20.0)
    assert car.said()[0].endswith("turn left")
    car.feed(GoalUpdate(car.t, 400.0, -1000.0))  # the destination moves south
    assert car.said()[-1] == "Change of plan: in 300 metres, turn right"
    decision = car.p.last_decision
    assert decision is not None and decision.exit_heading_rad == SOUTH
    assert car.p.planned_exit(car.p.reports) == 1
    car.drive(100.0)  # the estimate's wobble does not change it back
    assert sum(t.startswith("Change of plan") for t in car.said()) == 1


def test_no_change_after_the_just_before_prompt(make_pipeline: Callable[..., Pipeline]) -> None:
    car = Drive(make_pipeline(goal_xy_m=(400.0, 1000.0)), speed_mps=8.0)
    car.drive(10.0)
    car.feed(IntersectionScene(car.t, (NORTH, SOUTH), 60.0))
    assert car.said() == ["In 60 metres, turn left"]  # inside 8 s at 8 m/s: the last prompt
    car.drive(10.0)
    car.feed(GoalUpdate(car.t, 400.0, -1000.0))
    assert not any(t.startswith("Change") for t in car.said())
    assert car.p.planned_exit(car.p.reports) == 0


def test_then_for_two_manoeuvres_close_together(make_pipeline: Callable[..., Pipeline]) -> None:
    """The next two reported at once (the simulator when both are in view): the second is
    decided against the street the first turns into, and said with the first."""
    car = Drive(make_pipeline(goal_xy_m=(-1000.0, 300.0)), speed_mps=8.0)
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 120.0))  # left here...
    car.feed(IntersectionScene(car.t, (WEST, NORTH), 220.0))  # ...then left again onto west
    car.drive(70.0)
    last = car.said()[-1]
    assert last == "In 60 metres, turn left, then turn left"  # due at 8 s x 8 m/s
    assert car.p.planned_exit(2) == 0


def test_a_checkpoint_mid_approach_gives_the_same_future(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    runs = []
    for restart in (False, True):
        car = Drive(make_pipeline(goal_xy_m=(-400.0, 1000.0)), speed_mps=8.0)
        car.feed(IntersectionScene(car.t, (NORTH, EAST), 150.0))
        car.feed(IntersectionScene(car.t, (WEST, NORTH), 250.0))
        car.drive(40.0)
        if restart:
            snap = car.p.snapshot()
            fresh = make_pipeline(goal_xy_m=(-400.0, 1000.0))
            fresh.restore(snap)
            car.p = fresh
        car.feed(Approach(car.t, 110.0))
        car.drive(150.0, 0.0)
        runs.append((car.said()[-3:], [t.exit_index for t in car.taken]))
    assert runs[0] == runs[1]


def _info(car: Drive) -> list[str]:
    return [p.text for p in car.prompts if p.kind == "info"]


def test_cancel_withdraws_the_last_report_and_undoes_what_it_did(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """Issue 39: the co-driver reports the next intersection by mistake (the car is not through
    the first): "cancel" takes it back, and the first is no longer taken as behind the car (it
    would have been resolved "passed" after a few metres of straight road). Once withdrawn,
    there is nothing more to cancel."""
    car = Drive(make_pipeline(goal_xy_m=(1000.0, 0.0)))
    car.type("l s r")
    car.drive(20.0)
    car.type("l r")  # the mistake
    car.feed(CancelReport(car.t))
    assert _info(car) == ["The last report is cancelled."]
    assert car.p.planned_exit(1) is not None
    car.drive(30.0)
    assert car.taken == []  # the first is still ahead: not "passed" by the withdrawn report
    car.feed(CancelReport(car.t))
    assert _info(car)[-1] == "Nothing to cancel."
    car.type("l r")  # the real next one
    car.drive(12.0)
    assert len(car.taken) == 1 and car.taken[0].source == "passed"


def test_a_report_the_car_has_acted_on_cannot_be_cancelled(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)))
    car.feed(CancelReport(car.t))  # nothing reported yet
    car.type("l s r")
    car.drive(20.0)
    car.drive(12.0, NORTH)  # turned left, as advised: the report is resolved
    car.drive(20.0)
    assert len(car.taken) == 1
    out = car.p.feed(CancelReport(car.t))
    assert [p.text for p in out.prompts] == ["Nothing to cancel."]
    assert (out.accepted, out.reason) == (False, "nothing_to_cancel")
    assert _info(car) == ["Nothing to cancel."]
    far = IntersectionScene(car.t, (NORTH, WEST), distance_m=30.0)  # a scene with a distance
    car.feed(far)
    car.drive(35.0)  # reached: too late
    assert [p.text for p in car.p.feed(CancelReport(car.t)).prompts] == ["Nothing to cancel."]


def test_a_turn_made_in_a_can_gap_is_resolved_from_the_compass_and_credited_once(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """Issue 36, item 4: the wheels fall silent for 30 s with the intersection 150 m ahead and
    the car turns left there (the compass sees it). Where the intersection is along the road
    is not known after the gap (dead-reckoned at the last speed), but it was the only one the
    car could have reached: the turn was made there. It is not recorded as straight and not
    credited again to anything later."""
    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)), speed_mps=8.0)
    car.drive(20.0)
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 150.0))
    car.silence(30.0, NORTH)
    assert len(car.taken) == 1 and car.taken[0].source == "compass_gap" and car.taken[0].followed
    car.drive(200.0)
    assert len(car.taken) == 1


def test_intersections_a_can_gap_leaves_unplaced_are_dropped_unsaid(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """Issue 36, item 4: two intersections ahead when the wheels fall silent for 30 s, and a
    turn on the compass meanwhile: which one it was made at cannot be told, nor whether the
    other is still ahead. Both are dropped: nothing recorded, nothing more said about them
    (the 34 wrong words of the relocalisation benchmark were such stale places). One alone
    with no turn is dropped too: passed straight or still ahead cannot be told."""
    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)), speed_mps=8.0)
    car.drive(20.0)
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 150.0))
    car.feed(IntersectionScene(car.t, (NORTH, EAST, WEST), 250.0))
    said = list(car.said())
    car.silence(30.0, NORTH)
    car.drive(300.0)
    assert car.taken == [] and car.p.counts["ahead_unplaced_after_gap"] == 2
    assert car.said() == said

    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)), speed_mps=8.0)
    car.drive(20.0)
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 150.0))
    car.silence(30.0)
    car.drive(300.0)
    assert car.taken == [] and car.p.counts["ahead_unplaced_after_gap"] == 1


def test_a_short_can_gap_keeps_the_intersections_ahead(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """Two seconds of silence move the distance by at most 1/2 a t^2 = 6 m (2-sigma), inside
    the guide's "same place": the intersection ahead keeps its distance and is resolved as
    usual."""
    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)), speed_mps=8.0)
    car.drive(20.0)
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 150.0))
    car.silence(2.0)
    assert car.p.counts["odometry_gaps"] == 1
    assert car.p.counts["ahead_unplaced_after_gap"] == 0
    car.drive(130.0)
    car.drive(12.0, NORTH)
    car.drive(30.0)
    assert len(car.taken) == 1 and car.taken[0].source == "detected" and car.taken[0].followed


def test_a_first_instruction_too_close_to_act_on_is_held_unsaid(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """A decision first made 10 m before the intersection (e.g. right after the position is
    found) comes too late: the driver is already placed for the exit they chose. Nothing is
    said for it (announce.too_late: 2.5 s of reaction, at least 15 m), and no change later."""
    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)), speed_mps=8.0)
    car.drive(20.0)
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 10.0))
    car.drive(8.0)
    assert car.said() == [] and car.p.counts["too_late_not_said"] == 1
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 120.0))  # the next one is said as usual
    car.drive(70.0)
    assert car.said() and car.said()[-1].startswith("In ")


def test_the_next_intersection_seen_from_the_corner_is_on_the_road_the_car_takes(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """The next intersection comes into view when the car is already at the corner (within
    the guide's same place). If the driver then turns another way than advised, that report
    is still on the road really taken: it is kept (not dropped with the advised road's), and
    its manoeuvre is named against the road the car is on, not the advised exit."""
    car = Drive(make_pipeline(goal_xy_m=(0.0, 1000.0)), speed_mps=8.0)
    car.drive(20.0)
    car.feed(IntersectionScene(car.t, (NORTH, SOUTH), 100.0))  # advised: left (north)
    car.drive(94.0)
    car.feed(IntersectionScene(car.t, (WEST, SOUTH), 206.0))  # seen from the corner
    car.drive(12.0, SOUTH)  # the driver turns right instead
    car.drive(150.0)
    assert len(car.taken) == 1 and not car.taken[0].followed
    ahead = car.p.planner.guide.ahead
    assert ahead and ahead[0].on_taken_road
    said = car.said()[1:]
    assert said and all("left" not in s for s in said), said  # west is right from the south


def test_a_report_made_as_the_car_turns_is_named_against_the_road_it_settles_on(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """An intersection reported just as the car begins a turn the guide did not expect (a
    corner it could not place after a CAN gap, or one reported short): its road was taken
    from the car's heading, east. Nothing is named against that road while the car turns,
    and once it is steady on the road north the turn is named against that one: right, not
    straight on."""
    car = Drive(make_pipeline(goal_xy_m=(1000.0, 300.0)), speed_mps=8.0)
    car.drive(40.0)
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 110.0))  # north ahead, or right (east)
    car.drive(14.0, NORTH)  # the car turns left at a corner it did not know of
    assert car.said() == [] and car.p.counts["words_withheld_turning"] > 0
    car.drive(50.0)
    assert car.p.planned_exit(car.p.reports) == 1  # east, towards the goal
    assert car.said() == ["In 60 metres, turn right"], car.said()


def test_no_then_while_the_position_is_uncertain(make_pipeline: Callable[..., Pipeline]) -> None:
    """Two manoeuvres close together, but the position is uncertain past the warning (the next
    fix may replan beyond the next intersection): only the first is said; the second gets its
    own prompt when it is next."""
    uncertain = EstimatorConfig(compass_two_sigma_deg=20.0, initial_position_sigma_m=15.0)
    car = Drive(make_pipeline(goal_xy_m=(-1000.0, 300.0), estimator=uncertain), speed_mps=8.0)
    assert car.p.config.uncertain_warn_m < car.p.estimate.ellipse.major_axis_m
    assert not car.p.estimate.lost
    car.feed(IntersectionScene(car.t, (NORTH, EAST), 120.0))
    car.feed(IntersectionScene(car.t, (WEST, NORTH), 220.0))
    car.drive(70.0)
    assert car.said() and all(", then" not in s for s in car.said()), car.said()
    assert car.p.counts["then_withheld_uncertain"] > 0


def test_a_place_judged_from_afar_is_passed_only_past_its_uncertainty(
    make_pipeline: Callable[..., Pipeline],
) -> None:
    """An intersection reported 216 m ahead is truly 16 m further (a first sight is off by up
    to a tenth). The next one is not announced while the car may still be before it; and a
    distance given on the way re-places it (16 m off from 216 m is that intersection)."""
    first = Ahead(1, 0.0, (EAST, SOUTH), EAST, False, at_odometer_m=216.0, placed_from_m=216.0)
    second = Ahead(2, 0.0, (EAST, SOUTH), EAST, False, at_odometer_m=266.0, placed_from_m=266.0)
    assert announce_target([first, second], 222.0) == (-1, None)  # maybe still before it
    assert announce_target([first, second], 238.0) == (1, second)  # 21.6 m past: through it
    near = Ahead(1, 0.0, (EAST, SOUTH), EAST, False, at_odometer_m=216.0, placed_from_m=20.0)
    assert announce_target([near, second], 222.0) == (1, second)  # placed from close by

    car = Drive(make_pipeline(goal_xy_m=(400.0, -1000.0)), speed_mps=8.0)
    car.feed(IntersectionScene(car.t, (EAST, SOUTH), 216.0))  # truly at 232 m
    car.drive(180.0)
    car.feed(Approach(car.t, 52.0))  # the scene's distance to it: re-placed
    ahead = car.p.planner.guide.ahead
    assert ahead[0].at_odometer_m == pytest.approx(232.0, abs=0.5)
    assert ahead[0].placed_from_m == pytest.approx(52.0, abs=0.5)
