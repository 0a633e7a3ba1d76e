"""``guidance calibrate``: the deviation card from a calibration drive, written into the TOML."""

from __future__ import annotations

import io
import json
import math
import tomllib
from contextlib import redirect_stdout
from pathlib import Path

import can
import numpy as np
import pytest

from guidance.app.config import load_config
from guidance.core.localize.compass_cal import CompassCalibration
from guidance.tools.calibrate import write_card
from guidance.tools.cli import main
from hal_sim.sim_can import SimCanWheels
from hal_sim.sim_compass import hdg_body, nmea_sentence

REPO = Path(__file__).resolve().parents[3]
DATA = REPO / "tests" / "data" / "realdrives"
TRUE_CARD = CompassCalibration(20.0, 8.0, -5.0, 3.0, 2.0)
T0 = 1_700_000_000.0
DECLINATION = 5.0
START_TRUE = 30.0

CAR = f"""
[vehicle]
id = "cal"
track_m = 1.62

[start]
x_m = 0.0
y_m = 0.0
heading_deg = {START_TRUE}

[odometry]
backend = "can"
interface = "virtual"
channel = "replay"
profile = "toyota"

[compass]
backend = "nmea_serial"
port = "/dev/null"
declination_deg = {DECLINATION}
"""


def _cli(*args: str) -> str:
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main(list(args)) == 0
    return buf.getvalue()


def _reading_for(magnetic_deg: float) -> float:
    """The compass reading whose corrected value is ``magnetic_deg`` (invert the card)."""
    r = magnetic_deg
    for _ in range(50):
        r = magnetic_deg - TRUE_CARD.deviation_deg(r)
    return r % 360.0


def _circles_drive(tmp_path: Path) -> tuple[Path, Path]:
    """Two slow circles (radius 12 m, 4 m/s), one each way, as a candump log and NMEA text."""
    rng = np.random.default_rng(3)
    sim = SimCanWheels(profile="toyota")
    half = 0.5 * 1.62
    v, radius = 4.0, 12.0
    lap_s = 2 * math.pi * radius / v
    dt, t = sim.period_s, 0.0
    heading_true = START_TRUE
    log = tmp_path / "cal.log"
    nmea_lines = []
    next_nmea = 0.0
    with can.Logger(str(log)) as writer:
        while t < 2 * lap_s + 4.0:
            turn = 0.0 if t < 2.0 else (1.0 if t < 2.0 + lap_s else -1.0)  # left, then right
            if t > 2.0 + 2 * lap_s:
                turn = 0.0
            omega = turn * v / radius
            sim.set_speeds(v - omega * half, v + omega * half)
            for msg in sim.encode():
                msg.timestamp = T0 + t
                writer.on_message_received(msg)
            heading_true -= math.degrees(omega * dt)  # a left turn lowers the compass heading
            if t >= next_nmea:
                magnetic = heading_true - DECLINATION
                reading = _reading_for(magnetic) + rng.normal(0.0, 0.7)
                body = hdg_body(reading % 360.0)
                nmea_lines.append(f"{T0 + t:.3f} " + nmea_sentence(body).decode().strip())
                next_nmea += 0.1
            t += dt
    nmea = tmp_path / "cal.nmea"
    nmea.write_text("\n".join(nmea_lines) + "\n")
    return log, nmea


def test_two_circles_recover_the_card_and_write_it(tmp_path: Path) -> None:
    log, nmea = _circles_drive(tmp_path)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    out = _cli("calibrate", str(log), "--nmea", str(nmea), "--config", str(car), "--write",
               "--json")  # fmt: skip
    res = json.loads(out.splitlines()[-1])
    assert res["terms"] == "offset + 2 harmonics"
    want = [TRUE_CARD.a_deg, TRUE_CARD.b_deg, TRUE_CARD.c_deg, TRUE_CARD.d_deg, TRUE_CARD.e_deg]
    assert np.allclose(res["deviation_deg"], want, atol=1.5), res
    assert res["residual_rms_deg"] < 1.5
    written = tomllib.loads(car.read_text())["compass"]["deviation_deg"]
    assert written == res["deviation_deg"]
    cfg = load_config(car, require_goal=False)  # the car reads it back
    assert cfg.pipeline.compass_deviation_deg == tuple(written)
    assert cfg.pipeline.estimator.compass_bias_sigma_deg == 5.0  # calibrated prior
    # calibrating again replaces the line instead of adding one
    _cli("calibrate", str(log), "--nmea", str(nmea), "--config", str(car), "--write")
    assert car.read_text().count("deviation_deg") == 1


def test_a_straight_drive_fits_the_offset_only_and_says_so(tmp_path: Path) -> None:
    car = tmp_path / "car.toml"
    car.write_text((REPO / "config" / "realdrives" / "comma2k19_ex1.toml").read_text())
    out = _cli(
        "calibrate",
        str(DATA / "comma2k19_ex1_wheelspeeds.log"),
        "--nmea",
        str(DATA / "comma2k19_ex1_hdg_inferred.nmea"),
        "--config",
        str(car),
        "--json",
    )
    res = json.loads(out.splitlines()[-1])
    assert res["terms"] == "offset only" and "two slow circles" in res["note"]
    assert 35.0 < res["deviation_deg"][0] < 50.0  # the compass reads about 40 degrees low
    assert not res["written"] and "deviation_deg" not in car.read_text()


def test_write_card_adds_a_compass_table_when_there_is_none(tmp_path: Path) -> None:
    car = tmp_path / "car.toml"
    car.write_text("[vehicle]\nid = 'x'\n[start]\nlat_deg = 42.44\nlon_deg = -76.5\n")
    car.chmod(0o640)  # readable by the car's service group, as it was set up
    write_card(car, [1.0, 2.0, 3.0, 4.0, 5.0])
    assert tomllib.loads(car.read_text())["compass"]["deviation_deg"] == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert car.stat().st_mode & 0o777 == 0o640  # the rewrite keeps the file's mode
    assert [f.name for f in tmp_path.iterdir()] == ["car.toml"]  # no temporary file left


def test_bad_inputs_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    empty = tmp_path / "empty.nmea"
    empty.write_text("garbage\n")
    code = main(["calibrate", str(DATA / "comma2k19_ex1_wheelspeeds.log"), "--nmea", str(empty),
                 "--config", str(car), "--profile", "toyota"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("guidance calibrate: error:") and "Traceback" not in err
