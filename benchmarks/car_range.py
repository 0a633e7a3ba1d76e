"""Fig. 3's question for a population of real cars, uncalibrated and calibrated (issue 21, item 5).

Each car of ``hal_sim.population`` drives random routes through the car's real pipeline until it
declares itself lost (2-sigma major axis over 100 m) or reaches the cap, in four conditions
(``hal_sim.car_range``): odometry only or with its compass, each uncalibrated (the car model's
priors) and calibrated (the learned parameters of a first 3 km drive with landmark fixes, and
with a compass its deviation card). Prints the table and writes a figure beside fig3: the
major axis against distance, per car and the median, with the paper model's mean lost
distances (docs/simulation.md) marked for reference.

    .venv/bin/python benchmarks/car_range.py [--cars 100] [--seed 1] [--cap-km 20] [--out DIR]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hal_sim.car_range import (
    PAPER_LOST_KM,
    TABLE_HEADER,
    RangeFigures,
    median_axis_curve,
    range_study,
)


def figure(figs: list[RangeFigures], path: Path, cars: int, seed: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6), dpi=110)
    colours = plt.get_cmap("tab10")
    d_km = np.geomspace(0.02, max(f.cap_km for f in figs), 200)
    x_max = max(d_km[-1], 1.2 * max(PAPER_LOST_KM.values()))
    for i, f in enumerate(figs):
        col = colours(i)
        for r in f.results:
            if r.axis_m:
                a = np.asarray(r.axis_m)
                ax.plot(a[:, 0] / 1000, a[:, 1], color=col, alpha=0.08, linewidth=0.6)
        ax.plot(d_km, median_axis_curve(f.results, d_km), color=col, linewidth=2.2,
                label=f"{f.label}: mean lost {f.mean_km:.2f} km")  # fmt: skip
    for j, (label, km) in enumerate(PAPER_LOST_KM.items()):
        ax.axvline(km, color="grey", linestyle=":", linewidth=1.2 + 0.4 * j,
                   label=f"{label}: mean lost {km:.2f} km (fig3)")  # fmt: skip
    ax.axhline(100.0, color="black", linestyle="--", linewidth=1.2, label="lost: 100 m")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(d_km[0], x_max)
    ax.set_ylim(1, 1000)
    ax.set_xlabel("Distance driven along the streets, km")
    ax.set_ylabel("Major axis of the 2σ position ellipse, m")
    ax.set_title(f"Range of real cars (car model, {cars} cars, draw seed {seed}): "
                 "thin per car, thick median", fontsize=10)  # fmt: skip
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cars", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1, help="draws the cars (default 1)")
    ap.add_argument("--cap-km", type=float, default=20.0, help="a car never lost stops here")
    ap.add_argument("--out", type=Path, default=Path("out/car_range"), help="figure folder")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    t0 = time.monotonic()
    figs = range_study(args.cars, args.seed, 1000.0 * args.cap_km)
    wall = time.monotonic() - t0
    print(f"{args.cars} simulated cars (draw seed {args.seed}), each driven until lost (2-sigma "
          f"major axis > 100 m) or {args.cap_km:g} km; {wall:.1f} s wall")  # fmt: skip
    print(TABLE_HEADER)
    for f in figs:
        print(f.row())
    for label, km in PAPER_LOST_KM.items():
        print(f"| {label} (fig3, white noise, no persistent errors) | {km:.2f} km | | | | |")
    args.out.mkdir(parents=True, exist_ok=True)
    png = args.out / "car_range.png"
    figure(figs, png, args.cars, args.seed)
    print(f"figure: {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
