"""The matcher worker's threads beside a 100 Hz loop (issue 36): capped (one OpenCV thread,
one thread in each OpenBLAS: ``landmark_db.worker.WORKER_THREADS``) and uncapped (every pool
at its default, a thread per core), side by side in one run.

A ``RecogniserWorker`` (its own spawned process, 10 nice levels below this one, as in the
car) searches the whole database for a lost car, frame after frame (1232x1616 simulated
views of its places, ``state.lost``: the heaviest work it does: the global cosines over
every place, then up to 20 photos verified), while this process runs a 100 Hz ticker on
absolute monotonic deadlines (the app's loop shape) doing 1 ms of numpy work per tick.
Per arm: the ticker's lateness (median, p99, max), frames the worker finished per second,
the worker's CPU per frame and the cores it kept busy (its CPU time over wall time), its
threads as read back (``RecogniserWorker.scheduling``).

The database is ``benchmarks/landmark_locate.py``'s file (same builder and cache), so
``--places 10000`` measures at the size of the locate target; the default, 2000, builds in a
few minutes.

The arms alternate (``--rounds``), as the shared machine's load moves; run it at the
priority the app has (not under ``nice``: the worker lowers itself).

    python benchmarks/matcher_worker_threads.py [--places 2000] [--seconds 10] [--rounds 3]
        [--extractors rootsift xfeat]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from landmark_locate import CITY_SEED, FRAME_SIZE, build

from guidance.core.messages import CameraFrame, Ellipse, EstimateState
from hal_sim.sim_camera import SimCamera, SimCameraConfig, facade, photo_seed
from landmark_db.features import PHOTO_MAX_SIDE_PX, ExtractorConfig
from landmark_db.worker import WORKER_THREADS, RecogniserWorker

TICK_S = 0.01
LOST = EstimateState(
    0.0, 0.0, 0.0, 0.0, ((1e6, 0, 0), (0, 1e6, 0), (0, 0, 1.0)), Ellipse(2e3, 2e3, 0, 0), True,
    True,
)  # fmt: skip


def frames(n: int, pool: int, seed: int) -> list[np.ndarray]:
    cam = SimCamera([], seed, SimCameraConfig(width=FRAME_SIZE[0], height=FRAME_SIZE[1]))
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        p = int(rng.integers(pool))
        out.append(cam.view(facade(photo_seed(CITY_SEED, p)), float(rng.uniform(3.0, 15.0))))
    return out


async def ticker(stop: asyncio.Event, late_ms: list[float]) -> None:
    """100 Hz on absolute deadlines, about 1 ms of work a tick (an estimator step's order;
    element-wise numpy, no BLAS: this process's own pools are not what is measured)."""
    a = np.random.default_rng(0).normal(size=4096)
    deadline = time.monotonic()
    while not stop.is_set():
        deadline += TICK_S
        await asyncio.sleep(max(0.0, deadline - time.monotonic()))
        late_ms.append((time.monotonic() - deadline) * 1e3)
        t = time.perf_counter()
        while time.perf_counter() - t < 1e-3:
            a = np.tanh(a * 1.01)


async def arm(
    path: Path, threads: int | None, imgs: list[np.ndarray], seconds: float
) -> dict[str, list[float]]:
    with RecogniserWorker(path, threads=threads) as worker:
        await worker.process_async(CameraFrame(0.0, imgs[0], "bench"), LOST)  # loads the index
        s0 = worker.scheduling()
        stop = asyncio.Event()
        late: list[float] = []
        tick = asyncio.create_task(ticker(stop, late))
        t0 = time.monotonic()
        done = 0
        while time.monotonic() - t0 < seconds:
            img = imgs[done % len(imgs)]
            await worker.process_async(CameraFrame(0.5 * done, img, "bench"), LOST)
            done += 1
        wall = time.monotonic() - t0
        stop.set()
        await tick
        s1 = worker.scheduling()
    cpu_s = (s1["cpu_ms"] - s0["cpu_ms"]) / 1e3
    return {
        "late": late,
        "wall": [wall],
        "frames": [float(done)],
        "cpu": [cpu_s],
        "opencv": [float(s1["opencv_threads"])],
        "blas": [float(s1["blas_threads"])],
        "os_threads": [float(s1["os_threads"])],
    }


def summary(runs: list[dict[str, list[float]]]) -> dict[str, float]:
    """One arm's rounds pooled: lateness over every tick, rates over the summed time."""
    late = np.concatenate([r["late"] for r in runs])
    wall = sum(sum(r["wall"]) for r in runs)
    frames = sum(sum(r["frames"]) for r in runs)
    cpu = sum(sum(r["cpu"]) for r in runs)
    return {
        "late_med": float(np.median(late)),
        "late_p99": float(np.percentile(late, 99)),
        "late_max": float(late.max()),
        "fps": frames / wall,
        "cpu_frame": 1e3 * cpu / max(frames, 1.0),
        "cores": cpu / wall,
        "opencv": runs[-1]["opencv"][0],
        "blas": runs[-1]["blas"][0],
        "os_threads": runs[-1]["os_threads"][0],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--places", type=int, default=2000)
    ap.add_argument("--pool", type=int, default=300, help="distinct facades")
    ap.add_argument("--seconds", type=float, default=10.0, help="per arm and round")
    ap.add_argument("--rounds", type=int, default=3, help="the arms alternate, this many times")
    ap.add_argument("--extractors", nargs="+", default=["rootsift", "xfeat"])
    ap.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "urban-guidance-bench"
    )
    args = ap.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    imgs = frames(12, min(args.pool, args.places), 11)
    cols: dict[str, dict[str, float]] = {}
    for kind in args.extractors:
        ext = ExtractorConfig(kind, 1000, PHOTO_MAX_SIDE_PX[kind])
        path = args.cache / f"locate-{args.places}-{args.pool}-{ext.ident.replace('/', '_')}.sqlite"
        if not path.exists():
            print(f"building {path} ...", flush=True)
            build(path, args.places, ext, args.pool)
        arms = (("uncapped", None), ("capped", WORKER_THREADS))
        runs: dict[str, list[dict[str, list[float]]]] = {label: [] for label, _ in arms}
        for r in range(args.rounds):  # interleaved: the shared machine's load moves
            for label, threads in arms:
                runs[label].append(asyncio.run(arm(path, threads, imgs, args.seconds)))
            print(f"  {kind} round {r + 1} done", flush=True)
        for label, _ in arms:
            cols[f"{kind} {label}"] = summary(runs[label])
    print(
        f"lost-car search in a RecogniserWorker beside a 100 Hz ticker: {args.places} places,"
        f" {args.rounds} x {args.seconds:.0f} s per arm, interleaved, load average"
        f" {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(f"{'':<34}" + "".join(f"{k:>19}" for k in cols))
    rows = [
        ("ticker lateness median ms", "late_med", "{:.2f}"),
        ("ticker lateness p99 ms", "late_p99", "{:.2f}"),
        ("ticker lateness max ms", "late_max", "{:.1f}"),
        ("worker frames per s", "fps", "{:.2f}"),
        ("worker CPU ms per frame", "cpu_frame", "{:.0f}"),
        ("worker cores busy (CPU / wall)", "cores", "{:.2f}"),
        ("worker OpenCV threads", "opencv", "{:.0f}"),
        ("worker BLAS threads (largest)", "blas", "{:.0f}"),
        ("worker OS threads", "os_threads", "{:.0f}"),
    ]
    for name, key, fmt in rows:
        print(f"{name:<34}" + "".join(f"{fmt.format(c[key]):>19}" for c in cols.values()))


if __name__ == "__main__":
    main()
