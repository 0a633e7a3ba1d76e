"""Roadway scene: co-driver keyboard parsing, the keyboard source, and turn detection."""

from __future__ import annotations

import io
import logging
import math
import os
import threading
import time

import numpy as np
import pytest

from drivers.keyboard import KeyboardScene
from guidance.core.co_driver import ExitsTyped, SceneParseError, TurnTyped, parse_line, to_scene
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.messages import HeadingFix, IntersectionScene, TurnCompleted, WheelOdometry
from guidance.core.model import wrap_angle
from guidance.core.plan.turns import TurnDetector

DEG = math.pi / 180


@pytest.mark.parametrize(
    ("line", "expected_deg"),
    [
        ("l s r", (90, 0, -90)),
        ("lsr", (90, 0, -90)),
        ("s, r", (0, -90)),
        ("left straight right", (90, 0, -90)),
        ("bl hr u", (45, -135, 180)),
        ("846", (0, 90, -90)),  # keypad: 8 up, 4 left, 6 right
        ("l30 r60", (30, -60)),
        ("+45 -120", (45, -120)),
        ("8 4", (0, 90)),
        ("  S  ", (0,)),
    ],
)
def test_exits_are_parsed_relative_to_the_car(line: str, expected_deg: tuple[float, ...]) -> None:
    typed = parse_line(line)
    assert isinstance(typed, ExitsTyped)
    assert typed.relative_rad == pytest.approx(tuple(d * DEG for d in expected_deg))


@pytest.mark.parametrize(
    ("line", "expected_deg"),
    [("turned left", 90), ("tl", 90), ("t r", -90), ("took straight", 0), ("t 4", 90), ("tu", 180)],
)
def test_turn_reports(line: str, expected_deg: float) -> None:
    typed = parse_line(line)
    assert isinstance(typed, TurnTyped)
    assert typed.relative_rad == pytest.approx(expected_deg * DEG)


@pytest.mark.parametrize("line", ["x", "l q", "r200", "270", "+270", "turned", "turned left right"])
def test_bad_lines_are_refused_with_a_reason(line: str) -> None:
    with pytest.raises(SceneParseError):
        parse_line(line)


def test_blank_line_is_nothing() -> None:
    assert parse_line("   \n") is None


def test_exits_become_absolute_headings_with_the_estimated_heading() -> None:
    typed = parse_line("l s r")
    assert isinstance(typed, ExitsTyped)
    msg = to_scene(typed, 12.5, math.pi / 2)  # driving north
    assert isinstance(msg, IntersectionScene)
    assert msg.t_s == 12.5
    assert msg.distance_m is None
    # left of north is west (pi), straight is north, right is east (0).
    assert [wrap_angle(h) for h in msg.exit_headings_rad] == pytest.approx(
        [math.pi, math.pi / 2, 0.0], abs=1e-9
    )
    assert msg.labels == ("l", "s", "r")


def test_keyboard_scene_reads_lines_on_its_thread_and_reports_bad_ones() -> None:
    stream = io.StringIO("l s\nbogus\ntl\n")
    feedback = io.StringIO()
    got: list[object] = []
    done = threading.Event()

    def sink(msg: object) -> None:
        got.append(msg)
        if len(got) == 2:
            done.set()

    scene = KeyboardScene(lambda: 0.0, stream=stream, feedback=feedback, clock=lambda: 3.0)
    scene.start(sink)
    assert done.wait(5.0)
    scene.stop()
    assert isinstance(got[0], IntersectionScene)
    assert got[0].exit_headings_rad == pytest.approx((math.pi / 2, 0.0))
    assert isinstance(got[1], TurnCompleted)
    assert got[1].source == "co-driver"
    assert "unknown exit 'bogus'" in feedback.getvalue()
    assert scene.stats() == {"lines": 3, "rejected": 1, "intersections": 1, "turns": 1, "read": 3}


# ----------------------------------------------------------------------------- turn detection


