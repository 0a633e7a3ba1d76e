"""The first stage's cost per input, and a digest of every estimate it made (issue 37).

``Localizer.handle`` over two input streams, for four filters:

* ``recording``: the committed drive (``tests/data/replay/sim_seed3_landmarks.mcap``, 65 s,
  its decoded odometry, compass and landmark fixes), with its own recorded configuration;
* ``synthetic``: a seeded stream that reaches every branch of the filter: wheel increments
  with yaw readings at their own rate, compass readings (a magnetically disturbed stretch),
  landmark fixes (relocalising ones, used while lost), CAN gaps (dead reckoning; the long one
  loses the estimate), a clock stepped back, out-of-order and non-finite inputs, stops (a
  gyro's standstill update). The car-model filters start it from learned values
  (``Localizer.adopt``).

The filters: the recording's (``paper``: 3 states), the car model (7), the car model with a
gyro turning the heading (9), and with the wheels measuring the turn too (``both``).

Printed per case: microseconds of CPU per input (the median of ``--repeat`` runs) and a
sha256 of every estimate's bits (x, P, the verdict; each input's step). The digest is the
behaviour check when the filter's code is reorganised: run the script against two trees,
``PYTHONPATH=<tree> python benchmarks/localize_step.py``, and the digests must agree while
the times are compared side by side. Figures are for comparison in one run on one machine.

    .venv/bin/python benchmarks/localize_step.py [--repeat 7] [--json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import statistics
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from guidance.core.localize.car_model import car_model
from guidance.core.localize.gyro import GyroConfig
from guidance.core.localize.learned import LearnedParams
from guidance.core.localize.localizer import Localizer, LocalizerConfig
from guidance.core.messages import CompassHeading, LandmarkFix, WheelOdometry, YawRate
from guidance.core.pipeline_config import Input, PipelineConfig

RECORDING = Path(__file__).resolve().parents[1] / "tests/data/replay/sim_seed3_landmarks.mcap"


def recorded() -> tuple[PipelineConfig, list[Input]]:
    """The committed recording's configuration and its decoded inputs."""
    from guidance.tools.replay_mcap import mcap_inputs
    from guidance.tools.replay_session import pipeline_config_from_session

    session, inputs = mcap_inputs(RECORDING)
    return pipeline_config_from_session(session), list(inputs)


def synthetic(seed: int = 37, seconds: float = 240.0) -> list[Input]:
    """A seeded drive of ``seconds`` at 50 Hz odometry (module doc: every branch)."""
    rng = np.random.default_rng(seed)
    out: list[Input] = []
    speed = 0.0
    x = y = th = 0.0
    for k in range(1, round(seconds / 0.02) + 1):
        t = 0.02 * k
        phase = (t % 60.0) / 60.0
        speed = 0.0 if phase < 0.08 else min(12.0, speed + 0.05)  # a stop each minute
        yaw = 0.25 if 0.4 < phase < 0.5 else (-0.2 if 0.7 < phase < 0.75 else 0.0)
        d, dth = speed * 0.02, yaw * 0.02 if speed > 0 else 0.0
        x, y, th = x + d * math.cos(th + dth / 2), y + d * math.sin(th + dth / 2), th + dth
        can_gap = 100.0 < t < 102.5 or 150.0 < t < 190.0  # no wheels (the second loses it)
        if not can_gap and 200.0 < t < 200.5:  # a clock stepped back: followed after a while
            out.append(WheelOdometry(t - 5.0, d, d))
            continue
        if not can_gap:
            slip = rng.normal(0.0, 0.002, 2) * d
            half = 0.5 * 1.6 * dth
            out.append(WheelOdometry(t, d - half + slip[0], d + half + slip[1]))
        if k % 2 == 0:  # 25 Hz yaw rate
            out.append(YawRate(t + 0.001, yaw + 0.004 + rng.normal(0.0, 0.002)))
        if k % 5 == 0:  # 10 Hz compass
            off = 70.0 if 130.0 < t < 135.0 else 0.0  # a bridge's steel
            hdg = (90.0 - math.degrees(th) + off + rng.normal(0.0, 3.0)) % 360.0
            out.append(CompassHeading(t + 0.003, hdg, True))
        if k % 400 == 0:  # a landmark every 8 s, some relocalising
            far = rng.random() < 0.3
            lx, ly = x + rng.normal(0.0, 2.0), y + rng.normal(0.0, 2.0)
            out.append(LandmarkFix(t + 0.005, 1, lx + (300.0 if far else 0.0), ly, 3.0, far))
        if k % 997 == 0:  # damaged and late inputs
            out.append(WheelOdometry(t, math.nan, 0.1))
            out.append(LandmarkFix(t, 2, 1e300, 0.0, 1.0))
            out.append(WheelOdometry(t - 5.0, 0.1, 0.1))
    return out


def configs(base: PipelineConfig) -> dict[str, LocalizerConfig]:
    """The four filters of the module doc, on the recording's car."""
    car = car_model(base.estimator, calibrated=True)
    gyro = replace(car, gyro=GyroConfig())
    both = replace(car, gyro=GyroConfig(with_wheels=True))
    rates = {**base.expected_rates_hz, "odometry": 50.0}
    out = {}
    for name, est in (("paper", base.estimator), ("car", car), ("gyro", gyro), ("both", both)):
        cfg = LocalizerConfig.of(replace(base, estimator=est))
        out[name] = replace(cfg, expected_rates_hz=rates)
    return out


LEARNED = LearnedParams("bench", 0.0, 5000.0, 0.004, 0.002, 1e-4, 5e-5, 3.0, 2.0, 0.01, 0.005,
                        0.2, 0.05, 0.01, 0.005)  # fmt: skip
"""A car's learned values, adopted by the car-model filters before the synthetic drive."""


def run(config: LocalizerConfig, inputs: list[Input], digest: Any | None) -> float:
    """Every input through a fresh localizer; CPU seconds (and the estimates into ``digest``)."""
    loc = Localizer(config)
    if config.start_heading_rad is None:  # the synthetic drive: a car that learned before
        loc.adopt(LEARNED)
    start = time.process_time()
    if digest is None:
        for msg in inputs:
            loc.handle(msg)
        return time.process_time() - start
    for msg in inputs:
        step = loc.handle(msg)
        est = loc.estimator
        digest.update(est.x.tobytes() + est.P.tobytes())
        digest.update(repr((step.accepted, step.reason, len(step.moves))).encode())
    digest.update(repr((sorted(est.rejections.items()), sorted(est.accepted.items()))).encode())
    return time.process_time() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # the gaps' dead-reckoning lines, once per run
    base, rec = recorded()
    streams = {"recording": rec, "synthetic": synthetic()}
    rows = []
    for sname, inputs in streams.items():
        for cname, cfg in configs(base).items():
            if sname == "synthetic":  # from the origin, the heading from the first compass
                cfg = replace(cfg, start_xy_m=(0.0, 0.0), start_heading_rad=None)
            h = hashlib.sha256()
            run(cfg, inputs, h)
            times = [run(cfg, inputs, None) for _ in range(args.repeat)]
            us = 1e6 * statistics.median(times) / len(inputs)
            rows.append({"stream": sname, "filter": cname, "inputs": len(inputs),
                         "us_per_input": us, "digest": h.hexdigest()[:16]})  # fmt: skip
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'stream':<10} {'filter':<6} {'inputs':>7} {'us/input':>9}  digest")
    for r in rows:
        print(f"{r['stream']:<10} {r['filter']:<6} {r['inputs']:>7} {r['us_per_input']:>9.1f}"
              f"  {r['digest']}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
