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

from guidance.config_tables import Rule, rule_of
from guidance.core.health import HealthConfig
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import CompassHeading, IntersectionScene, WheelOdometry
from guidance.core.pipeline import Pipeline
from guidance.core.pipeline_config import PipelineConfig
from guidance.core.plan.chance import ChanceSettings
from guidance.core.plan.navigator import Landmark, Method, NavigatorConfig
from guidance.core.plan.turns import TurnDetectorConfig
from guidance.core.speech import Units
from guidance.errors import UserError
from guidance.tools.replay import pipeline_config_from_session, replay


def _within(r: Rule, lo: float, hi: float) -> tuple[float, float]:
    """The drawn range: the rule's bounds where it has them (a positive rule: from ``lo``)."""
    low = max(lo, r.lo) if r.lo is not None else lo
    high = min(hi, r.hi) if r.hi is not None else hi
    return (max(low, 1e-3) if r.positive else low), high


def _optional_dataclass(hint: Any) -> type | None:
    """``X`` of a ``X | None`` hint whose ``X`` is a dataclass, else None."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if len(args) == 1 and len(typing.get_args(hint)) == 2 and dataclasses.is_dataclass(args[0]):
        return args[0] if isinstance(args[0], type) else None
    return None


def _values(cls: type) -> st.SearchStrategy[Any]:
    """Any valid instance of one of the pipeline's config dataclasses, drawn within each
    field's own rule (the one the record is read with)."""
    hints = typing.get_type_hints(cls)
    fields: dict[str, st.SearchStrategy[Any]] = {}
    for f in dataclasses.fields(cls):
        hint, r = hints[f.name], rule_of(cls, f.name)
        if hint is bool:
            fields[f.name] = st.booleans()
        elif hint is int:
            lo, hi = _within(r, -(2**40), 2**40)
            fields[f.name] = st.integers(int(lo), int(min(hi, 100_000)))
        elif hint is float:
            fields[f.name] = st.floats(*_within(r, 1e-3, 1e4), allow_nan=False)
        elif hint == float | None:
            fields[f.name] = st.none() | st.floats(*_within(r, 1e-3, 1e3))
        elif isinstance(hint, type) and issubclass(hint, Enum):
            fields[f.name] = st.sampled_from(list(hint))
        elif (inner := _optional_dataclass(hint)) is not None:  # e.g. a gyro car's GyroConfig
            fields[f.name] = st.none() | _values(inner)
        else:
            raise AssertionError(f"no strategy for {cls.__name__}.{f.name}: {hint}")
    return st.builds(cls, **fields)


XY = st.tuples(st.floats(-1e7, 1e7), st.floats(-1e7, 1e7))

CONFIGS = st.builds(
    PipelineConfig,
    estimator=_values(EstimatorConfig),
    navigator=_values(NavigatorConfig),
    start_xy_m=XY,
    goal_xy_m=st.none() | XY,  # None: no goal (a raw-log replay)
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
        (("health", "silence_periods"), 0.0, "[pipeline.health] silence_periods must be > 0, not"),
        (
            ("health", "max_reject_fraction"),
            3.0,
            "[pipeline.health] max_reject_fraction must be within [0.0, 1.0], not 3.0",
        ),
        (("turn_detector", "window_m"), float("inf"), "window_m must be finite, not inf"),
        (("health", "min_reads_for_validity"), 2.5, "min_reads_for_validity must be an integer"),
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


def _outside(r: Rule, hint: Any) -> list[Any]:
    """Values just outside each bound of the rule ``r`` (of the type ``hint``)."""
    step = 1 if hint is int else 1e-6
    out: list[Any] = []
    if r.lo is not None:
        out.append(hint(r.lo) - step if hint is int else r.lo - max(step, abs(r.lo) * 1e-6))
    if r.hi is not None:
        out.append(hint(r.hi) + step if hint is int else r.hi + max(step, abs(r.hi) * 1e-6))
    if r.positive:
        out.append(0 if hint is int else 0.0)
    return out


def _ruled_fields() -> list[tuple[tuple[str, ...], Any]]:
    """Every field of the record that a rule bounds: (path in the record, a value outside)."""
    cases: list[tuple[tuple[str, ...], Any]] = []
    nested = {"estimator": EstimatorConfig, "navigator": NavigatorConfig, "health": HealthConfig,
              "turn_detector": TurnDetectorConfig, "chance": ChanceSettings}  # fmt: skip
    tables: list[tuple[tuple[str, ...], type]] = [((), PipelineConfig)]
    tables += [((name,), cls) for name, cls in nested.items()]
    for path, cls in tables:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            hint = hints[f.name]
            scalar = {float | None: float, tuple[float, float]: float, tuple[float, ...]: float,
                      typing.Mapping[str, float | None]: float}.get(hint, hint)  # fmt: skip
            if scalar not in (int, float):
                continue
            for bad in _outside(rule_of(cls, f.name), scalar):
                value: Any = bad
                if hint in (tuple[float, float], tuple[float, ...]):
                    value = [bad, 0.0]
                elif scalar is not hint and hint != float | None:
                    value = {"odometry": bad}
                cases.append(((*path, f.name), value))
    return cases


RULED = _ruled_fields()


@pytest.mark.parametrize(("path", "value"), RULED, ids=[".".join(p) for p, _ in RULED])
def test_every_rule_refuses_a_value_just_outside_it_naming_the_setting(
    path: tuple[str, ...], value: Any
) -> None:
    """Each rule written on the core's config dataclasses holds in the session record: a value
    just past a bound is refused in one line naming the table, the key and the value."""
    d: dict[str, Any] = PipelineConfig(
        EstimatorConfig(), NavigatorConfig(), (0.0, 0.0), (1.0, 1.0)
    ).describe()
    table = d
    for key in path[:-1]:
        table = table[key]
    table[path[-1]] = value
    with pytest.raises(UserError) as exc:
        pipeline_config_from_session(json.loads(json.dumps({"pipeline": d})))
    where = ".".join(("pipeline", *path[:-1]))
    text = str(exc.value)
    assert f"[{where}] {path[-1]}" in text and " must be " in text, text
    assert "\n" not in text


def test_sizes_are_rules_too() -> None:
    """A list longer than its rule (the deviation card's 5, 100,000 landmarks) or than a
    record's default (64) is refused before its items are read."""
    base = PipelineConfig(EstimatorConfig(), NavigatorConfig(), (0.0, 0.0), (1.0, 1.0)).describe()
    for key, value, limit in [
        ("compass_deviation_deg", [0.0] * 6, 5),
        ("landmarks", [{"id": 1, "x_m": 0.0, "y_m": 0.0}] * 100_001, 100_000),
        ("expected_rates_hz", {str(i): 1.0 for i in range(65)}, 64),
    ]:
        d = {**base, key: value}
        with pytest.raises(UserError, match=rf"\[pipeline\] {key} must hold at most {limit} items"):
            pipeline_config_from_session({"pipeline": d})
