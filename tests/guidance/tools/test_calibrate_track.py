"""``guidance calibrate --turned-deg`` (issue 38, item 3): the effective track from two
circles in a car park, written into the learned file the car starts from."""

from __future__ import annotations

import io
import json
import math
from contextlib import redirect_stdout
from pathlib import Path

import can
import pytest

from guidance.app.learned_file import load_learned
from guidance.tools.cli import main
from hal_sim.sim_can import SimCanWheels

PROFILE_TRACK_M = 1.62  # the toyota profile's
CAR = ('[vehicle]\nid = "t1"\n[start]\nx_m = 0.0\ny_m = 0.0\nheading_deg = 0.0\n'
       '[odometry]\nbackend = "can"\ninterface = "virtual"\nchannel = "replay"\n'
       'profile = "toyota"\n[compass]\nenabled = false\n'
       '[checkpoint]\nlearned_path = "learned.json"\n')  # fmt: skip


def _circles(tmp_path: Path, effective_track_m: float, turns: float) -> Path:
    """Straight 5 s, ``turns`` full circles to the left at 4 m/s on an 8 m radius, straight
    5 s; the wheels' speeds those of a car whose effective track is ``effective_track_m``."""
    sim = SimCanWheels(profile="toyota")
    log, t = tmp_path / "circles.log", 0.0
    v, w = 4.0, 0.5
    circle_s = turns * 2 * math.pi / w
    with can.Logger(str(log)) as writer:
        while t < 10.0 + circle_s:
            rate = w if 5.0 <= t < 5.0 + circle_s else 0.0
            sim.set_speeds(v - 0.5 * rate * effective_track_m, v + 0.5 * rate * effective_track_m)
            for msg in sim.encode():
                msg.timestamp = 1_700_000_000.0 + t
                writer.on_message_received(msg)
            t += sim.period_s
    return log


def _cli(*args: str) -> str:
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main(list(args)) == 0
    return buf.getvalue()


def test_two_circles_teach_the_effective_track_and_it_is_kept(tmp_path: Path) -> None:
    true_track = 0.94 * PROFILE_TRACK_M  # 6 % narrower than the profile's (issue 38's figure)
    log = _circles(tmp_path, true_track, 2.0)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    # the wheel scale first (the turn is (1 + k)(1 + kt) of the wheels'): the same drive's
    # length is known too (4 m/s for its 35.1 s, measured with a tape: 0.2 m)
    length = 4.0 * (10.0 + 4 * math.pi / 0.5)
    _cli("calibrate", str(log), "--config", str(car), "--distance-m", f"{length:.2f}",
         "--distance-sigma-m", "0.2", "--write")  # fmt: skip
    out = _cli("calibrate", str(log), "--config", str(car), "--turned-deg", "720", "--write",
               "--json")  # fmt: skip
    doc = json.loads(out.splitlines()[-1])["turn_scale"]
    assert doc["written"] is True
    sigma_track = true_track * doc["turn_scale_sigma"]
    assert abs(doc["effective_track_m"] - true_track) < 2 * sigma_track
    assert doc["turn_scale_sigma"] < 0.01  # 3 degrees of 720 and the wheels' noise: 0.4 %
    learned, why = load_learned(tmp_path / "learned.json", "t1")
    assert why is None and learned is not None
    assert learned.turn_scale == pytest.approx(doc["turn_scale"])
    # a second calibration is combined with the first (inverse variance)
    _cli("calibrate", str(log), "--config", str(car), "--turned-deg", "720", "--write")
    again, _ = load_learned(tmp_path / "learned.json", "t1")
    assert again is not None and again.turn_scale_sigma is not None
    fused = learned.turn_scale_sigma / math.sqrt(2)
    assert again.turn_scale_sigma == pytest.approx(fused, rel=0.01)


def test_a_turn_that_is_not_this_drive_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _circles(tmp_path, PROFILE_TRACK_M, 1.0)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    cases = (("90", "at least 180"), ("-360", "not this drive"), ("1500", "not this drive"))
    for turned, why in cases:
        assert main(["calibrate", str(log), "--config", str(car), "--turned-deg", turned]) != 0
        assert why in capsys.readouterr().err
    assert not (tmp_path / "learned.json").exists()
