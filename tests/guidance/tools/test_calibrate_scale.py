"""``guidance calibrate --distance-m``: the wheel scale from a drive of known length (issue 21),
written into the car's learned-parameters file with its uncertainty; absurd results refused."""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
import json
import math
import os
import re
import time
from contextlib import redirect_stdout
from pathlib import Path

import can
import pytest

from guidance.app.learned_file import load_learned, start_from_learned
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.localize.localizer import Localizer, LocalizerConfig
from guidance.core.localize.wheel_cal import fuse, scale_from_distance
from guidance.tools.cli import main
from hal_sim.sim_can import SimCanWheels

REPO = Path(__file__).resolve().parents[3]
DATA = REPO / "tests" / "data" / "realdrives"
T0 = 1_700_000_000.0
TRUE_SCALE = 0.03  # true distance = measured x (1 + k)
CAR = """
[vehicle]
id = "cal"
track_m = 1.62

[start]
x_m = 0.0
y_m = 0.0
heading_deg = 30.0

[odometry]
backend = "can"
interface = "virtual"
channel = "replay"
profile = "toyota"

[compass]
enabled = false

[checkpoint]
learned_path = "learned.json"
"""


def _cli(*args: str) -> str:
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main(list(args)) == 0
    return buf.getvalue()


def _straight_drive(
    tmp_path: Path, true_m: float = 600.0, v: float = 12.0, turn_deg: float = 0.0
) -> Path:
    """A drive of ``true_m`` metres whose wheels read 3 % short (a candump log), straight or
    turning by ``turn_deg`` evenly over it."""
    sim = SimCanWheels(profile="toyota")
    dt, t = sim.period_s, 0.0
    log = tmp_path / "straight.log"
    measured = v / (1.0 + TRUE_SCALE)
    half = 0.5 * 1.62 * math.radians(turn_deg) / true_m * measured  # omega x track / 2
    with can.Logger(str(log)) as writer:
        while t * v < true_m:
            sim.set_speeds(measured - half, measured + half)
            for msg in sim.encode():
                msg.timestamp = T0 + t
                writer.on_message_received(msg)
            t += dt
    return log


def test_a_simulated_straight_gives_the_scale_within_its_sigma_and_writes_it(
    tmp_path: Path,
) -> None:
    log = _straight_drive(tmp_path)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    out = _cli("calibrate", str(log), "--config", str(car), "--distance-m", "600",
               "--distance-sigma-m", "0.5", "--write", "--json")  # fmt: skip
    res = json.loads(out.splitlines()[-1])["wheel_scale"]
    assert res["written"] and "deviation_deg" not in out
    assert abs(res["scale"] - TRUE_SCALE) <= res["scale_sigma"], res
    assert 0.0007 < res["scale_sigma"] < 0.001  # 0.5 m / 583 m, and 4 cm of wheel noise
    params, why = load_learned(tmp_path / "learned.json", "cal")  # relative to the TOML
    assert why is None and params is not None
    assert params.scale == pytest.approx(res["scale"]) and params.scale_sigma == res["scale_sigma"]
    assert params.diff == 0.0 and params.diff_sigma == 3e-4  # the prior: nothing learned
    # a second calibration combines with the file: the sigma shrinks by sqrt(2)
    _cli("calibrate", str(log), "--config", str(car), "--distance-m", "600",
         "--distance-sigma-m", "0.5", "--write")  # fmt: skip
    again, _ = load_learned(tmp_path / "learned.json", "cal")
    assert again is not None
    assert again.scale_sigma == pytest.approx(res["scale_sigma"] / math.sqrt(2.0), rel=0.01)


def test_two_known_points_on_a_straight(tmp_path: Path) -> None:
    log = _straight_drive(tmp_path)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    # 600 m due north of the first point (one degree of latitude is 111.2 km there)
    out = _cli("calibrate", str(log), "--config", str(car), "--points", "48.0,11.0",
               f"{48.0 + 600.0 / 111_200.0:.7f},11.0", "--json")  # fmt: skip
    res = json.loads(out.splitlines()[-1])["wheel_scale"]
    assert not res["written"]
    assert res["known_m"] == pytest.approx(600.0, abs=1.0)
    assert abs(res["scale"] - TRUE_SCALE) <= 2.0 * res["scale_sigma"], res


