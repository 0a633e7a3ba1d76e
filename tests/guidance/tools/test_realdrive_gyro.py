"""A car's own speed and yaw rate through ``guidance replay`` as a gyro car (issue 38).

Run as a user would (``guidance replay ODOM.csv --config CAR.toml --track T --learned L``,
then ``guidance evaluate``): a drive made here from a known motion and a sensor with a known
bias (always), and the shared smartLoc Berlin drive's own odometry CSV (CC BY-SA, used from
../shared/data when present), against the wheel-difference model on the same drive.
"""

from __future__ import annotations

import io
import json
import math
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from guidance.errors import UserError
from guidance.tools.cli import main
from guidance.tools.odometry_csv import odometry_inputs, read_odometry_csv

REPO = Path(__file__).resolve().parents[3]
SHARED = REPO.parent / "shared" / "data" / "realdrives"
BERLIN_ODOM = SHARED / "smartloc_berlin_potsdamer_platz_odom.csv"
BERLIN_LOG = SHARED / "smartloc_berlin_potsdamer_platz.log"
BERLIN_TRUTH = SHARED / "smartloc_berlin_potsdamer_platz_truth.csv"
BERLIN_CAR = REPO / "config" / "realdrives" / "smartloc_berlin.toml"

CAR = """[vehicle]
id = "gyrocar"
track_m = 1.6
yaw_source = "{source}"

[start]
lat_deg = 52.5
lon_deg = 13.4
heading_deg = 0.0

[estimator]
compass_two_sigma_deg = false

[odometry]
backend = "can"
interface = "virtual"
channel = "replay"
profile = "toyota"

[compass]
enabled = false
"""


def _cli(*args: str) -> str:
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main(list(args)) == 0
    return buf.getvalue()


def _run(tmp_path: Path, odom: Path, car: Path, truth: Path, tag: str) -> tuple[dict, dict]:
    track, learned = tmp_path / f"track_{tag}.csv", tmp_path / f"learned_{tag}.json"
    _cli("replay", str(odom), "--config", str(car), "--track", str(track),
         "--learned", str(learned))  # fmt: skip
    out = _cli("evaluate", "--track", str(track), "--truth", str(truth), "--json")
    rows = track.read_text().splitlines()
    final_axis = float(rows[-1].split(",")[rows[0].split(",").index("major_axis_m")])
    ev = dict(json.loads(out.splitlines()[-1]), final_major_axis_m=final_axis)
    return ev, json.loads(learned.read_text())


def _made_drive(tmp_path: Path, bias_deg_s: float) -> tuple[Path, Path]:
    """A drive from a parked start: straights, right-angle turns, a stop at a light; 5 Hz."""
    rng = np.random.default_rng(6)
    plan = [(20.0, 0.0, 0.0), (40.0, 10.0, 0.0), (9.0, 5.0, 10.0), (40.0, 10.0, 0.0),
            (30.0, 0.0, 0.0), (40.0, 10.0, 0.0), (9.0, 5.0, -10.0), (60.0, 10.0, 0.0),
            (9.0, 5.0, -10.0), (60.0, 10.0, 0.0)]  # fmt: skip
    dt, t, x, y, th = 0.2, 1.7e9, 0.0, 0.0, math.pi / 2
    odom, truth = ["t,speed_mps,yaw_rate_rad_s"], ["t,east_m,north_m"]
    bias = math.radians(bias_deg_s)
    for seconds, v, rate_deg in plan:
        for _ in range(round(seconds / dt)):
            t += dt
            w = math.radians(rate_deg)
            x += v * dt * math.cos(th + 0.5 * w * dt)
            y += v * dt * math.sin(th + 0.5 * w * dt)
            th += w * dt
            reading = w + bias + rng.normal() * math.radians(0.1)
            odom.append(f"{t:.3f},{v:.4f},{reading:.6f}")
            truth.append(f"{t:.3f},{x:.3f},{y:.3f}")
    (tmp_path / "odom.csv").write_text("\n".join(odom) + "\n")
    (tmp_path / "truth.csv").write_text("\n".join(truth) + "\n")
    return tmp_path / "odom.csv", tmp_path / "truth.csv"


def test_a_gyro_car_learns_its_bias_standing_and_stays_honest(tmp_path: Path) -> None:
    """The same drive as a gyro car and as a wheel car whose yaw rate is split into a wheel
    difference (what the shared Berlin log's re-encoding does): the wheel model takes the
    gyro's bias for a left/right difference, which grows with distance, not time."""
    odom, truth = _made_drive(tmp_path, 0.25)
    gyro_car, wheel_car = tmp_path / "gyro.toml", tmp_path / "wheels.toml"
    gyro_car.write_text(CAR.format(source="gyro"))
    wheel_car.write_text(CAR.format(source="wheels"))
    g, learned = _run(tmp_path, odom, gyro_car, truth, "gyro")
    w, _ = _run(tmp_path, odom, wheel_car, truth, "wheels")
    assert learned["gyro_bias_deg_s"] == pytest.approx(0.25, abs=0.03)
    assert g["inside_2sigma_frac"] >= 0.80
    assert g["final_error_m"] < 0.5 * w["final_error_m"]
    assert w["inside_2sigma_frac"] < 0.5  # the bias as a wheel difference: overconfident


