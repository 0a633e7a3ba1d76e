"""The estimator on real drives with ground truth (issue 12, docs/estimation.md).

Run as a user would: ``guidance replay LOG [--nmea NMEA] --config CAR.toml --track T.csv`` then
``guidance evaluate --track T.csv --truth TRUTH.csv --json``. The comma2k19 segment is shipped
(trimmed, MIT) in tests/data/realdrives; the smartLoc drive (CC BY-SA) is used from
../shared/data when present.
"""

from __future__ import annotations

import heapq
import io
import json
import math
from contextlib import redirect_stdout
from dataclasses import replace
from pathlib import Path

import pytest

from guidance.core.messages import CompassHeading, Speech, WheelOdometry
from guidance.core.pipeline import Pipeline
from guidance.tools.cli import main
from guidance.tools.replay import can_inputs, nmea_inputs, raw_setup

REPO = Path(__file__).resolve().parents[3]
DATA = REPO / "tests" / "data" / "realdrives"
SHARED = REPO.parent / "shared" / "data" / "realdrives"
COMMA_LOG = DATA / "comma2k19_ex1_wheelspeeds.log"
COMMA_NMEA = DATA / "comma2k19_ex1_hdg_inferred.nmea"
COMMA_TRUTH = DATA / "comma2k19_ex1_truth.csv"
COMMA_CAR = REPO / "config" / "realdrives" / "comma2k19_ex1.toml"


def _cli(*args: str) -> str:
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main(list(args)) == 0
    return buf.getvalue()


def _replay_and_evaluate(tmp_path: Path, log: Path, car: Path, truth: Path, *extra: str) -> dict:
    track = tmp_path / "track.csv"
    _cli("replay", str(log), "--config", str(car), "--track", str(track), *extra)
    header = track.read_text().splitlines()[0]
    assert header.startswith("t_s,east_m,north_m,heading_deg,var_east_m2,cov_east_north_m2")
    out = _cli("evaluate", "--track", str(track), "--truth", str(truth), "--json")
    return dict(json.loads(out.splitlines()[-1]))


def test_comma2k19_odometry_only_is_honest(tmp_path: Path) -> None:
    ev = _replay_and_evaluate(tmp_path, COMMA_LOG, COMMA_CAR, COMMA_TRUTH)
    assert ev["steps"] > 4000
    assert ev["inside_2sigma_frac"] >= 0.80  # the paper's model: 74 %
    assert ev["median_axis_ratio"] <= 3.0  # the paper's model: 4.4


def test_comma2k19_with_its_real_uncalibrated_compass(tmp_path: Path) -> None:
    """The compass reads about 40 degrees off; the bias state learns it from the start heading."""
    ev = _replay_and_evaluate(
        tmp_path, COMMA_LOG, COMMA_CAR, COMMA_TRUTH, "--nmea", str(COMMA_NMEA)
    )
    assert ev["final_error_m"] <= 40.0  # odometry only: 124 m
    assert ev["inside_2sigma_frac"] >= 0.70


def _pipeline(model: str) -> tuple[Pipeline, list[WheelOdometry | CompassHeading]]:
    setup = raw_setup(str(COMMA_CAR), None, None, COMMA_LOG)
    pcfg = setup.pipeline
    if model == "paper":  # the paper's white-noise filter, as `[estimator] model = "paper"`
        from guidance.core.localize.estimator import EstimatorConfig

        est = EstimatorConfig(track_m=1.62, compass_two_sigma_deg=5.0)
        pcfg = replace(pcfg, estimator=est)
    odo = list(can_inputs(COMMA_LOG, setup.profile))
    msgs = list(heapq.merge(odo, nmea_inputs(COMMA_NMEA, 0.0, 10.0), key=lambda m: m.t_s))
    return Pipeline(pcfg), msgs


