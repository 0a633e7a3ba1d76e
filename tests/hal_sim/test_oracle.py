"""The truth oracle itself (hal_sim/oracle.py): it must catch what is wrong, or the guidance tests
that rely on it prove nothing."""

from __future__ import annotations

import math

import pytest

from hal_sim.oracle import (
    Report,
    SpokenPrompt,
    TruthSample,
    check,
    parse_prompt,
)


def _l_track(turn_deg: float = 90.0, block_m: float = 200.0, v: float = 10.0) -> list[TruthSample]:
    """East for ``block_m`` to the corner at (block_m, 0), then along ``turn_deg``, at v m/s."""
    out, t, h2 = [], 0.0, math.radians(turn_deg)
    for k in range(int(2 * block_m)):  # one sample per metre
        s = float(k)
        if s <= block_m:
            x, y, h = s, 0.0, 0.0
        else:
            x = block_m + (s - block_m) * math.cos(h2)
            y = (s - block_m) * math.sin(h2)
            h = h2
        out.append(TruthSample(t, x, y, h))
        t += 1.0 / v
    return out


def test_parse_prompt_reads_back_every_turn_sentence() -> None:
    p = parse_prompt("In 250 metres, turn left")
    assert p is not None and p.action == "turn left" and p.distance_m == 250.0
    p = parse_prompt("Change of plan: in 1.5 kilometres, bear right, then turn left")
    assert p is not None and p.changed and p.distance_m == 1500.0
    assert p.action == "bear right" and p.then == "turn left"
    p = parse_prompt("At the next intersection, make a U-turn")
    assert p is not None and p.action == "make a u-turn" and p.distance_m is None
    p = parse_prompt("Continue straight")
    assert p is not None and p.action == "continue straight"
    assert parse_prompt("In 500 feet, turn right") is not None
    assert parse_prompt("Passing the bakery: position confirmed") is None


def test_a_right_prompt_passes_and_a_wrong_manoeuvre_is_caught() -> None:
    truth = _l_track(90.0)
    reports = [Report(0.0, 200.0)]
    ok = check(truth, reports, [SpokenPrompt(5.0, "In 150 metres, turn left")])
    assert ok.ok() and ok.manoeuvres_checked == 1 and ok.distances_ok == 1 and ok.turns == 1
    bad = check(truth, reports, [SpokenPrompt(5.0, "In 150 metres, turn right")])
    assert len(bad.wrong) == 1 and not bad.ok()
    straight = check(_l_track(0.0), reports, [SpokenPrompt(5.0, "In 150 metres, turn left")])
    assert len(straight.wrong) == 1


def test_a_wrong_distance_a_late_prompt_a_silent_turn_and_a_repeat_are_caught() -> None:
    truth = _l_track(-90.0)
    reports = [Report(0.0, 200.0)]
    far = check(truth, reports, [SpokenPrompt(5.0, "In 300 metres, turn right")])
    assert far.distances_checked == 1 and far.distances_ok == 0 and not far.wrong
    late = check(truth, reports, [SpokenPrompt(19.0, "In 10 metres, turn right")])
    assert len(late.late) == 1 and late.margins_s == [pytest.approx(1.0, abs=0.15)]
    silent = check(truth, reports, [])
    assert len(silent.unannounced) == 1
    twice = check(
        truth,
        reports,
        [
            SpokenPrompt(5.0, "In 150 metres, turn right"),
            SpokenPrompt(8.0, "In 150 metres, turn right"),
        ],
    )
    assert len(twice.repeats) == 1


def test_the_then_part_is_checked_against_the_intersection_after_the_next() -> None:
    # Corner 1 at 200 m (straight on), corner 2 at 300 m (left): reported together.
    truth = []
    t = 0.0
    for k in range(500):
        s = float(k)
        x, y, h = (s, 0.0, 0.0) if s <= 300 else (300.0, s - 300.0, math.pi / 2)
        truth.append(TruthSample(t, x, y, h))
        t += 0.1
    reports = [Report(0.0, 200.0), Report(0.0, 300.0)]
    good = check(
        truth, reports, [SpokenPrompt(15.0, "In 50 metres, continue straight, then turn left")]
    )
    assert not good.wrong and good.manoeuvres_checked == 2
    assert len(good.unannounced) == 1  # a "then" is not the turn's own final announcement
    bad = check(
        truth, reports, [SpokenPrompt(15.0, "In 50 metres, continue straight, then turn right")]
    )
    assert len(bad.wrong) == 1 and "then" in bad.wrong[0].text


def test_the_exact_turn_from_the_simulator_wins_over_the_track() -> None:
    truth = _l_track(150.0)  # a U-turn that has not settled on the track: 150 deg there
    exact = [Report(0.0, 200.0, true_turn_rad=math.pi)]
    assert check(truth, exact, [SpokenPrompt(5.0, "In 150 metres, make a U-turn")]).ok()
    measured = check(
        truth, [Report(0.0, 200.0)], [SpokenPrompt(5.0, "In 150 metres, make a U-turn")]
    )
    assert len(measured.wrong) == 1  # the track alone says sharp right/left


def test_a_prompt_heard_in_a_corner_with_a_distance_past_it_is_about_the_next_one() -> None:
    """Corner 1 at 200 m (left onto north), corner 2 at 300 m (left onto west). "In 95 metres,
    turn left" spoken 4 m before corner 1, the car already in its arc, is about corner 2 (a
    driver turning there hears it so); without a distance, or with one that fits corner 1, it
    is about corner 1; and a wrong manoeuvre for corner 2 is still caught."""
    truth, t = [], 0.0
    for k in range(500):
        s = float(k)
        if s <= 200:
            x, y, h = s, 0.0, 0.0
        elif s <= 300:
            x, y, h = 200.0, s - 200.0, math.pi / 2
        else:
            x, y, h = 200.0 - (s - 300.0), 100.0, math.pi
        truth.append(TruthSample(t, x, y, h))
        t += 0.1
    reports = [Report(0.0, 200.0), Report(0.0, 300.0)]
    in_corner = 19.6  # 196 m along
    ok = check(truth, reports, [SpokenPrompt(in_corner, "In 95 metres, turn left")])
    assert not ok.wrong and ok.distances_ok == 1
    bad = check(truth, reports, [SpokenPrompt(in_corner, "In 95 metres, turn right")])
    assert len(bad.wrong) == 1
    near = check(truth, reports, [SpokenPrompt(in_corner, "In 5 metres, continue straight")])
    assert len(near.wrong) == 1  # that distance fits corner 1, where the car turns left
    before = check(truth, reports, [SpokenPrompt(15.0, "In 145 metres, turn left")])
    assert before.distances_ok == 0  # 50 m before corner 1, a distance is not re-read
