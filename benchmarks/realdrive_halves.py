"""A real drive split in two halves: the first learns, the second starts from what it learned.

Issue 21, item 3 on a shared drive. The drive's CAN log is cut at the middle of its time span.
The first half is replayed through the car's pipeline with two simulated landmark fixes taken
from the truth (at a quarter and at half of the drive, ``FIX_SIGMA_M``); what the filter
learned (wheel scale, left/right difference) is saved into a learned-parameters file as
``guidance replay --learned`` saves it. The second half starts where the truth is at the split,
as an operator would give it (the position from the map, the heading of the street rounded to a
degree, and that heading +-1 degree), with its truth re-based to that start; it is replayed
through the CLI (``guidance replay LOG --config CAR --track T [--learned FILE]``, then
``guidance evaluate --track T --truth TRUTH --json``) from the learned file and from the priors.

    .venv/bin/python benchmarks/realdrive_halves.py [--drive berlin|comma2k19] [--out DIR]

The drives are in ../shared/data/realdrives (smartLoc Berlin is CC BY-SA: it stays there).
"""

from __future__ import annotations

import argparse
import csv
import heapq
import io
import json
import re
import sys
import tempfile
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

SHARED = REPO.parent / "shared" / "data" / "realdrives"
DRIVES = {
    "berlin": (
        SHARED / "smartloc_berlin_potsdamer_platz.log",
        SHARED / "smartloc_berlin_potsdamer_platz_truth.csv",
        REPO / "config" / "realdrives" / "smartloc_berlin.toml",
    ),
    "comma2k19": (
        REPO / "tests" / "data" / "realdrives" / "comma2k19_ex1_wheelspeeds.log",
        REPO / "tests" / "data" / "realdrives" / "comma2k19_ex1_truth.csv",
        REPO / "config" / "realdrives" / "comma2k19_ex1.toml",
    ),
}
FIX_SIGMA_M = 3.0
"""A landmark fix's 1-sigma (a confirmed camera match on a surveyed landmark)."""
FIX_AT = (0.25, 0.5)
"""The fixes, as fractions of the whole drive's time span."""
FIGURES = ("inside_2sigma_frac", "mean_nees", "median_axis_ratio", "along_nees", "across_nees",
           "final_error_m")  # fmt: skip
_STAMP = re.compile(r"^\((\d+(?:\.\d*)?)\)")


def split_log(log: Path, t_split: float, first: Path, second: Path) -> None:
    """A candump log cut at ``t_split`` (each line by its time stamp)."""
    with first.open("w") as a, second.open("w") as b:
        for line in log.read_text().splitlines(keepends=True):
            m = _STAMP.match(line)
            if m:
                (a if float(m.group(1)) < t_split else b).write(line)


