"""Gated candidate query time against database size (issue 5: <= 1 ms at 100,000 landmarks).

Run: .venv/bin/python benchmarks/landmark_query.py [--sizes 100 1000 10000 100000]

For each size, landmarks are spread uniformly at a constant density (default 10 per km2,
the spec's densest map, so 100,000 landmarks cover 10,000 km2: a region, not a city), and
also packed into one 100 km2 city (1,000 per km2, the worst case for the number of boxes
the R*Tree returns). Each query is ``landmark_db.store.query_gate``: R*Tree box, then the
exact ellipse-plus-range test, for a random 2-sigma ellipse (semi-axes 10-100 m, any
orientation) plus the 20 m sighting range at a random position. Prints median and p99.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from guidance.core.geo import Origin
from landmark_db.features import Features
from landmark_db.store import LandmarkDb, create_db, open_db, query_gate

RANGE_M = 20.0
QUERIES = 2000


def build(path: Path, xy: np.ndarray) -> None:
    """A database of ``xy`` landmarks with a placeholder photo (queries never read it)."""
    db = create_db(path, Origin(42.444, -76.5019))
    dummy = Features(np.zeros((1, 6), np.float32), np.zeros((1, 32), np.uint8), 1, 1)
    step = 10_000
    for k in range(0, len(xy), step):
        rows = [(f"l{k + i}", float(x), float(y)) for i, (x, y) in enumerate(xy[k : k + step])]
        db.add_many_precomputed(rows, dummy, b"placeholder")
    db.close()


def bench(db: LandmarkDb, side_m: float, rng: np.random.Generator) -> tuple[float, float, float]:
    """(median ms, p99 ms, mean candidates) over QUERIES random gated queries."""
    times = np.empty(QUERIES)
    found = 0
    for i in range(QUERIES):
        mean = rng.uniform(0.0, side_m, 2)
        a, b = rng.uniform(10.0, 100.0), rng.uniform(10.0, 100.0)
        ang = rng.uniform(0.0, math.pi)
        c, s = math.cos(ang), math.sin(ang)
        rot = np.array([[c, -s], [s, c]])
        cov = rot @ np.diag([(a / 2) ** 2, (b / 2) ** 2]) @ rot.T
        cov_t = ((cov[0, 0], cov[0, 1]), (cov[1, 0], cov[1, 1]))
        t0 = time.perf_counter()
        cands = query_gate(db, mean, cov_t, RANGE_M)
        times[i] = time.perf_counter() - t0
        found += len(cands)
    return float(np.median(times) * 1e3), float(np.percentile(times, 99) * 1e3), found / QUERIES


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1_000, 10_000, 100_000])
    ap.add_argument("--density", type=float, default=10.0, help="landmarks per km2")
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    print(f"gated query (R*Tree + exact gate), {QUERIES} queries per row, range {RANGE_M} m")
    print(f"{'landmarks':>10} {'layout':>22} {'median_ms':>10} {'p99_ms':>8} {'candidates':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            layouts = [(f"{args.density:g}/km2", math.sqrt(n / args.density) * 1000.0)]
            if n >= 10_000:
                layouts.append(("100 km2 city", 10_000.0))
            for label, side in layouts:
                path = Path(tmp) / f"q{n}_{int(side)}.sqlite"
                build(path, rng.uniform(0.0, side, (n, 2)))
                with open_db(path) as db:
                    med, p99, cands = bench(db, side, rng)
                print(f"{n:>10} {label:>22} {med:>10.3f} {p99:>8.3f} {cands:>10.2f}")
                path.unlink()
    print("target: median <= 1 ms at 100,000 landmarks")


if __name__ == "__main__":
    main()
