"""Guidance against the truth: random simulated trips, every spoken manoeuvre checked.

Each trip draws a city seed, a method, the co-driver's report distance (30, 100 or 250 m, or a
keyboard co-driver who reports each intersection right after the previous one with no
distance), a landmark density and sometimes a CAN dropout, drives it through the car's
pipeline (``hal_sim.guided``) and checks it with the truth oracle (``hal_sim.oracle``): the
wrong-instruction rate, prompts per km, spoken distances, the announcement margin before each
turn, repeats. Target: 0 wrong.

    .venv/bin/python benchmarks/guidance_truth.py [--trips 200] [--seed 1] [--show 10]

The trips are drawn from ``--seed`` (not the shared drives' seeds), so a run is reproducible.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hal_sim.drive_options import DriveOptions
from hal_sim.guided import guided_drive
from hal_sim.oracle import CheckResult

METHODS = ("straight_to_goal", "landmark_to_landmark", "hybrid")


def draw(rng: np.random.Generator) -> tuple[DriveOptions, bool, str]:
    """One random trip: its options, whether the co-driver types, and a label."""
    codriver = bool(rng.random() < 0.2)
    dist = float(rng.choice([30.0, 100.0, 250.0]))
    method = str(rng.choice(METHODS))
    density = float(rng.choice([0.0, 1.0, 5.0]))
    fault = None
    if rng.random() < 0.15:
        fault = (float(rng.uniform(20.0, 120.0)), float(rng.uniform(2.0, 6.0)))
    opts = DriveOptions(
        seed=int(rng.integers(10_000, 2**31)),
        method=method,
        density_per_km2=density,
        decision_distance_m=dist,
        can_silent=fault,
    )
    who = "co-driver" if codriver else f"{dist:.0f} m"
    label = f"seed {opts.seed} {method} {who} {density:.0f}/km2"
    if fault:
        label += f" CAN off {fault[0]:.0f}+{fault[1]:.1f} s"
    return opts, codriver, label


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trips", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1, help="draws the trips (default 1)")
    ap.add_argument("--show", type=int, default=10, help="findings to list (default 10)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)  # a CAN dropout's warnings are expected here
    rng = np.random.default_rng(args.seed)
    total: CheckResult | None = None
    outcomes: Counter[str] = Counter()
    bad: list[str] = []
    t0 = time.monotonic()
    for i in range(args.trips):
        opts, codriver, label = draw(rng)
        trip = guided_drive(opts, codriver=codriver)
        res = trip.check()
        outcomes[trip.outcome] += 1
        if not res.ok(min_distance_frac=0.0):
            bad.append(
                f"{label}: {len(res.wrong)} wrong, {len(res.late)} late, "
                f"{len(res.unannounced)} unannounced, {len(res.repeats)} repeats"
            )
        if total is None:
            total = res
        else:
            total.merge(res)
        done = i + 1
        if done % 10 == 0 or done == args.trips:
            print(f"\r{done}/{args.trips} trips, {time.monotonic() - t0:.0f} s", end="",
                  file=sys.stderr, flush=True)  # fmt: skip
    print(file=sys.stderr)
    assert total is not None
    print(f"guidance against the truth: {args.trips} random trips (draw seed {args.seed}), "
          f"{time.monotonic() - t0:.1f} s wall")  # fmt: skip
    print("outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())))
    print(total.summary())
    print(f"WRONG-INSTRUCTION RATE: {100 * total.wrong_rate:.2f} % "
          f"({len(total.wrong)} of {total.manoeuvres_checked} spoken manoeuvres)")  # fmt: skip
    for line in bad[: args.show]:
        print("  trip: " + line)
    return 0 if total.ok() else 1


if __name__ == "__main__":
    raise SystemExit(main())
