"""The estimator's honesty over a population of simulated cars (issue 21, hal_sim/population.py).

Each car has its own wheel-scale and left/right errors, compass offset, hard-iron curve and
drift, and start errors, drawn heavier-tailed than the filter's priors; it drives 1.5 km of
random route through the car's real pipeline with the uncalibrated car model. Prints the
figures over the population and the worst cars.

    .venv/bin/python benchmarks/estimator_population.py [--cars 500] [--compass] [--seed 1]
        [--matched] [--diff-walk 1e-10] [--landmarks 1.0]
    .venv/bin/python benchmarks/estimator_population.py --learned [--cars 200]
    .venv/bin/python benchmarks/estimator_population.py --limit
    .venv/bin/python benchmarks/estimator_population.py --compass --vs-odometry
        [--distance 3000] [--hard-iron 0.6,0.9]

``--learned``: each car first drives 3 km with landmark fixes (40 per km^2, 60 % seen) and
learns; its next drive (another route, no landmarks, a day later) from what it learned and
from the priors, both printed (issue 21, item 3). ``--limit``: the purely persistent limit
(``population.persistent_limit``), no cars driven. ``--vs-odometry`` (with ``--compass``):
each car drives its route twice, with its compass and without, and the two final errors are
compared car by car (does the compass bring the estimate nearer the truth?); ``--hard-iron``
draws the cars' hard-iron ratio from another range (default 0,0.4).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hal_sim.car_errors import HARD_IRON, draw_car, draw_matched_car, t4_draw, with_camber
from hal_sim.population import CarResult, drive_car, learn_then_drive, persistent_limit, population


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cars", type=int, default=500)
    ap.add_argument("--compass", action="store_true", help="with each car's uncalibrated compass")
    ap.add_argument("--seed", type=int, default=1, help="draws the cars (default 1)")
    ap.add_argument("--worst", type=int, default=5, help="worst cars to list")
    ap.add_argument("--learned", action="store_true", help="a second drive from what it learned")
    ap.add_argument(
        "--matched",
        action="store_true",
        help="cars drawn from the filter's own Gaussian priors (the yardstick)",
    )
    ap.add_argument("--diff-walk", type=float, default=0.0, metavar="VAR_PER_M",
                    help="each car's left/right difference walks along the road at this variance "
                         "per metre (the filter's own: 1e-10; default 0, constant)")  # fmt: skip
    ap.add_argument("--camber", action="store_true",
                    help="each car's left/right difference also changes from street to street "
                         "(car_errors.with_camber: a Gauss-Markov process, 0.005-0.03 %%, "
                         "150-400 m)")  # fmt: skip
    ap.add_argument("--landmarks", type=float, default=0.0, metavar="PER_KM2",
                    help="landmark fixes where the city has landmarks at this density, 60 %% "
                         "seen (the product's operating mode; default 0: none)")  # fmt: skip
    ap.add_argument("--turn-scale", type=float, default=None, metavar="SCALE",
                    help="each car's turn scale error t4 x SCALE instead of the population's "
                         "(within +-8 %%, drawn apart from the other errors; 0: none)")  # fmt: skip
    ap.add_argument("--distance", type=float, default=1500.0, metavar="M",
                    help="each car's drive (default 1500 m)")  # fmt: skip
    ap.add_argument("--hard-iron", type=_range, default=HARD_IRON, metavar="LO,HI",
                    help="the cars' hard-iron ratio, uniform in LO-HI of the earth's horizontal "
                         "field (default 0,0.4)")  # fmt: skip
    ap.add_argument("--vs-odometry", action="store_true",
                    help="with --compass: each car also without its compass, the final errors "
                         "compared car by car")  # fmt: skip
    ap.add_argument("--limit", action="store_true",
                    help="print the purely persistent limit (no cars driven): what a Gaussian "
                         "filter can promise when each car's error is one draw")  # fmt: skip
    args = ap.parse_args(argv)
    if args.vs_odometry and not args.compass:
        ap.error("--vs-odometry compares the compass with odometry only: add --compass")
    logging.basicConfig(level=logging.ERROR)
    rng = np.random.default_rng(args.seed)
    t0 = time.monotonic()
    if args.limit:
        return _limit(rng)
    if args.learned:
        return _learned(args, rng, t0)
    results, plain = [], []
    draw = draw_matched_car if args.matched else partial(draw_car, hard_iron=args.hard_iron)
    turn_rng = np.random.default_rng([args.seed, 7])
    camber_rng = np.random.default_rng([args.seed, 8])
    for i in range(args.cars):
        car = replace(draw(rng), diff_walk_var_per_m=args.diff_walk)
        if args.camber:
            car = with_camber(car, camber_rng)
        if args.turn_scale is not None:
            kt = t4_draw(turn_rng, args.turn_scale, 0.08) if args.turn_scale else 0.0
            car = replace(car, turn_scale=kt)
        drive = partial(drive_car, 10_000 + i, car, landmarks_per_km2=args.landmarks,
                        distance_m=args.distance)  # fmt: skip
        results.append(drive(compass=args.compass))
        if args.vs_odometry:
            plain.append(drive(compass=False))
        if (i + 1) % 25 == 0 or i + 1 == args.cars:
            print(f"\r{i + 1}/{args.cars} cars, {time.monotonic() - t0:.0f} s", end="",
                  file=sys.stderr, flush=True)  # fmt: skip
    print(file=sys.stderr)
    mode = "wheel odometry + uncalibrated compass" if args.compass else "wheel odometry only"
    if args.matched:
        mode += ", cars drawn from the filter's own priors"
    if args.camber:
        mode += ", left/right changing from street to street"
    if args.diff_walk:
        mode += f", left/right walking {args.diff_walk:g} per m"
    if args.turn_scale is not None:
        mode += f", turn scale errors t4 x {100 * args.turn_scale:g} %"
    if args.landmarks:
        mode += f", landmark fixes at {args.landmarks:g} per km^2 (60 % seen)"
    if args.hard_iron != HARD_IRON:
        mode += f", hard iron {args.hard_iron[0]:g}-{args.hard_iron[1]:g} of the earth's field"
    print(f"{args.cars} simulated cars, {mode}, {args.distance:.0f} m each, draw seed "
          f"{args.seed}, {time.monotonic() - t0:.1f} s wall")  # fmt: skip
    print(population(results).summary())
    if plain:
        _vs_odometry(results, plain)
    for r in sorted(results, key=lambda r: r.inside)[: args.worst]:
        e = r.errors
        print(f"  worst: inside {100 * r.inside:.0f} %, scale {100 * e.scale:+.2f} %, left/right "
              f"{100 * e.diff:+.3f} %, start heading {e.start_heading_deg:+.1f} deg, "
              f"final error {r.final_error_m:.0f} m")  # fmt: skip
    return 0


def _vs_odometry(with_compass: list[CarResult], without: list[CarResult]) -> None:
    a = np.array([r.final_error_m for r in with_compass])
    b = np.array([r.final_error_m for r in without])
    print("the same cars without their compass:\n  "
          + population(without).summary().replace("\n", "\n  "))  # fmt: skip
    print(f"final error, car by car: median {np.median(b):.0f} m odometry only, "
          f"{np.median(a):.0f} m with the compass (mean {b.mean():.0f} / {a.mean():.0f} m); "
          f"the compass nearer the truth for {100 * np.mean(a < b):.0f} % of the cars, "
          f"median ratio {np.median(a / np.maximum(b, 1e-9)):.2f}")  # fmt: skip


def _range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected LO,HI, e.g. 0.6,0.9") from None
    if not 0.0 <= lo <= hi < 1.0:
        raise argparse.ArgumentTypeError(f"{text!r}: need 0 <= LO <= HI < 1")
    return lo, hi


def _limit(rng: np.random.Generator) -> int:
    print("each car's error one persistent 2-D draw, unit variance per axis, 2,000,000 cars:")
    for name, df in (("Gaussian", None), ("Student t4", 4.0)):
        lim = persistent_limit(rng, 2_000_000, df=df)
        print(f"  {name}: {100 * lim.outside_matched:.1f} % of cars outside a matched 2-sigma "
              f"ellipse; 5 % outside needs {lim.inflation_for:.2f}x the variance, mean NEES "
              f"then {lim.nees_then:.2f} (honest: 2)")  # fmt: skip
    return 0


def _learned(args: argparse.Namespace, rng: np.random.Generator, t0: float) -> int:
    runs = []
    for i in range(args.cars):
        runs.append(learn_then_drive(10_000 + i, draw_car(rng), compass=args.compass))
        print(f"\r{i + 1}/{args.cars} cars, {time.monotonic() - t0:.0f} s", end="",
              file=sys.stderr, flush=True)  # fmt: skip
    print(file=sys.stderr)
    wall = time.monotonic() - t0
    print(f"{args.cars} simulated cars, draw seed {args.seed}: a 3 km drive with landmark "
          f"fixes, then another route a day later without; {wall:.1f} s wall")  # fmt: skip
    scale = [100 * r.first.learned.scale_sigma for r in runs if r.first.learned is not None]
    print(f"learned wheel-scale sigma: median {np.median(scale):.2f} % (prior 2 %)")
    for name, res in (("from the priors", [r.from_priors for r in runs]),
                      ("from what it learned", [r.from_learned for r in runs])):  # fmt: skip
        axis = np.median([r.final_major_axis_m for r in res])
        print(f"second drive {name}: median final 2-sigma major axis {axis:.0f} m")
        print("  " + population(res).summary().replace("\n", "\n  "))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
