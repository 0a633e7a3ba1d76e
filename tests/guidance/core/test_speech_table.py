"""The sentence table (guidance.core.speech): phrasing, rounding, units, one sentence per event."""

from __future__ import annotations

import math

import pytest

from guidance.core import speech as prompts
from guidance.core.messages import Say, Speech
from guidance.core.speech import COMPONENT_WORDS, SENSOR_WORDS, SPEECH, Units, words

M, IMP = Units.METRIC, Units.IMPERIAL


@pytest.mark.parametrize(
    ("metres", "units", "text"),
    [
        (3.0, M, "10 metres"),
        (10.0, M, "10 metres"),
        (44.0, M, "40 metres"),
        (96.0, M, "100 metres"),
        (180.0, M, "200 metres"),
        (230.0, M, "250 metres"),
        (960.0, M, "950 metres"),
        (980.0, M, "1 kilometre"),
        (1000.0, M, "1 kilometre"),
        (1460.0, M, "1.5 kilometres"),
        (12400.0, M, "12 kilometres"),
        (30.0, IMP, "100 feet"),
        (100.0, IMP, "350 feet"),
        (290.0, IMP, "950 feet"),
        (320.0, IMP, "0.2 miles"),
        (1609.344, IMP, "1 mile"),
        (2500.0, IMP, "1.6 miles"),
        (20000.0, IMP, "12 miles"),
    ],
)
def test_format_distance(metres: float, units: Units, text: str) -> None:
    assert prompts.format_distance(metres, units) == text


@pytest.mark.parametrize(
    ("turn_deg", "distance", "units", "text"),
    [
        (90.0, None, M, "At the next intersection, turn left"),
        (-90.0, None, M, "At the next intersection, turn right"),
        (0.0, None, M, "Continue straight"),
        (5.0, None, M, "Continue straight"),
        (-90.0, 200.0, M, "In 200 metres, turn right"),
        (90.0, 180.0, IMP, "In 600 feet, turn left"),
        (40.0, None, M, "At the next intersection, bear left"),
        (-150.0, None, M, "At the next intersection, turn sharp right"),
        (180.0, 50.0, M, "In 50 metres, make a U-turn"),
        (0.0, 400.0, M, "In 400 metres, continue straight"),
    ],
)
def test_turn_prompt(turn_deg: float, distance: float | None, units: Units, text: str) -> None:
    assert prompts.turn_prompt(math.radians(turn_deg), distance, units) == text


@pytest.mark.parametrize(
    ("gap_m", "text"),
    [
        (80.0, "In 200 metres, turn left, then turn right"),
        (400.0, "In 200 metres, turn left"),
    ],
)
def test_then_form_for_two_close_turns(gap_m: float, text: str) -> None:
    assert (
        prompts.turn_prompt(math.pi / 2, 200.0, M, then_turn_rad=-math.pi / 2, then_gap_m=gap_m)
        == text
    )


def test_event_phrases() -> None:
    hall = "Passing the town hall: position confirmed"
    assert words(Say(Speech.LANDMARK, name="the town hall")) == hall
    assert words(Say(Speech.LANDMARK)) == "Landmark passed: position confirmed"
    for internal in ("57", "landmark 57", "sim-00057", "lm_3"):  # never read out an id
        assert words(Say(Speech.LANDMARK, name=internal)) == "Landmark passed: position confirmed"
        assert words(Say(Speech.FOUND, name=internal)).endswith("at a known landmark")
    assert words(Say(Speech.LANDMARK, name="Gate 5")) == "Passing Gate 5: position confirmed"
    assert words(Say(Speech.UNCERTAIN, distance_m=83.0)) == "Position uncertain, within 80 metres"
    assert words(Say(Speech.UNCERTAIN, distance_m=83.0), IMP) == (
        "Position uncertain, within 250 feet"
    )
    assert words(Say(Speech.ARRIVED)) == "You have arrived at your destination"
    assert words(Say(Speech.LOST)).startswith("Position lost")
    assert words(Say(Speech.CHANCE, chance=0.42)) == (
        "Chance of reaching the destination is now about 40 percent."
    )
    assert words(Say(Speech.READ_BACK, line="l s r")) == "Left, straight, right."
    assert words(Say(Speech.READ_BACK, line="t hr")) == "Turned hard right."
    assert words(Say(Speech.READ_BACK, line="u")) == "U-turn."
    assert words(Say(Speech.READ_BACK, line="mute")) == "Mute."