def test_a_compass_the_filter_keeps_rejecting_is_reported_unusable_within_30_s(
    caplog: pytest.LogCaptureFixture,
) -> None:
    pipeline, msgs = _pipeline("paper")
    t0 = msgs[0].t_s
    said: list[tuple[float, str]] = []
    flagged_at = None
    for m in msgs:
        out = pipeline.feed(m)
        said += [(p.t_s - t0, p.text) for p in out.prompts]
        for ch in out.health:
            if ch.status.name == "compass" and not ch.status.valid and flagged_at is None:
                flagged_at = ch.t_s - t0
                assert "unusable" in ch.status.detail
    assert flagged_at is not None and flagged_at <= 30.0
    unusable = [t for t, text in said if text.startswith("Compass unusable")]
    assert len(unusable) == 1 and unusable[0] <= 30.0  # spoken once
    assert pipeline.statuses(msgs[-1].t_s)["compass"].valid is False
    # the log says what the operator can act on, not that a device "sends garbage"
    logged = [r.getMessage() for r in caplog.records if r.getMessage().startswith("compass")]
    assert any(m.startswith("compass is unusable (uncalibrated)") for m in logged), logged
    assert not any("garbage" in m for m in logged), logged


def test_the_car_model_keeps_the_same_compass_usable() -> None:
    pipeline, msgs = _pipeline("car")
    for m in msgs:
        pipeline.feed(m)
    st = pipeline.statuses(msgs[-1].t_s)["compass"]
    assert st.valid, st.detail
    accepted = pipeline.localizer.estimator.accepted["HeadingFix"]
    assert accepted > 0.9 * sum(isinstance(m, CompassHeading) for m in msgs)


ROUTE_SPEECH = {Speech.TURN, Speech.ARRIVED, Speech.CHANCE, Speech.DIFFERENT_EXIT}
"""What the driver hears only of a trip to a goal."""


@pytest.mark.parametrize("model", ["paper", "car"])
def test_a_replay_without_a_goal_reports_all_but_the_route(model: str) -> None:
    """A car TOML with no ``[goal]``: the raw replay's pipeline has no goal (before: one
    10,000 km away, whose chance the states carried: 99.95 %, then 0 %). It publishes the same
    states, health changes and warnings as with the drive's real destination (the truth's
    last point) for a goal, and nothing of a route: no decision, chance, arrival or target."""
    runs = {}
    for goal in (None, _truth_end()):
        pipeline, msgs = _pipeline(model)
        assert pipeline.config.goal_xy_m is None  # the TOML has none
        if goal is not None:
            pipeline = Pipeline(replace(pipeline.config, goal_xy_m=goal))
        states, said, health, chances, route = [], [], [], [], 0
        for m in msgs:
            out = pipeline.feed(m)
            if out.state is not None:
                states.append(out.state)
                chances.append(out.chance)
            said += [(p.t_s, p.text) for p in out.prompts
                     if p.say is None or p.say.speech not in ROUTE_SPEECH]  # fmt: skip
            health += [(h.t_s, h.status) for h in out.health]
            route += len(out.decisions) + len(out.exits_taken) + out.arrived
        runs[goal] = (states, said, health, chances, route, pipeline.target())
    (states, said, health, chances, route, target), with_goal = runs[None], runs[_truth_end()]
    assert len(states) > 500 and (states, said, health) == with_goal[:3]
    assert {"Position uncertain, within 50 metres"} <= {t for _, t in said}  # said all the same
    assert all(c is None for c in chances) and route == 0 and target is None
    assert all(c is not None for c in with_goal[3]) and with_goal[5] is not None


def _truth_end() -> tuple[float, float]:
    last = COMMA_TRUTH.read_text().strip().splitlines()[-1].split(",")
    return float(last[1]), float(last[2])