def read_truth(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def truth_at(rows: list[dict[str, str]], t: float) -> dict[str, str]:
    """The truth row nearest in time."""
    return min(rows, key=lambda r: abs(float(r["t"]) - t))


def write_rebased_truth(rows: list[dict[str, str]], t_from: float, out: Path) -> dict[str, str]:
    """The truth from ``t_from`` on, east/north relative to its position then; its first row."""
    keep = [r for r in rows if float(r["t"]) >= t_from]
    e0, n0 = float(keep[0]["east_m"]), float(keep[0]["north_m"])
    with out.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in keep:
            w.writerow({**r, "east_m": f"{float(r['east_m']) - e0:.4f}",
                        "north_m": f"{float(r['north_m']) - n0:.4f}"})  # fmt: skip
    return keep[0]


def second_half_toml(base: Path, heading_deg: float, out: Path) -> None:
    """The car's TOML with ``[start]`` at the split: local (0, 0), the operator's heading."""
    text = base.read_text()
    start = f"[start]\nx_m = 0.0\ny_m = 0.0\nheading_deg = {heading_deg}\n"
    text = re.sub(r"\[start\][^\[]*", start + "\n", text, count=1)
    if "declination_deg" not in text and "enabled = false" not in text:
        text = text.replace("[compass]\n", "[compass]\ndeclination_deg = 0.0\n", 1)
    out.write_text(text)


def learn_first_half(log: Path, car: Path, truth: list[dict[str, str]], learned: Path,
                     fix_times: list[float]) -> dict[str, Any]:  # fmt: skip
    """The first half through the car's pipeline with landmark fixes at the truth; saves what
    it learned as ``guidance replay --learned`` does. What it learned, as a dict."""
    from guidance.app.config import load_config
    from guidance.app.learned_file import save_after
    from guidance.core.messages import LandmarkFix
    from guidance.core.pipeline import Pipeline
    from guidance.tools.replay import can_inputs, raw_setup

    setup = raw_setup(str(car), None, None, log)
    pcfg = setup.pipeline
    if "compass" in pcfg.expected_rates_hz:
        pcfg = pcfg.__class__(**{**_fields(pcfg), "expected_rates_hz": {
            k: v for k, v in pcfg.expected_rates_hz.items() if k != "compass"}})  # fmt: skip
    p = Pipeline(pcfg)
    fixes = []
    for i, t in enumerate(fix_times):
        r = truth_at(truth, t)
        fixes.append(LandmarkFix(float(r["t"]), 900 + i, float(r["east_m"]),
                                 float(r["north_m"]), FIX_SIGMA_M))  # fmt: skip
    last = 0.0
    for msg in heapq.merge(can_inputs(log, setup.profile), fixes, key=lambda m: m.t_s):
        p.feed(msg)
        last = msg.t_s
    vid = load_config(str(car), require_goal=False).vehicle_id
    params = save_after(p.localizer, learned, vid, last, p.estimate.odometer_m, None)
    assert params is not None, "the car model learns; the paper model has nothing to keep"
    return {"fixes_used": p.landmark_updates, "scale": params.scale,
            "scale_sigma": params.scale_sigma, "diff": params.diff,
            "diff_sigma": params.diff_sigma, "distance_m": params.distance_m}  # fmt: skip


def _fields(obj: Any) -> dict[str, Any]:
    from dataclasses import fields

    return {f.name: getattr(obj, f.name) for f in fields(obj)}


def _cli(*args: str) -> str:
    from guidance.tools.cli import main

    buf = io.StringIO()
    with redirect_stdout(buf), redirect_stderr(io.StringIO()):
        rc = main(list(args))
    if rc != 0:
        raise RuntimeError(f"guidance {' '.join(args)}: exit {rc}")
    return buf.getvalue()


def evaluate_second_half(log: Path, car: Path, truth: Path, work: Path,
                         learned: Path | None) -> dict[str, Any]:  # fmt: skip
    """``guidance replay`` then ``guidance evaluate --json``, as docs/estimation.md says."""
    track = work / "track.csv"
    extra = []
    if learned is not None:  # a copy: the replay saves what the second half learned into it
        used = work / "learned_used.json"
        used.write_bytes(learned.read_bytes())
        extra = ["--learned", str(used)]
    _cli("replay", str(log), "--config", str(car), "--track", str(track), *extra)
    ev = json.loads(_cli("evaluate", "--track", str(track), "--truth", str(truth),
                         "--json").splitlines()[-1])  # fmt: skip
    with track.open() as f:
        last = list(csv.DictReader(f))[-1]
    ev["final_major_axis_m"] = float(last["major_axis_m"])
    return dict(ev)


def run(drive: str, work: Path) -> dict[str, Any]:
    """Both halves; the figures of the second from the learned file and from the priors, at
    the operator's start heading and +-1 degree."""
    log, truth_path, car = DRIVES[drive]
    truth = read_truth(truth_path)
    t0, t1 = float(truth[0]["t"]), float(truth[-1]["t"])
    t_split = 0.5 * (t0 + t1)
    log1, log2 = work / "first.log", work / "second.log"
    split_log(log, t_split, log1, log2)
    learned = work / "learned.json"
    if learned.exists():
        learned.unlink()
    taught = learn_first_half(log1, car, truth, learned, [t0 + f * (t1 - t0) for f in FIX_AT])
    truth2 = work / "second_truth.csv"
    start = write_rebased_truth(truth, t_split, truth2)
    heading = float(round(float(start["heading_deg"])))  # the street's bearing on a map
    out: dict[str, Any] = {"drive": drive, "split_t": t_split, "learned": taught,
                           "start_heading_deg": heading, "second": {}}  # fmt: skip
    for dh in (0.0, -1.0, 1.0):
        car2 = work / "second.toml"
        second_half_toml(car, heading + dh, car2)
        row = {}
        for name, path in (("priors", None), ("learned", learned)):
            ev = evaluate_second_half(log2, car2, truth2, work, path)
            row[name] = {k: ev[k] for k in (*FIGURES, "final_major_axis_m")}
        out["second"][f"{heading + dh:.0f}"] = row
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drive", choices=sorted(DRIVES), default="berlin")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    if not DRIVES[args.drive][0].is_file():
        print(f"{DRIVES[args.drive][0]} is not present (../shared/data/realdrives)")
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        res = run(args.drive, Path(tmp))
    if args.json:
        print(json.dumps(res))
        return 0
    lt = res["learned"]
    print(f"{args.drive}: split at t = {res['split_t']:.1f}; the first half "
          f"({lt['distance_m']:.0f} m, {lt['fixes_used']} landmark fixes of {FIX_SIGMA_M} m) "
          f"learned wheel scale {100 * lt['scale']:+.2f} +- {100 * lt['scale_sigma']:.2f} %, "
          f"left/right {100 * lt['diff']:+.3f} +- {100 * lt['diff_sigma']:.3f} %")  # fmt: skip
    print(
        "second half | start heading | inside 2-sigma | mean NEES | median semi/err | "
        "along / across | final error | final 2-sigma major axis"
    )
    for hdg, row in res["second"].items():
        for name, ev in row.items():
            print(f"{name:>8} | {hdg} deg | {100 * ev['inside_2sigma_frac']:.1f} % | "
                  f"{ev['mean_nees']:.2f} | {ev['median_axis_ratio']:.2f} | "
                  f"{ev['along_nees']:.2f} / {ev['across_nees']:.2f} | "
                  f"{ev['final_error_m']:.0f} m | {ev['final_major_axis_m']:.0f} m")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
