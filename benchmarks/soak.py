"""Soak: two simulated hours of the full in-car stack, accelerated (issue 7).

One ``guidance sim`` drive under the field protocol (a new random goal at each
arrival) for ``--hours`` simulated hours, in this process: CAN frames on the
python-can virtual bus through the real driver, NMEA through a pseudo-terminal,
the estimator, navigator, Zenoh telemetry on loopback and MCAP recording with
rotation. A thread samples this process's resident memory.

Prints memory at the start (after the first simulated 5 minutes, once every
library is loaded and every buffer has filled) and at the end, their ratio
(target: growth under 10 %), and the loop-lag percentiles the app measured.

    .venv/bin/python benchmarks/soak.py [--hours 2] [--seed 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hal_sim.drive import DriveOptions, run_drive

PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE / 2**20


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=2.0, help="simulated hours (default 2)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--warm-up-min", type=float, default=5.0, help="start of the memory baseline")
    args = ap.parse_args()

    samples: list[tuple[float, float]] = []  # (simulated s, RSS MiB)
    baseline: list[float] = []
    wall0 = time.monotonic()

    def progress(t_s: float) -> None:
        rss = rss_mib()
        samples.append((t_s, rss))
        if not baseline and t_s >= 60.0 * args.warm_up_min:
            baseline.append(rss)
        if int(t_s) % 1200 < 60:
            wall = time.monotonic() - wall0
            print(f"  t={t_s / 60:5.0f} min  RSS {rss:7.1f} MiB  wall {wall:5.0f} s", flush=True)

    peak = [0.0]
    stop = threading.Event()

    def watch() -> None:
        while not stop.wait(0.5):
            peak[0] = max(peak[0], rss_mib())

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    with tempfile.TemporaryDirectory() as out:
        opts = DriveOptions(
            seed=args.seed,
            method="hybrid",
            compass_deg=20.0,
            density_per_km2=2.0,
            duration_s=args.hours * 3600.0,
            voice="none",
            png=False,
            out=out,
            print_prompts=False,
        )
        print(f"soak: {args.hours:g} simulated hours, seed {args.seed}, full stack", flush=True)
        result = run_drive(opts, None, None, progress)
        files = len(result.recording)
    stop.set()
    watcher.join()
    end = rss_mib()
    start = baseline[0] if baseline else samples[0][1]
    lag = result.loop_lag_ms
    print(f"simulated {result.sim_s / 3600:.2f} h in {result.wall_s:.0f} s wall "
          f"({result.sim_s / result.wall_s:.0f}x real time)")  # fmt: skip
    print(f"drove {result.driven_km:.1f} km, {result.goals_reached} goals reached, "
          f"{result.decisions} decisions, {result.prompts} prompts, "
          f"{result.landmark_updates} landmark updates, {files} recording files")  # fmt: skip
    print(f"memory: start {start:.1f} MiB (at {args.warm_up_min:g} min), end {end:.1f} MiB, "
          f"peak {peak[0]:.1f} MiB")  # fmt: skip
    growth = end / start - 1.0
    print(f"memory growth: {growth:+.1%} (target < 10%)")
    print(
        "loop lag (last samples): "
        + ", ".join(
            f"{k.removeprefix('loop_lag_')} {v:.2f}" for k, v in lag.items() if v is not None
        )
    )
    return 0 if growth < 0.10 else 1


if __name__ == "__main__":
    sys.exit(main())
