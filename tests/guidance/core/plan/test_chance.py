"""The car's chance of reaching the goal: the shipped table read and checked, interpolation,
the one spoken warning, and the pipeline publishing it with each state."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest

from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import GoalUpdate, Say, Speech, WheelOdometry
from guidance.core.pipeline import Pipeline
from guidance.core.pipeline_config import PipelineConfig
from guidance.core.plan import chance
from guidance.core.plan.chance import ChanceSettings, ChanceTable, ChanceTableError, ChanceWatch
from guidance.core.plan.navigator import Method, NavigatorConfig
from guidance.core.speech import words


def test_shipped_table_reads_and_covers_every_method_and_compass() -> None:
    t = ChanceTable.shipped()
    assert None in t.compass_two_sigma_deg
    for m in chance.METHODS:
        for c in t.compass_two_sigma_deg:
            assert len(t.coef[(m, c)]) == len(t.densities_per_km2)


def test_a_damaged_table_is_refused_with_what_is_wrong() -> None:
    good = ChanceTable.shipped().as_json()
    assert ChanceTable.from_json(good) == ChanceTable.from_json(copy.deepcopy(good))
    cases = {
        "schema": ("schema", "x"),
        "densities_per_km2": ("densities_per_km2", [1.0, 0.5]),
        "detection_rates": ("detection_rates", [0.2, 1.5]),
        "lost_major_axis_m": ("lost_major_axis_m", -1),
    }
    for what, (key, value) in cases.items():
        bad = copy.deepcopy(good)
        bad[key] = value
        with pytest.raises(ChanceTableError, match=what.split("_")[0]):
            ChanceTable.from_json(bad)
    bad = copy.deepcopy(good)
    first = next(iter(bad["coef"]))
    bad["coef"][first][0][0] = [1.0, float("nan"), 0.0, 0.0]
    with pytest.raises(ChanceTableError, match="finite"):
        ChanceTable.from_json(bad)
    with pytest.raises(ChanceTableError):
        ChanceTable.from_json([1, 2])


def test_interpolation_is_exact_at_grid_points_and_clamped_outside() -> None:
    t = ChanceTable.shipped()
    h = Method.HYBRID.value
    w = t.coef[(h, 30.0)][2][1]  # density 1.0, detection 0.6
    assert t.densities_per_km2[2] == 1.0 and t.detection_rates[1] == 0.6
    assert t.weights(h, 1.0, 0.6, 30.0) == pytest.approx(w)
    mid = t.weights(h, 1.5, 0.6, 30.0)  # halfway between densities 1 and 2
    w2 = t.coef[(h, 30.0)][3][1]
    assert mid == pytest.approx([(a + b) / 2 for a, b in zip(w, w2, strict=True)])
    assert t.weights(h, 50.0, 0.6, 30.0) == pytest.approx(t.coef[(h, 30.0)][-1][1])
    assert t.weights(h, -1.0, 0.6, 30.0) == pytest.approx(t.coef[(h, 30.0)][0][1])
    assert t.weights(h, 1.0, 0.6, 5.0) == pytest.approx(t.coef[(h, 10.0)][2][1])
    assert t.chance(h, 1.0, 0.6, 30.0, 3000, 120.0) == 0.0  # past the lost threshold
    # an unknown method is judged as straight to goal, not an error
    assert t.chance("zigzag", 0.0, 0.6, 30.0, 3000, 10) == t.chance(
        "straight_to_goal", 0.0, 0.6, 30.0, 3000, 10
    )


def test_the_warning_is_said_once_and_rearms_above_the_margin() -> None:
    w = ChanceWatch(ChanceSettings(warn_below=0.5), ChanceTable.shipped(), "straight_to_goal")
    w.set_trip([], (0, 0), (9000, 0))  # no landmarks: density 0
    said = False
    texts = []
    for axis in (5.0, 60.0, 70.0, 75.0):  # the uncertainty grows: the chance falls
        text, said = w.update(5000, axis, 100.0, 30.0, said=said, quiet=False)
        texts.append(text)
    spoken = [t for t in texts if t]
    assert len(spoken) == 1 and spoken[0] is not None and spoken[0].speech is Speech.CHANCE
    assert "Chance of reaching the destination is now" in words(spoken[0])
    assert w.value is not None and w.value < 0.5
    # near the goal with a small ellipse (a landmark fix): high again, re-armed
    text, said = w.update(300, 5.0, 100.0, 30.0, said=said, quiet=False)
    assert text is None and not said
    # quiet (lost already said, arrived): never
    text, said = w.update(5000, 75.0, 100.0, 30.0, said=False, quiet=True)
    assert text is None and not said


def test_spoken_and_shown_forms() -> None:
    assert words(Say(Speech.CHANCE, chance=0.42)) == (
        "Chance of reaching the destination is now about 40 percent."
    )
    assert words(Say(Speech.CHANCE, chance=0.03)) == (
        "Chance of reaching the destination is now below 10 percent."
    )
    assert chance.shown(0.42) == "40 %" and chance.shown(0.999) == ">95 %"
    assert chance.shown(0.001) == "<5 %" and chance.shown(None) == "-"
    assert chance.shown(float("nan")) == "-"


def test_trip_density_counts_landmarks_in_the_trip_box() -> None:
    lms = [(0.0, 0.0), (500.0, 500.0), (9000.0, 9000.0)]
    # box 3 km x 2 km (1 km margin around (0,0)-(1000,0)) holds the first two
    assert chance.trip_density_per_km2(lms, (0.0, 0.0), (1000.0, 0.0)) == pytest.approx(2 / 6)


def _pipeline(goal: tuple[float, float], **kw: object) -> Pipeline:
    cfg = PipelineConfig(
        estimator=EstimatorConfig(),
        navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
        start_xy_m=(0.0, 0.0),
        goal_xy_m=goal,
        start_heading_rad=0.0,
        **kw,  # type: ignore[arg-type]
    )
    return Pipeline(cfg)


def _drive(p: Pipeline, metres: float) -> list[float | None]:
    values = []
    t = 0.0
    for _ in range(int(metres / 1.0)):
        t += 0.1
        out = p.feed(WheelOdometry(t, 1.0, 1.0))
        if out.state is not None:
            values.append(out.chance)
    return values


def test_pipeline_publishes_the_chance_with_each_state_and_it_falls_with_distance() -> None:
    near = _pipeline((800.0, 0.0))
    far = _pipeline((12000.0, 0.0))
    vn, vf = _drive(near, 100), _drive(far, 100)
    assert vn and all(v is not None and 0.0 <= v <= 1.0 for v in vn)
    assert vn[0] is not None and vf[0] is not None and vn[0] > vf[0]
    # the same as the table says for its inputs
    est = far.localizer.estimator
    to_go = math.hypot(12000.0 - est.x[0], -est.x[1])
    expect = ChanceTable.shipped().chance(
        "straight_to_goal", 0.0, 0.6, 30.0, to_go, est.major_axis_m
    )
    assert vf[-1] == pytest.approx(expect, abs=0.02)


def test_pipeline_says_a_low_chance_once_and_again_after_a_new_goal() -> None:
    p = _pipeline((15000.0, 0.0))
    t = 0.0
    said = []
    for _ in range(60):
        t += 0.1
        said += [x.text for x in p.feed(WheelOdometry(t, 1.0, 1.0)).prompts if x.kind == "chance"]
    assert len(said) == 1 and "percent" in said[0]
    assert p.planner.st.chance_said and not p.lost
    out = p.feed(GoalUpdate(t + 0.1, 14000.0, 0.0, source="operator"))
    said += [x.text for x in out.prompts if x.kind == "chance"]
    t += 0.1
    for _ in range(20):
        t += 0.1
        out = p.feed(WheelOdometry(t, 1.0, 1.0))
        said += [x.text for x in out.prompts if x.kind == "chance"]
    assert len(said) == 2


def test_disabled_chance_is_none_and_silent() -> None:
    p = _pipeline((15000.0, 0.0), chance=ChanceSettings(enabled=False))
    assert all(v is None for v in _drive(p, 50))


def test_a_damaged_shipped_table_costs_the_chance_not_the_car(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A broken install (the package's table truncated): the car guides, its chance is None
    (null in the state message), and the log says why once."""
    import json

    def broken() -> ChanceTable:
        return ChanceTable.from_json(json.loads('{"schema": "guidance.chance_table/1"'))

    monkeypatch.setattr(chance, "_shipped", broken)
    chance.shipped_or_none.cache_clear()
    try:
        with caplog.at_level("ERROR", logger="guidance.core.plan.chance"):
            p = _pipeline((3000.0, 0.0))
            values = _drive(p, 30)
            _pipeline((3000.0, 0.0))  # a second pipeline: no second log line
    finally:
        chance.shipped_or_none.cache_clear()
    assert values and all(v is None for v in values)
    assert p.estimate.odometer_m > 25.0
    assert sum("no chance of success" in r.message for r in caplog.records) == 1