def _drive(segments: list[tuple[float, float]], compass_sigma_deg: float | None = 20.0) -> list:
    """Drive (distance m, turn deg) segments at 10 m/s through the real estimator.

    Wheel increments every 0.1 s; a turn is spread over 10 m (a 6-7 m radius corner). The
    compass (noisy, 6 Hz) keeps the heading honest. Returns the detector's reports.
    """
    rng = np.random.default_rng(3)
    track = 1.72
    est = PoseEstimator(EstimatorConfig(compass_two_sigma_deg=compass_sigma_deg))
    det = TurnDetector()
    true_h, t, odo = 0.0, 0.0, 0.0
    reports = []
    step_m = 1.0
    for length, turn_deg in segments:
        n_turn = 10 if turn_deg else 0
        for i in range(int(length / step_m)):
            dth = math.radians(turn_deg) / n_turn if i < n_turn else 0.0
            dl = step_m - 0.5 * track * dth
            dr = step_m + 0.5 * track * dth
            true_h = wrap_angle(true_h + dth)
            t += 0.1
            odo += step_m
            est.process(WheelOdometry(t, dl, dr))
            if compass_sigma_deg and i % 2 == 0:
                noise = rng.normal(0, math.radians(compass_sigma_deg) / 2)
                est.process(HeadingFix(t, wrap_angle(true_h + noise)))
            r = det.update(t, float(est.x[2]), odo)
            if r is not None:
                reports.append((odo, r))
    return reports


def test_one_report_per_corner_with_the_right_sign_and_size() -> None:
    reports = _drive([(60, 0), (60, 90), (80, -90), (60, 0), (40, 180), (60, 0)])
    changes = [math.degrees(r.heading_change_rad) for _, r in reports]
    assert len(changes) == 3
    assert changes[0] == pytest.approx(90, abs=15)
    assert changes[1] == pytest.approx(-90, abs=15)
    assert abs(changes[2]) == pytest.approx(180, abs=20)
    assert all(r.source == "detected" for _, r in reports)
    # Reported soon after the corner (within the settle distance plus a few metres).
    ends = [60 + 10, 60 + 60 + 10, 60 + 60 + 80 + 60 + 10]
    for (odo, _), end in zip(reports, ends, strict=True):
        assert end <= odo <= end + 20


def test_no_turn_on_a_straight_road_with_a_noisy_compass() -> None:
    assert _drive([(2000, 0)], compass_sigma_deg=30.0) == []


def test_a_lane_change_or_bend_is_not_a_turn() -> None:
    assert _drive([(50, 0), (30, 25), (30, -25), (50, 0)]) == []


def test_detector_state_survives_a_snapshot() -> None:
    a = TurnDetector()
    for i in range(20):
        a.update(i * 0.1, 0.05 * i, float(i))
    b = TurnDetector()
    b.restore(a.snapshot())
    for i in range(20, 60):
        ra = a.update(i * 0.1, min(0.05 * i, math.pi / 2), float(i))
        rb = b.update(i * 0.1, min(0.05 * i, math.pi / 2), float(i))
        assert (ra is None) == (rb is None)
        if ra is not None and rb is not None:
            assert ra.heading_change_rad == rb.heading_change_rad


def test_keyboard_is_a_reader_on_the_drivers_base_a_failing_sink_is_counted_and_logged_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """KeyboardScene on drivers._reader.ThreadedSource: the sink raising on every line is
    counted (sink_errors), logged once, and the end of the input is the status "ended"."""
    stream = io.StringIO("l s\nl s\nl s\n")

    def sink(msg: object) -> None:
        raise RuntimeError("loop gone")

    scene = KeyboardScene(lambda: 0.0, stream=stream, feedback=io.StringIO())
    with caplog.at_level(logging.ERROR, logger="drivers.keyboard"):
        scene.start(sink)
        deadline = time.monotonic() + 5.0
        while scene.health().status != "ended" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert scene.health().status == "ended"
        scene.stop()
    assert scene.stats()["sink_errors"] == 3
    assert sum("sink raised" in r.getMessage() for r in caplog.records) == 1


def test_stopping_a_keyboard_blocked_in_readline_is_quick_and_not_an_error(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A terminal's readline cannot be woken: stop() returns within its short join and leaves
    the daemon thread blocked, logged at debug only (a normal shutdown must not log errors)."""
    r, w = os.pipe()
    stream = os.fdopen(r, "r")
    scene = KeyboardScene(lambda: 0.0, stream=stream, feedback=io.StringIO())
    try:
        with caplog.at_level(logging.DEBUG, logger="drivers.keyboard"):
            scene.start(lambda msg: None)
            t0 = time.monotonic()
            scene.stop()
            assert time.monotonic() - t0 < 10.0  # its short join, not the blocked read's wait
        assert not [rec for rec in caplog.records if rec.levelno >= logging.WARNING]
        assert any("left blocked" in rec.getMessage() for rec in caplog.records)
    finally:
        os.close(w)  # end of input: the blocked thread returns
        time.sleep(0.1)
        stream.close()