def test_two_known_points_on_a_bend_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _straight_drive(tmp_path, turn_deg=45.0)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    args = ["--points", "48.0,11.0", "48.005,11.0"]
    assert main(["calibrate", str(log), "--config", str(car), *args]) != 0
    err = capsys.readouterr().err
    assert re.search(r"heading spans 4[45] degrees", err) and "--distance-m" in err, err
    # measured along the road, the same bend is fine
    out = _cli("calibrate", str(log), "--config", str(car), "--distance-m", "600", "--json")
    assert abs(json.loads(out.splitlines()[-1])["wheel_scale"]["scale"] - TRUE_SCALE) < 0.002


def test_an_absurd_result_is_refused_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _straight_drive(tmp_path)
    car = tmp_path / "car.toml"
    car.write_text(CAR)

    def refused(*extra: str) -> str:
        assert main(["calibrate", str(log), "--config", str(car), *extra]) != 0
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        return err

    err = refused("--distance-m", "1000", "--write")
    assert re.search(r"wheel scale \+71\.\d % .* outside \+-10 %", err), err
    assert not (tmp_path / "learned.json").exists()
    assert "at least 100 m" in refused("--distance-m", "50", "--to-t", str(T0 + 4.0))
    (tmp_path / "learned.json").write_text('{"schema": "guidance.learned/1", "scale": 7}')
    assert "not written" in refused("--distance-m", "600", "--write")
    assert "--nmea" in refused()


def test_the_pure_fit_and_fusion() -> None:
    fit = scale_from_distance(1000.0, 1010.0, 1.0, 5e-6)
    assert fit.scale == pytest.approx(0.01)
    assert fit.scale_sigma == pytest.approx(math.hypot(1e-3, 1.01e-3 * math.sqrt(2.5e-3)))
    assert fuse(0.01, 0.001, 0.012, 0.001)[:2] == pytest.approx((0.011, 0.001 / math.sqrt(2)))
    assert fuse(0.01, 0.001, 0.03, 0.001) == (0.03, 0.001, False)  # 14 sigma apart: replaced


def _truth_length(path: Path) -> tuple[float, float, float]:
    with path.open() as f:
        rows = [(float(r["t"]), float(r["east_m"]), float(r["north_m"]))
                for r in csv.DictReader(f)]  # fmt: skip
    length = sum(math.hypot(b[1] - a[1], b[2] - a[2]) for a, b in itertools.pairwise(rows))
    return rows[0][0], rows[-1][0], length


