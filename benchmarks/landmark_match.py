"""Per-frame matching cost (issue 5): a 1232x1616 frame against up to 5 candidates in <= 60 ms,
and a per-frame cost that stays flat as the database grows from 100 to 100,000 landmarks.

Run: .venv/bin/python benchmarks/landmark_match.py [--sizes 100 1000 10000 100000]

Part 1: five landmarks within 10 m of each other (distinct facade photos, 1000 ORB features
each, the database default); frames are 1232x1616 perturbed views of one of them
(``hal_sim.sim_camera``); ``Recogniser.process`` with the default settings (frame described
at <= 1024 px with 700 ORB features). Prints median and p90 and the stage split.

Part 2: databases of N landmarks at 10 per km2 (the spec's densest map; 100,000 landmarks
cover 10,000 km2), each with a full 1000-feature set (the photos cycle through a pool of 12
facades; every landmark stores its own copy, so the 100,000 file is 4 GB). Frames at random
landmarks with a 2-sigma ellipse of 50 m: the gate passes the few nearby landmarks, so the
cost must not grow with N. Prints the median per size and the ratio to the smallest.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from hal_sim.sim_camera import SimCamera, SimCameraConfig, facade
from landmark_db.features import encode_image, extract
from landmark_db.geo import Origin
from landmark_db.recognise import Recogniser
from landmark_db.store import create_db, open_db

FRAME_SIZE = (1232, 1616)  # (width, height) of the camera
ORIGIN = Origin(42.444, -76.5019)
POOL = 12


def _state_cov(sigma_m: float) -> tuple[tuple[float, float], tuple[float, float]]:
    return ((sigma_m**2, 0.0), (0.0, sigma_m**2))


def _camera(seed: int) -> SimCamera:
    """The simulated camera rendering natively at the real camera's resolution."""
    w, h = FRAME_SIZE
    return SimCamera([], seed=seed, config=SimCameraConfig(width=w, height=h))


def _frame(cam: SimCamera, seed: int) -> np.ndarray:
    return cam.view(facade(seed), 8.0)


def part1(tmp: Path, n_frames: int) -> None:
    db = create_db(tmp / "five.sqlite", ORIGIN)
    seeds = [900 + i for i in range(5)]
    for i, s in enumerate(seeds):
        db.add(f"c{i}", facade(s), x_m=2.0 * i, y_m=1.0 * i)
    db.close()
    cam = _camera(1)
    frames = [_frame(cam, seeds[k % 5]) for k in range(n_frames)]
    with open_db(tmp / "five.sqlite") as ro:
        rec = Recogniser(ro)
        times, cpu, found, ncand = [], [], 0, []
        from guidance.core.messages import CameraFrame

        for k, img in enumerate(frames):
            c0 = time.process_time()
            r = rec.process_xy(CameraFrame(10.0 * k, img), (4.0, 2.0), _state_cov(10.0))
            cpu.append(time.process_time() - c0)
            times.append(r.elapsed_s)
            found += r.landmark_id == k % 5 + 1
            ncand.append(len(r.evidence))
        # stage split on the last frame
        orb = rec.config.frame_orb.create()
        t0 = time.perf_counter()
        for _ in range(10):
            feats = extract(frames[-1], rec.config.frame_orb, orb)
        t_orb = (time.perf_counter() - t0) / 10
        photo = ro.features(1)
        assert photo is not None
        from landmark_db.matcher import PairMatcher

        pm = PairMatcher(rec.config.match)
        t0 = time.perf_counter()
        for _ in range(10):
            pm.verify(1, feats, photo)
        t_pair = (time.perf_counter() - t0) / 10
    ms = np.array(times) * 1e3
    print(
        f"part 1: {FRAME_SIZE[0]}x{FRAME_SIZE[1]} frame against {int(np.mean(ncand))} candidates,"
        f" {n_frames} frames"
    )
    print(
        f"  per frame: median {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms,"
        f" max {ms.max():.1f} ms (target <= 60 ms)"
    )
    print(
        f"  CPU time per frame (all threads, less sensitive to other load): median"
        f" {np.median(cpu) * 1e3:.1f} ms; load average {os.getloadavg()[0]:.1f} on"
        f" {os.cpu_count()} cores"
    )
    print(
        f"  stages: grey+downscale+ORB {t_orb * 1e3:.1f} ms; per candidate (kNN + ratio +"
        f" RANSAC) {t_pair * 1e3:.1f} ms"
    )
    print(f"  correct landmark verified in {found}/{n_frames} frames")


def part2(tmp: Path, sizes: list[int], density: float, n_frames: int) -> None:
    rng = np.random.default_rng(2)
    probe = create_db(tmp / "probe.sqlite", ORIGIN)
    pool = [extract(facade(700 + i), probe.orb) for i in range(POOL)]
    probe.close()
    photo = encode_image(np.zeros((8, 8), np.uint8))  # photos are not read when matching
    cam = _camera(3)
    frames = [(_frame(cam, 700 + k % POOL), k % POOL) for k in range(n_frames)]
    print(
        f"part 2: per-frame cost against database size ({density:g} landmarks per km2,"
        " 2-sigma ellipse 50 m + 20 m range)"
    )
    print(
        f"{'landmarks':>10} {'build_s':>8} {'file_MB':>8} {'median_ms':>10} {'p90_ms':>8}"
        f" {'candidates':>10} {'ratio':>6}"
    )
    base = None
    from guidance.core.messages import CameraFrame

    for n in sizes:
        side = np.sqrt(n / density) * 1000.0
        xy = rng.uniform(0.0, side, (n, 2))
        path = tmp / f"m{n}.sqlite"
        t0 = time.perf_counter()
        db = create_db(path, ORIGIN)
        for p in range(POOL):  # landmark i uses pool photo i % POOL
            idx = np.arange(p, n, POOL)
            db.add_many_precomputed(
                [(f"l{i}", float(xy[i, 0]), float(xy[i, 1])) for i in idx], pool[p], photo
            )
        db.close()
        build_s = time.perf_counter() - t0
        # ids were assigned pool by pool: map landmark index -> id
        with open_db(path) as ro:
            rec = Recogniser(ro)
            times, cands = [], []
            for k, (img, p) in enumerate(frames):
                # at a landmark that shows pool photo p, estimate off by a few metres
                i = int(rng.choice(np.arange(p, n, POOL)))
                mean = xy[i] + rng.normal(0.0, 5.0, 2)
                r = rec.process_xy(CameraFrame(100.0 * k, img), mean, _state_cov(25.0))
                times.append(r.elapsed_s)
                cands.append(len(r.candidates))
        ms = np.array(times) * 1e3
        med = float(np.median(ms))
        base = base or med
        size_mb = path.stat().st_size / 1e6
        print(
            f"{n:>10} {build_s:>8.1f} {size_mb:>8.0f} {med:>10.1f}"
            f" {np.percentile(ms, 90):>8.1f} {np.mean(cands):>10.2f} {med / base:>6.2f}"
        )
        path.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1_000, 10_000, 100_000])
    ap.add_argument("--density", type=float, default=10.0)
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads")
    with tempfile.TemporaryDirectory() as tmp:
        part1(Path(tmp), args.frames)
        part2(Path(tmp), args.sizes, args.density, args.frames)


if __name__ == "__main__":
    main()