def test_the_odometry_csv_is_read_through_the_door_and_refused_with_the_line(
    tmp_path: Path,
) -> None:
    good = tmp_path / "o.csv"
    good.write_text("t,speed_mps,yaw_rate_rad_s\n1.0,0,0.01\n1.2,1.0,0.02\n")
    msgs = list(odometry_inputs(good, gyro=True, track_m=1.6))
    assert [type(m).__name__ for m in msgs] == ["YawRate", "YawRate", "WheelOdometry"]
    assert msgs[-1].d_left_m == pytest.approx(0.1)
    split = list(odometry_inputs(good, gyro=False, track_m=1.6))
    assert split[0].d_right_m - split[0].d_left_m == pytest.approx(0.015 * 0.2 * 1.6)
    cases = {
        "t,speed_mps\n2.0,1\n1.0,1\n": "line 3: time 1.0 is not after 2.0",
        "t,speed_mps,yaw_rate_rad_s\n1.0,1,57.3\n": "is it in deg/s",
        "t,speed_mps\n1.0,400\n": "beyond +-100 m/s",
        "t,yaw_rate_rad_s\n1.0,0\n": "lacks speed_mps",
    }
    for text, why in cases.items():
        bad = tmp_path / "bad.csv"
        bad.write_text(text)
        with pytest.raises(UserError, match=why.replace("+", r"\+")):
            read_odometry_csv(bad)


@pytest.mark.skipif(not BERLIN_ODOM.exists(), reason="../shared/data/realdrives not present")
def test_berlin_through_its_own_speed_and_yaw_rate_as_a_gyro_car(tmp_path: Path) -> None:
    """The shared drive's own odometry as a gyro car, against the wheel-difference model on
    its re-encoded CAN log: honest, and a smaller final ellipse."""
    car = tmp_path / "berlin_gyro.toml"
    text = BERLIN_CAR.read_text().replace("[vehicle]\n", '[vehicle]\nyaw_source = "gyro"\n')
    car.write_text(text.replace('id = "smartloc"', 'id = "smartloc"\ntrack_m = 1.62', 1))
    g, learned = _run(tmp_path, BERLIN_ODOM, car, BERLIN_TRUTH, "gyro")
    w, _ = _run(tmp_path, BERLIN_LOG, BERLIN_CAR, BERLIN_TRUTH, "wheels")
    assert g["inside_2sigma_frac"] >= 0.80
    assert g["final_major_axis_m"] < w["final_major_axis_m"]
    assert abs(learned["gyro_bias_deg_s"]) < 3 * learned["gyro_bias_sigma_deg_s"] + 0.1


COMMA = REPO / "tests" / "data" / "realdrives"


def test_comma2k19_as_a_gyro_car_through_its_can_yaw_rate(tmp_path: Path) -> None:
    """The RAV4's own KINEMATICS.YAW_RATE (shipped excerpt) merged with its wheel speeds: a
    gyro car that never stands still on this straight minute cannot see its bias (about
    -0.4 deg/s): honest, and wider than the wheels; with its compass the bias is seen."""
    lines = (COMMA / "comma2k19_ex1_wheelspeeds.log").read_text().splitlines()
    lines += (COMMA / "comma2k19_ex1_kinematics.log").read_text().splitlines()
    log = tmp_path / "comma.log"
    log.write_text("\n".join(sorted(lines, key=lambda s: float(s[1 : s.index(")")]))) + "\n")
    car = tmp_path / "rav4_gyro.toml"
    text = (REPO / "config" / "realdrives" / "comma2k19_ex1.toml").read_text()
    car.write_text(text.replace("[vehicle]\n", '[vehicle]\nyaw_source = "gyro"\n', 1))
    truth = COMMA / "comma2k19_ex1_truth.csv"
    g, learned = _run(tmp_path, log, car, truth, "gyro")
    assert g["inside_2sigma_frac"] >= 0.80 and g["mean_nees"] <= 2.5
    assert learned["gyro_bias_sigma_deg_s"] > 0.25  # no stop: nothing taught it
    track = tmp_path / "t.csv"
    _cli("replay", str(log), "--config", str(car), "--track", str(track),
         "--nmea", str(COMMA / "comma2k19_ex1_hdg_inferred.nmea"))  # fmt: skip
    out = _cli("evaluate", "--track", str(track), "--truth", str(truth), "--json")
    c = json.loads(out.splitlines()[-1])
    assert c["inside_2sigma_frac"] >= 0.80 and c["final_error_m"] < 0.5 * g["final_error_m"]


def test_comma2k19_with_wheels_and_gyro_both_learns_the_bias_the_gyro_alone_cannot(
    tmp_path: Path,
) -> None:
    """``yaw_source = "both"`` on the RAV4's real wheel speeds and yaw rate: the wheels see the
    gyro's bias on a drive that never stops (-0.32 +- 0.10 deg/s learned), so the final
    ellipse and error are smaller than either source alone gives, still honest."""
    lines = (COMMA / "comma2k19_ex1_wheelspeeds.log").read_text().splitlines()
    lines += (COMMA / "comma2k19_ex1_kinematics.log").read_text().splitlines()
    log = tmp_path / "comma.log"
    log.write_text("\n".join(sorted(lines, key=lambda s: float(s[1 : s.index(")")]))) + "\n")
    text = (REPO / "config" / "realdrives" / "comma2k19_ex1.toml").read_text()
    truth = COMMA / "comma2k19_ex1_truth.csv"
    ev = {}
    for source in ("wheels", "both"):
        car = tmp_path / f"rav4_{source}.toml"
        car.write_text(text.replace("[vehicle]\n", f'[vehicle]\nyaw_source = "{source}"\n', 1))
        ev[source], learned = _run(tmp_path, log, car, truth, source)
    b = ev["both"]
    assert b["inside_2sigma_frac"] >= 0.80 and b["mean_nees"] <= 2.5
    assert b["final_major_axis_m"] < ev["wheels"]["final_major_axis_m"]
    assert b["final_error_m"] < ev["wheels"]["final_error_m"]
    assert learned["gyro_bias_deg_s"] < -0.1 and learned["gyro_bias_sigma_deg_s"] < 0.2