def test_comma2k19_over_the_truth_span_gives_the_truth_scale(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The RAV4's wheels measure 0.89 % short of its post-processed truth path (README); the
    learned file is what ``guidance replay --learned`` then starts from."""
    t_from, t_to, truth_m = _truth_length(DATA / "comma2k19_ex1_truth.csv")
    log, car = (
        DATA / "comma2k19_ex1_wheelspeeds.log",
        REPO / "config" / "realdrives" / "comma2k19_ex1.toml",
    )
    learned = tmp_path / "rav4.json"
    out = _cli("calibrate", str(log), "--config", str(car), "--distance-m", f"{truth_m:.2f}",
               "--from-t", f"{t_from}", "--to-t", f"{t_to}", "--learned", str(learned), "--write",
               "--json")  # fmt: skip
    res = json.loads(out.splitlines()[-1])["wheel_scale"]
    truth_scale = 1.0 / (1.0 - 0.0089) - 1.0
    assert abs(res["scale"] - truth_scale) <= res["scale_sigma"], res
    assert res["scale_sigma"] < 0.002  # 1 m over 1 km, and the wheel noise
    capsys.readouterr()
    track = tmp_path / "track.csv"
    _cli("replay", str(log), "--config", str(car), "--learned", str(learned), "--track", str(track))
    assert (
        "starting from learned parameters (1.0 km, 0.0 days old): wheel scale +0.94 +- 0.10 %"
        in (capsys.readouterr().err)
    )
    # Honest with the scale known: the ellipse is then thin along the road, and the second-
    # order term of the 14-degree heading error (~15 m along, at the end) keeps the truth in
    # it (without the term: 79 % inside, mean NEES 2.5).
    truth = DATA / "comma2k19_ex1_truth.csv"
    out = _cli("evaluate", "--track", str(track), "--truth", str(truth), "--json")
    ev = json.loads(out.splitlines()[-1])
    assert ev["inside_2sigma_frac"] >= 0.95 and ev["mean_nees"] <= 1.5, ev


# -- issue 40, defects 7 and 12: what calibrate writes the car takes; one line, never internal ---
def test_calibrate_refuses_bad_inputs_with_one_line_and_no_internal_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _straight_drive(tmp_path)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    nmea = tmp_path / "compass.log"
    nmea.write_text("0.0 $HCHDG,30.0,,,,*6D\n")
    cases = {  # argv -> what the line says
        (str(tmp_path / "missing.log"), "--distance-m", "600"): "not found",
        (str(tmp_path), "--distance-m", "600"): "not a regular file (a folder)",
        (str(log), "--nmea", str(nmea), "--start-heading-deg", "nan"): "invalid number value",
        (str(log), "--nmea", str(nmea), "--start-heading-deg", "inf"): "invalid number value",
        (str(log), "--distance-m", "6_00"): "invalid number value",
        (str(log), "--distance-m", "\u0666\u0660\u0660"): "invalid number value",  # Arabic-Indic
        (str(log), "--distance-m", "600", "--distance-sigma-m", "2000", "--write"): "+-344 %",
    }
    for argv, said in cases.items():
        with pytest.raises(SystemExit) if "invalid" in said else contextlib.nullcontext():
            assert main(["calibrate", *argv, "--config", str(car)]) == 2
        err = capsys.readouterr().err
        assert said in err and "internal error" not in err and "Traceback" not in err, (argv, err)
        assert err.strip().splitlines()[-1].startswith("guidance calibrate: error:"), err
    assert not (tmp_path / "learned.json").exists()
    fifo = tmp_path / "fifo.json"  # defect 4: `calibrate --write` hung on a FIFO learned file
    os.mkfifo(fifo)
    assert main(["calibrate", str(log), "--config", str(car), "--distance-m", "600",
                 "--learned", str(fifo), "--write"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert f"learned parameters {fifo}: not a regular file (a FIFO); not written" in err, err


def test_what_calibrate_writes_passes_the_car_s_loader(tmp_path: Path) -> None:
    """Defect 7: a 2 cm distance sigma over 600 m (below what any drive can know: floored at
    ``MIN_SCALE_SIGMA``), and a log stamped after 1e11 s (the file's save time is then now,
    not the log's future): both written, both taken by the car's own loader at its start."""
    from guidance.core.localize.state_limits import MIN_SCALE_SIGMA

    log = _straight_drive(tmp_path)
    car = tmp_path / "car.toml"
    car.write_text(CAR)
    out = _cli("calibrate", str(log), "--config", str(car), "--distance-m", "600",
               "--distance-sigma-m", "0.02", "--write")  # fmt: skip
    assert "+- 0.01 %" in out
    first = LocalizerConfig(car_model(EstimatorConfig(), calibrated=False), start_xy_m=(0.0, 0.0))
    used, note = start_from_learned(Localizer(first), tmp_path / "learned.json", "cal", time.time())
    assert used is not None and used.scale_sigma >= MIN_SCALE_SIGMA, note
    future = tmp_path / "future.log"  # the same drive stamped 1.7e11 s (about 5,000 years on)
    ahead = 168_300_000_000  # every stamp after 1e11 s
    future.write_text(re.sub(r"\((\d+)\.", lambda m: f"({int(m[1]) + ahead}.", log.read_text()))
    (tmp_path / "learned.json").unlink()
    _cli("calibrate", str(future), "--config", str(car), "--distance-m", "600", "--write")
    params, why = load_learned(tmp_path / "learned.json", "cal", time.time())
    assert why is None and params is not None and params.saved_unix_s <= time.time()