def test_noise_grows_with_distance_not_with_the_message_rate() -> None:
    """Merging the 83 Hz increments four at a time (about 20 Hz) leaves the ellipse alone."""
    setup = raw_setup(str(COMMA_CAR), None, None, COMMA_LOG)
    odo = list(can_inputs(COMMA_LOG, setup.profile))
    merged = [
        WheelOdometry(
            chunk[-1].t_s,
            sum(m.d_left_m for m in chunk),
            sum(m.d_right_m for m in chunk),
        )
        for chunk in (odo[i : i + 4] for i in range(0, len(odo), 4))
    ]
    axes = []
    for msgs in (odo, merged):
        p = Pipeline(setup.pipeline)
        for m in msgs:
            p.feed(m)
        axes.append(p.localizer.estimator.major_axis_m)
    assert math.isclose(axes[0], axes[1], rel_tol=0.03), axes


@pytest.mark.shared_data
def test_smartloc_berlin_odometry_only_is_honest(tmp_path: Path) -> None:
    log = SHARED / "smartloc_berlin_potsdamer_platz.log"
    if not log.is_file():
        pytest.skip("../shared/data/realdrives (smartLoc, CC BY-SA) not present")
    car = REPO / "config" / "realdrives" / "smartloc_berlin.toml"
    truth = SHARED / "smartloc_berlin_potsdamer_platz_truth.csv"
    ev = _replay_and_evaluate(tmp_path, log, car, truth)
    assert ev["inside_2sigma_frac"] >= 0.80  # the paper's model: 97 %, but 6x too wide
    assert ev["median_axis_ratio"] <= 4.0  # the paper's model: 6.0
    # conservative, not absurdly so: 0.28 along and 0.35 across with the turn scale's prior
    # (0.32 / 0.39 without it); below 0.2 the ellipse would be over twice the error's spread
    assert 0.2 <= ev["along_nees"] <= 1.5 and 0.2 <= ev["across_nees"] <= 1.5


@pytest.mark.parametrize("start_heading_deg", [17.0, 19.0])
def test_smartloc_berlin_is_honest_with_the_start_heading_a_degree_off(
    tmp_path: Path, start_heading_deg: float
) -> None:
    """Issue 21: an operator's start heading is good to about a degree; the figure must not
    hang on it (before: 85 % inside at 18 deg, 75 % at 17 deg)."""
    log = SHARED / "smartloc_berlin_potsdamer_platz.log"
    if not log.is_file():
        pytest.skip("../shared/data/realdrives (smartLoc, CC BY-SA) not present")
    text = (REPO / "config" / "realdrives" / "smartloc_berlin.toml").read_text()
    car = tmp_path / "berlin.toml"
    car.write_text(text.replace("heading_deg = 18.0 ", f"heading_deg = {start_heading_deg} "))
    truth = SHARED / "smartloc_berlin_potsdamer_platz_truth.csv"
    ev = _replay_and_evaluate(tmp_path, log, car, truth)
    assert ev["inside_2sigma_frac"] >= 0.80


def test_a_second_replay_starts_from_what_the_first_learned(tmp_path: Path) -> None:
    """``guidance replay ... --learned FILE``: the first drive saves the car's wheel scale,
    left/right difference and compass bias; the next starts from them: a smaller ellipse,
    still honest."""
    if not COMMA_NMEA.is_file():
        pytest.skip("the comma2k19 compass capture is not present")
    learned = tmp_path / "rav4.learned.json"
    figures = []
    for run in (1, 2):
        track = tmp_path / f"track{run}.csv"
        _cli("replay", str(COMMA_LOG), "--nmea", str(COMMA_NMEA), "--config", str(COMMA_CAR),
             "--track", str(track), "--learned", str(learned))  # fmt: skip
        out = _cli("evaluate", "--track", str(track), "--truth", str(COMMA_TRUTH), "--json")
        figures.append(json.loads(out.strip().splitlines()[-1]))
        assert learned.is_file()
    first, second = figures
    assert second["inside_2sigma_frac"] >= 0.80
    assert second["median_axis_ratio"] < first["median_axis_ratio"]
    doc = json.loads(learned.read_text())
    assert doc["schema"] == "guidance.learned/4" and doc["vehicle_id"] == "rav4"