def test_a_turn_is_worded_from_its_numbers_with_the_units_applied_once() -> None:
    left, right = math.pi / 2, -math.pi / 2
    turn = Say(Speech.TURN, left, 180.0, right, 80.0)
    assert words(turn, M) == "In 200 metres, turn left, then turn right"
    assert words(turn, IMP) == "In 600 feet, turn left, then turn right"
    changed = Say(Speech.TURN, right, 150.0, changed=True)
    assert words(changed) == "Change of plan: in 150 metres, turn right"
    assert words(Say(Speech.TURN, left, again=True)) == "At the next intersection, turn left again"
    fuzzy = Say(Speech.TURN, math.radians(90), 90.0, band_rad=math.radians(40))
    assert words(fuzzy) == "In 90 metres, go left"


def test_every_event_has_words_and_one_sentence_per_input_and_status() -> None:
    assert set(SPEECH) == set(Speech)
    for speech in Speech:
        for units in Units:
            assert words(Say(speech), units).strip()
    # an odometry dropout is one sentence whoever noticed it (driver flip or pipeline clock)
    silent = Say(Speech.SENSOR, input="odometry", status="silent")
    assert words(silent) == SENSOR_WORDS["odometry"]["silent"] == (
        "Wheel speed signal lost. Position is getting less certain."
    )
    sentences = [w for table in SENSOR_WORDS.values() for w in table.values()]
    assert len(sentences) == len(set(sentences))
    assert words(Say(Speech.SENSOR, input="gyro", status="silent")) == "Warning: gyro is silent"


def test_the_components_warnings_are_in_the_table_once() -> None:
    """Issue 37 item 2: the voice's, telemetry's and the recorder's warnings are events of the
    table like the inputs', one sentence per component and status, none shared with an input."""
    disk = Say(Speech.COMPONENT, input="recorder", status="disk_full")
    assert words(disk) == words(disk, IMP) == "The disk is full: recording has stopped."
    sentences = [w for table in COMPONENT_WORDS.values() for w in table.values()]
    inputs = [w for table in SENSOR_WORDS.values() for w in table.values()]
    assert len(sentences) == len(set(sentences)) and not set(sentences) & set(inputs)
    assert words(Say(Speech.COMPONENT, input="gps", status="down")) == "Warning: gps is down"


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf])
def test_bad_distance_is_an_error(bad: float) -> None:
    with pytest.raises(ValueError):
        prompts.format_distance(bad)


def test_a_manoeuvre_is_named_only_when_the_heading_band_keeps_its_name() -> None:
    """Issue 36: with the approach heading known to +-band, the name when every turn in the
    band has it; else the side; else the road's direction (which the scene gives exactly)."""
    from guidance.core.speech import bearing_word, manoeuvre_within

    east, north = 0.0, math.pi / 2
    assert manoeuvre_within(math.radians(90), 0.0, north) == "turn left"
    assert manoeuvre_within(math.radians(90), math.radians(20), north) == "turn left"
    assert manoeuvre_within(math.radians(90), math.radians(40), north) == "go left"
    assert manoeuvre_within(math.radians(-90), math.radians(60), east) == "go right"
    assert manoeuvre_within(0.0, math.radians(10), east) == "continue straight"
    assert manoeuvre_within(0.0, math.radians(30), east) == "take the road towards the east"
    assert manoeuvre_within(math.radians(90), math.radians(80), north) == (
        "take the road towards the north"
    )
    assert [bearing_word(math.radians(a)) for a in (0, 45, 90, 180, 270, -44)] == [
        "east", "north-east", "north", "west", "south", "south-east"]  # fmt: skip
    assert prompts.turn_prompt(0.5, 200.0, action="go left") == "In 200 metres, go left"
