"""The shared real drives with each ``[vehicle] yaw_source`` (issue 38): wheels, gyro, both.

Run as a user would (``guidance replay FILE --config CAR --track T --learned L``, then
``guidance evaluate --track T --truth TRUTH --json``), each car's TOML the drive's own with
``yaw_source`` set. comma2k19 (tests/data: the RAV4's ``WHEEL_SPEEDS`` and
``KINEMATICS.YAW_RATE`` merged) with and without its compass; Berlin (../shared/data, when
present) as wheels (its re-encoded CAN log) and gyro (its own speed and yaw-rate CSV). Berlin
has no "both": its CAN log's wheel difference *is* its yaw rate re-encoded, so the two would
be one measurement counted twice (the replay refuses "both" on a speed and yaw-rate CSV).

    .venv/bin/python benchmarks/realdrive_yaw_sources.py
"""

from __future__ import annotations

import io
import json
import sys
import tempfile
from contextlib import redirect_stdout
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from guidance.tools.cli import main as cli

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data" / "realdrives"
SHARED = REPO.parent / "shared" / "data" / "realdrives"


def _cli(*args: str) -> str:
    buf = io.StringIO()
    with redirect_stdout(buf):
        if cli(list(args)) != 0:
            raise SystemExit(f"guidance {' '.join(args)} failed")
    return buf.getvalue()


def run(tmp: Path, log: Path, car_text: str, truth: Path, tag: str, *extra: str) -> dict:
    car, track, learned = tmp / f"{tag}.toml", tmp / f"{tag}.csv", tmp / f"{tag}.json"
    car.write_text(car_text)
    _cli("replay", str(log), "--config", str(car), "--track", str(track),
         "--learned", str(learned), *extra)  # fmt: skip
    ev = json.loads(_cli("evaluate", "--track", str(track), "--truth", str(truth),
                         "--json").splitlines()[-1])  # fmt: skip
    rows = track.read_text().splitlines()
    ev["final_major_axis_m"] = float(rows[-1].split(",")[rows[0].split(",").index("major_axis_m")])
    lp = json.loads(learned.read_text())
    ev["gyro_bias"] = (lp.get("gyro_bias_deg_s"), lp.get("gyro_bias_sigma_deg_s"))
    return ev


def with_source(text: str, source: str, extra: str = "") -> str:
    return text.replace("[vehicle]\n", f'[vehicle]\nyaw_source = "{source}"\n{extra}', 1)


def row(name: str, ev: dict) -> str:
    b, s = ev["gyro_bias"]
    bias = "" if b is None else f"{b:+.3f} +- {s:.3f}"
    return (f"| {name} | {100 * ev['inside_2sigma_frac']:.0f} % | {ev['mean_nees']:.2f} | "
            f"{ev['final_error_m']:.0f} m | {ev['final_major_axis_m']:.0f} m | {bias} |")


def main() -> int:
    print("| drive, yaw source | inside 2-sigma | mean NEES | final error | final 2-sigma major "
          "axis | learned gyro bias, deg/s |\n|---|---|---|---|---|---|")  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        lines = (DATA / "comma2k19_ex1_wheelspeeds.log").read_text().splitlines()
        lines += (DATA / "comma2k19_ex1_kinematics.log").read_text().splitlines()
        log = tmp / "comma.log"
        log.write_text("\n".join(sorted(lines, key=lambda s: float(s[1 : s.index(")")]))) + "\n")
        text = (REPO / "config" / "realdrives" / "comma2k19_ex1.toml").read_text()
        truth = DATA / "comma2k19_ex1_truth.csv"
        nmea = ("--nmea", str(DATA / "comma2k19_ex1_hdg_inferred.nmea"))
        for source in ("wheels", "gyro", "both"):
            ev = run(tmp, log, with_source(text, source), truth, f"c_{source}")
            print(row(f"comma2k19, {source}", ev))
        for source in ("wheels", "gyro", "both"):
            ev = run(tmp, log, with_source(text, source), truth, f"cc_{source}", *nmea)
            print(row(f"comma2k19 with its compass, {source}", ev))
        if not (SHARED / "smartloc_berlin_potsdamer_platz.log").exists():
            print("(Berlin: ../shared/data/realdrives not present)")
            return 0
        berlin = (REPO / "config" / "realdrives" / "smartloc_berlin.toml").read_text()
        truth = SHARED / "smartloc_berlin_potsdamer_platz_truth.csv"
        ev = run(tmp, SHARED / "smartloc_berlin_potsdamer_platz.log", berlin, truth, "b_wheels")
        print(row("Berlin, wheels (re-encoded CAN log)", ev))
        gyro = with_source(berlin, "gyro", "track_m = 1.62\n")
        ev = run(tmp, SHARED / "smartloc_berlin_potsdamer_platz_odom.csv", gyro, truth, "b_gyro")
        print(row("Berlin, gyro (its speed and yaw-rate CSV)", ev))
    return 0


if __name__ == "__main__":
    sys.exit(main())
