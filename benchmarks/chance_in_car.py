"""The car's chance of reaching the goal against what its simulated drives then did.

The table (``guidance/core/plan/chance_table.json``) is calibrated on the study engine's trials
(``guidance study chance``); this checks the number the *car* computes and publishes, through
the full in-car stack (``guidance sim``: CAN on a virtual bus, the compass on a pseudo-terminal,
the App, its pipeline, its navigator) on drives with random conditions: method, compass (none,
or 2-sigma 10-45 degrees), landmark density (0.2-3 per km2), detection rate (0.3-1.0), city
area and goal distance. Per drive: the first chance the car published and whether it arrived.
Printed: the calibration in bins of the prediction, the Brier score against the base rate's,
and the largest gap where a bin holds at least 20 drives.

    .venv/bin/python benchmarks/chance_in_car.py [--drives 120] [--workers 2] [--seed 1]
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

METHODS = ("straight_to_goal", "landmark_to_landmark", "hybrid")


def one(args: tuple[int, int]) -> tuple[float | None, bool, dict[str, object]]:
    from hal_sim.drive import run_drive
    from hal_sim.drive_options import DriveOptions

    seed, k = args
    rng = np.random.default_rng([seed, k])
    compass = None if rng.random() < 0.1 else float(rng.uniform(10.0, 45.0))
    goal_min = float(rng.uniform(500.0, 4000.0))
    opts = DriveOptions(
        seed=int(rng.integers(1, 2**31 - 1)),
        method=METHODS[int(rng.integers(3))],
        compass_deg=compass,
        density_per_km2=float(math.exp(rng.uniform(math.log(0.2), math.log(3.0)))),
        detection_rate=float(rng.uniform(0.3, 1.0)),
        area_km2=float(rng.uniform(9.0, 40.0)),
        goal_min_m=goal_min,
        goal_max_m=goal_min + 1000.0,
        voice="none",
        png=False,
        record=False,
        telemetry=False,
        print_prompts=False,
        out=f"/tmp/chance_in_car/{k}",
    )
    r = run_drive(opts)
    cond = {
        "method": opts.method,
        "compass": compass,
        "density": round(opts.density_per_km2, 2),
        "detection": round(opts.detection_rate, 2),
        "outcome": r.outcome,
        "km": round(r.driven_km, 2),
    }
    return r.chance_at_start, r.outcome == "arrived", cond


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drives", type=int, default=120)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    t0 = time.monotonic()
    pred: list[float] = []
    real: list[float] = []
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [(args.seed, k) for k in range(args.drives)]
        for i, (p, ok, _cond) in enumerate(pool.map(one, jobs), 1):
            if p is not None:
                pred.append(p)
                real.append(float(ok))
            print(f"\r{i}/{args.drives} drives", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    P, R = np.array(pred), np.array(real)
    print(f"{len(P)} drives through the full in-car stack in {time.monotonic() - t0:.0f} s")
    print(f"arrived {R.mean():.1%}, mean predicted at the start {P.mean():.1%}")
    edges = (0.0, 0.2, 0.5, 0.8, 0.95, 1.0001)
    worst = 0.0
    print("predicted bin   drives  mean predicted  arrived  95 % (Wilson)")
    for lo, hi in itertools.pairwise(edges):
        m = (lo <= P) & (hi > P)
        n = int(m.sum())
        if not n:
            continue
        k = float(R[m].sum())
        z = 1.96
        c = (k / n + z * z / (2 * n)) / (1 + z * z / n)
        h = z * math.sqrt(k / n * (1 - k / n) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        gap = abs(P[m].mean() - R[m].mean())
        if n >= 20:
            worst = max(worst, gap)
        print(f"{lo:4.2f}-{min(hi, 1):4.2f}   {n:6d}  {P[m].mean():14.1%}  {R[m].mean():7.1%}"
              f"  [{max(0, c - h):.0%}, {min(1, c + h):.0%}]")  # fmt: skip
    brier = float(np.mean((P - R) ** 2))
    base = float(np.mean((R.mean() - R) ** 2))
    print(f"Brier score {brier:.3f} (base rate alone {base:.3f}); "
          f"largest gap in a bin of 20 or more drives: {worst * 100:.0f} points")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
