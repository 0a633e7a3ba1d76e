"""The matcher in a process of its own, beside the car's 100 Hz loop (issue 23, item 9;
issue 36): ``RecogniserWorker`` runs a ``Recogniser`` in one spawned process at a lower
priority than the app, with its thread pools capped (``landmark_db.threads``), so the camera
never competes with the loop for both cores.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Mapping
from concurrent.futures import Future, ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from guidance.core.messages import CameraFrame, EstimateState
from landmark_db.recognise import Recogniser, RecogniserConfig, RecognitionResult
from landmark_db.store import open_db
from landmark_db.threads import blas_threads, cap_threads

# --- worker process --------------------------------------------------------------------------

_worker: Recogniser | None = None


WORKER_NICE_LEVELS = 10
"""The matcher worker runs this many nice levels below the app that starts it (issue 23,
item 9): the loop then weighs about 9 times the matcher with the scheduler (1.25 a level)."""


def lower_priority(levels: int = WORKER_NICE_LEVELS) -> str:
    """Make this process background work: ``levels`` nice levels below what it inherited
    (the app's: -10 under the car's systemd unit, so 0 there), at most 19.

    Matching must never delay the odometry loop, but must not starve either: under the
    unit the worker is level with the laptop's other programs, and the loop above them all.
    ``SCHED_IDLE`` (used before) gives way to every other program: beside one CPU-bound
    process on a busy 2-core machine the worker got no CPU at all (0 matches in 3 s, the
    first one minutes late), so a busy laptop meant no landmark fixes. Raising one's own
    nice value needs no privilege."""
    if os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK in (os.SCHED_RR, os.SCHED_FIFO):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # never real-time
    nice = min(19, os.getpriority(os.PRIO_PROCESS, 0) + levels)
    os.setpriority(os.PRIO_PROCESS, 0, nice)
    return f"nice {nice}"


WORKER_THREADS = 1
"""Threads in the matcher worker (issue 23, item 9; issue 36): one for OpenCV and one for
every BLAS (``landmark_db.threads.cap_threads``). Their defaults (a thread per core) spread
each match over every core, the loop's included: numpy's OpenBLAS for the XFeat cosines and
the whole-database search, OpenCV's own OpenBLAS for its DNN (XFeat), OpenCV's pool for the
rest. The matcher is one process working one frame at a time, and a frame it cannot take is
overwritten anyway."""
WORKER_OPENCV_THREADS = WORKER_THREADS
"""The OpenCV part of ``WORKER_THREADS`` (the name issue 23 gave it)."""


def worker_setup(threads: int | None = WORKER_THREADS) -> str:
    """The matcher worker's own setup, before any matching: a lower priority than the app's
    (``lower_priority``) and its thread pools capped at ``threads`` (None: left at their
    defaults, for the side-by-side benchmark only). Threads started later inherit the
    priority. Returns the priority taken."""
    taken = lower_priority()
    if threads is not None:
        cap_threads(threads)
    return taken


def worker_scheduling() -> dict[str, int]:
    """How the calling process is scheduled: its policy (``os.SCHED_*``), nice level, OpenCV
    thread count, the largest thread count of its BLAS libraries (``blas_threads``, 0 when
    none is loaded), its OS threads (``os_threads``, idle pool threads included) and the CPU
    time it has used (``cpu_ms``, every thread); run in the worker by
    ``RecogniserWorker.scheduling``."""
    import cv2

    try:
        os_threads = len(os.listdir("/proc/self/task"))
    except OSError:
        os_threads = 0
    return {
        "policy": os.sched_getscheduler(0),
        "nice": os.getpriority(os.PRIO_PROCESS, 0),
        "opencv_threads": int(cv2.getNumThreads()),
        "blas_threads": max(blas_threads().values(), default=0),
        "os_threads": os_threads,
        "cpu_ms": round(time.process_time() * 1e3),
    }


def _worker_init(path: str, config: RecogniserConfig | None, threads: int | None) -> None:
    global _worker
    worker_setup(threads)
    _worker = Recogniser.from_path(path, config)


def _worker_process(frame: CameraFrame, state: EstimateState) -> RecognitionResult:
    assert _worker is not None, "worker not initialised"
    return _worker.process(frame, state)


def _worker_stats() -> dict[str, int]:
    assert _worker is not None, "worker not initialised"
    return dict(_worker.stats())


class RecogniserWorker:
    """A ``Recogniser`` in its own process, for when the GIL must not be shared at all.

    One worker process (spawned, so no locks are inherited) opens the database read-only;
    frames are pickled to it. Its thread pools are capped at ``threads`` (``WORKER_THREADS``;
    None leaves them at a thread per core, for the side-by-side benchmark). ``process``
    returns a future; ``process_async`` awaits it. The worker's temporal state persists
    between calls, as in-process.
    """

    def __init__(
        self,
        db_path: str | Path,
        config: RecogniserConfig | None = None,
        threads: int | None = WORKER_THREADS,
    ) -> None:
        open_db(db_path, readonly=True).close()  # fail here, with a clear message, if bad
        self._pool = ProcessPoolExecutor(
            max_workers=1,
            mp_context=get_context("spawn"),
            initializer=_worker_init,
            initargs=(str(db_path), config, threads),
        )

    def process(self, frame: CameraFrame, state: EstimateState) -> Future[RecognitionResult]:
        return self._pool.submit(_worker_process, frame, state)

    async def process_async(self, frame: CameraFrame, state: EstimateState) -> RecognitionResult:
        return await asyncio.wrap_future(self.process(frame, state))

    def stats(self) -> Mapping[str, int]:
        return self._pool.submit(_worker_stats).result()

    def scheduling(self) -> dict[str, int]:
        """The worker's scheduling (``worker_scheduling``): background, one OpenCV thread and
        one BLAS thread."""
        return self._pool.submit(worker_scheduling).result()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> RecogniserWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
