"""The processed-input codec: to_record and from_record are inverses, per message type."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from guidance.core import codec
from guidance.core.codec import CodecError, from_record, schema, to_record
from guidance.core.messages import (
    Approach,
    CancelReport,
    CompassHeading,
    GoalUpdate,
    HeadingFix,
    IntersectionScene,
    LandmarkFix,
    TurnCompleted,
    WheelOdometry,
    YawRate,
)

f = st.floats(allow_nan=False, allow_infinity=False, width=64)
text = st.text(max_size=12)

MESSAGES: dict[type, st.SearchStrategy[Any]] = {
    WheelOdometry: st.builds(WheelOdometry, f, f, f),
    CompassHeading: st.builds(CompassHeading, f, f, st.booleans()),
    HeadingFix: st.builds(HeadingFix, f, f),
    LandmarkFix: st.builds(LandmarkFix, f, st.integers(-(2**31), 2**31), f, f, f),
    IntersectionScene: st.builds(
        IntersectionScene,
        f,
        st.lists(f, max_size=6).map(tuple),
        st.none() | f,
        st.lists(text, max_size=6).map(tuple),
    ),
    TurnCompleted: st.builds(TurnCompleted, f, f, text),
    CancelReport: st.builds(CancelReport, f, text),
    Approach: st.builds(Approach, f, f),
    GoalUpdate: st.builds(GoalUpdate, f, f, f, text),
    YawRate: st.builds(YawRate, f, f),
}


def test_every_input_type_has_a_strategy_and_a_topic() -> None:
    assert set(MESSAGES) == set(codec.TOPICS)


@pytest.mark.parametrize("cls", list(MESSAGES), ids=lambda c: c.__name__)
def test_round_trip_through_json(cls: type) -> None:
    @given(MESSAGES[cls])
    def check(msg: Any) -> None:
        topic, body = to_record(msg)
        assert topic == codec.TOPICS[cls]
        back = from_record(topic, json.loads(json.dumps(body)))
        assert back == msg

    check()


@pytest.mark.parametrize("cls", list(MESSAGES), ids=lambda c: c.__name__)
def test_records_fit_their_generated_schema(cls: type) -> None:
    @given(MESSAGES[cls])
    def check(msg: Any) -> None:
        topic, body = to_record(msg)
        props = schema(topic)["properties"]
        assert set(body) <= set(props)
        assert set(schema(topic)["required"]) <= set(body)

    check()


@pytest.mark.parametrize(
    ("topic", "data", "why"),
    [
        ("/odometry", {"t_s": 1.0, "d_left_m": 0.1}, "missing"),
        ("/odometry", {"t_s": 1.0, "d_left_m": "x", "d_right_m": 0.1}, "number"),
        ("/odometry", {"t_s": math.nan, "d_left_m": 0.1, "d_right_m": 0.1}, "finite"),
        ("/compass", {"t_s": 1.0, "heading_deg": 3.0, "is_true": 1}, "true/false"),
        ("/landmark_fix", {"t_s": 1, "landmark_id": 1.5, "x_m": 0, "y_m": 0, "sigma_m": 1}, "int"),
        ("/scene", {"t_s": 1.0, "kind": "bridge"}, "unknown kind"),
        ("/scene", {"t_s": 1.0, "kind": "intersection", "exit_headings_rad": 3}, "list"),
        ("/goal", [1, 2], "object"),
    ],
)
def test_damaged_records_are_codec_errors(topic: str, data: Any, why: str) -> None:
    with pytest.raises(CodecError, match=why):
        from_record(topic, data)


def test_topics_that_are_not_inputs_decode_to_none() -> None:
    assert from_record("/state", {"t_s": 1.0}) is None
