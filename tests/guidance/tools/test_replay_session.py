"""The session record is the car (issue 25): ``PipelineConfig.describe()`` read back by
``pipeline_config_from_session`` is the same configuration, every table included, so a replay
is the car that was recorded."""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from enum import Enum
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from guidance.core.health import HealthConfig
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import CompassHeading, IntersectionScene, WheelOdometry
from guidance.core.pipeline import Pipeline
from guidance.core.pipeline_config import PipelineConfig
from guidance.core.plan.navigator import Landmark, Method, NavigatorConfig
from guidance.core.plan.turns import TurnDetectorConfig
from guidance.core.speech import Units
from guidance.errors import UserError
from guidance.tools.replay import pipeline_config_from_session, replay

INTS = {"max_intersections": (1, 100_000), "max_exits": (1, 64), "min_reads_for_validity": (1, 99)}
FRACTIONS = {"max_reject_fraction"}


def _values(cls: type) -> st.SearchStrategy[Any]:
    """Any valid instance of one of the pipeline's config dataclasses."""
    hints = typing.get_type_hints(cls)
    fields: dict[str, st.SearchStrategy[Any]] = {}
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if hint is bool:
            fields[f.name] = st.booleans()
        elif hint is int:
            lo, hi = INTS[f.name]
            fields[f.name] = st.integers(lo, hi)
        elif hint is float:
            hi = 1.0 if f.name in FRACTIONS else 1e4
            fields[f.name] = st.floats(1e-3, hi, allow_nan=False)
        elif hint == float | None:
            fields[f.name] = st.none() | st.floats(1e-3, 1e3)
        elif isinstance(hint, type) and issubclass(hint, Enum):
            fields[f.name] = st.sampled_from(list(hint))
        else:
            raise AssertionError(f"no strategy for {cls.__name__}.{f.name}: {hint}")
    return st.builds(cls, **fields)


XY = st.tuples(st.floats(-1e7, 1e7), st.floats(-1e7, 1e7))

CONFIGS = st.builds(
    PipelineConfig,
    estimator=_values(EstimatorConfig),
    navigator=_values(NavigatorConfig),
    start_xy_m=XY,
    goal_xy_m=XY,
    start_heading_rad=st.none() | st.floats(-math.pi, math.pi),
    landmarks=st.lists(
        st.builds(
            Landmark,
            st.integers(-(2**62), 2**62),
            st.floats(-1e7, 1e7),
            st.floats(-1e7, 1e7),
            st.text(max_size=20),
        ),
        max_size=4,
    ).map(tuple),
    declination_deg=st.floats(-180, 180),
    mounting_offset_deg=st.floats(-180, 180),
    compass_deviation_deg=st.lists(st.floats(-45, 45), max_size=5).map(tuple),
    compass_unusable_after_s=st.floats(0.1, 1e3),
    units=st.sampled_from(list(Units)),
    state_period_s=st.floats(1e-3, 60),
    expected_rates_hz=st.dictionaries(
        st.sampled_from(["odometry", "compass", "camera"]), st.none() | st.floats(0.1, 1e3)
    ),
    health=_values(HealthConfig),
    turn_detector=_values(TurnDetectorConfig),
    straight_after_m=st.floats(1e-3, 1e3),
    uncertain_warn_m=st.floats(1e-3, 1e3),
    stop_at_arrival=st.booleans(),
    resume_gap_inflation=st.booleans(),
)


@settings(max_examples=150, deadline=None)
@given(CONFIGS)
def test_the_session_record_round_trips_every_setting(cfg: PipelineConfig) -> None:
    """Through JSON, as the recorder writes it: the same configuration, field for field."""
    record = json.loads(json.dumps({"pipeline": cfg.describe()}))
    assert pipeline_config_from_session(record) == cfg


def test_every_field_of_the_configuration_is_in_the_record() -> None:
    """A field added later is recorded without anyone remembering to (describe is generic)."""
    d = PipelineConfig(EstimatorConfig(), NavigatorConfig(), (0.0, 0.0), (1.0, 1.0)).describe()
    assert set(d) == {f.name for f in dataclasses.fields(PipelineConfig)}
    assert {"health", "turn_detector", "resume_gap_inflation"} <= set(d)