@pytest.mark.parametrize(
    "damage", ["deep", "digits_400", "dev_zero", "fifo", "nan", "no_compass_slice_only"]
)
def test_a_hostile_shipped_table_is_one_error_line_and_a_null_chance(
    damage: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Defect 5: the package's table nested 200,000 deep (RecursionError), a 400-digit number
    (OverflowError), /dev/zero (MemoryError) crashed the car at start, a FIFO hung it; a table
    with only the no-compass slice was accepted. Now: one ERROR line, the chance None."""
    import json
    import os

    good = json.loads(chance.TABLE_PATH.read_text())
    path = tmp_path / "chance_table.json"
    if damage == "deep":
        path.write_text('{"schema": ' + "[" * 200_000 + "]" * 200_000 + "}")
    elif damage == "digits_400":
        text = json.dumps(good | {"lost_major_axis_m": 7})
        key = '"lost_major_axis_m": '
        path.write_text(text.replace(key + "7", key + "1" + "0" * 400))
    elif damage == "dev_zero":
        path.symlink_to("/dev/zero")
    elif damage == "fifo":
        os.mkfifo(path)
    elif damage == "nan":
        path.write_text(json.dumps(good | {"lost_major_axis_m": float("nan")}))
    else:
        only = [None]
        coef = {k: v for k, v in good["coef"].items() if k.endswith("/none")}
        path.write_text(json.dumps(good | {"compass_two_sigma_deg": only, "coef": coef}))
    monkeypatch.setattr(chance, "TABLE_PATH", path)
    chance._shipped.cache_clear()
    chance.shipped_or_none.cache_clear()
    try:
        with caplog.at_level("ERROR", logger="guidance.core.plan.chance"):
            assert chance.shipped_or_none() is None
    finally:
        chance._shipped.cache_clear()
        chance.shipped_or_none.cache_clear()
    lines = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert len(lines) == 1 and "no chance of success" in lines[0] and "\n" not in lines[0]