def test_a_record_from_before_a_setting_existed_keeps_its_default() -> None:
    """Recordings made before ``[health]`` was recorded replay under the defaults they had."""
    d = PipelineConfig(EstimatorConfig(), NavigatorConfig(), (0.0, 0.0), (1.0, 1.0)).describe()
    for key in ("health", "turn_detector", "resume_gap_inflation"):
        del d[key]
    cfg = pipeline_config_from_session({"pipeline": d})
    assert cfg.health == HealthConfig() and cfg.turn_detector == TurnDetectorConfig()


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("health", "silence_periods"), 0.0, "[pipeline.health] silence_periods must be a finite"),
        (
            ("health", "max_reject_fraction"),
            3.0,
            "max_reject_fraction must be a finite number >= 0",
        ),
        (("turn_detector", "window_m"), float("inf"), "window_m must be a finite number"),
        (("health", "min_reads_for_validity"), 2.5, "must be an integer in [1, 1000000]"),
        (("turn_detector", "settle_m"), "far", "[pipeline.turn_detector] settle_m must be a"),
    ],
)
def test_hostile_values_in_the_new_tables_are_refused_naming_the_setting(
    path: tuple[str, str], value: Any, message: str
) -> None:
    d = PipelineConfig(EstimatorConfig(), NavigatorConfig(), (0.0, 0.0), (1.0, 1.0)).describe()
    table = d[path[0]]
    assert isinstance(table, dict)
    table[path[1]] = value
    with pytest.raises(UserError, match="the recording's /session record") as exc:
        pipeline_config_from_session({"pipeline": d})
    assert message in str(exc.value)


def _drive() -> list[Any]:
    """50 Hz odometry along a street with a 0.6 s CAN dropout, a 5 Hz compass, a left turn
    and intersections reported ahead."""
    out: list[Any] = []
    t, heading = 0.0, 90.0
    for i in range(1500):
        t = 0.02 * i
        if 10.0 < t < 10.6:
            continue  # the dropout: longer than the recorded [health] timeout, not the default
        turning = 14.0 < t < 17.0
        d = 0.2 if not turning else 0.1
        dl, dr = (d - 0.0025, d + 0.0025) if turning else (d, d)
        heading = heading - 30.0 * 0.02 if turning else heading
        out.append(WheelOdometry(t, dl, dr))
        if i % 10 == 0:
            out.append(CompassHeading(t + 0.001, heading % 360.0))
        if i % 250 == 100:
            out.append(IntersectionScene(t + 0.002, (0.0, math.pi / 2, -math.pi / 2), 40.0))
    return out


def test_a_drive_with_non_default_tables_replays_to_the_same_decisions_and_states() -> None:
    """[navigation], [estimator] and [health] not at their defaults: the replay rebuilt from
    the record gives what the car gave, decision for decision and state for state. Before the
    record carried ``health``, the replay used the default timeouts and treated the dropout
    differently."""
    cfg = PipelineConfig(
        estimator=car_model(EstimatorConfig(track_m=1.6), calibrated=False),
        navigator=NavigatorConfig(method=Method.LANDMARK_TO_LANDMARK, lookahead_m=15.0),
        start_xy_m=(0.0, 0.0),
        goal_xy_m=(800.0, 600.0),
        start_heading_rad=0.0,
        landmarks=(Landmark(7, 400.0, 300.0, "tower"),),
        expected_rates_hz={"odometry": 50.0, "compass": 5.0},
        health=HealthConfig(silence_periods=3.0, min_timeout_s=0.3),
        turn_detector=TurnDetectorConfig(window_m=30.0),
        straight_after_m=20.0,
        stop_at_arrival=False,
    )
    inputs = _drive()
    car = replay(Pipeline(cfg), inputs)
    record = json.loads(json.dumps({"pipeline": cfg.describe()}))
    again = replay(Pipeline(pipeline_config_from_session(record)), inputs)
    assert car.decisions and car.states
    assert again.decisions == car.decisions and again.states == car.states
    assert again.final == car.final
    default_health = replay(Pipeline(dataclasses.replace(cfg, health=HealthConfig())), inputs)
    assert default_health.states != car.states  # the test can see a dropped [health]
