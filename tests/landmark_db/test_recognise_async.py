"""Matching runs off the event loop: a 10 ms ticker keeps ticking while a big frame is matched."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import cv2
import numpy as np

from guidance.core.geo import Origin
from guidance.core.messages import CameraFrame, Ellipse, EstimateState
from hal_sim.sim_camera import SimLandmark, facade
from landmark_db.features import OrbConfig
from landmark_db.recognise import Recogniser, RecogniserConfig, recognise_async
from landmark_db.store import create_db

TICK_S = 0.010
MAX_LAG_S = 0.100


def _state(x: float, y: float) -> EstimateState:
    c = ((400.0, 0.0, 0.0), (0.0, 400.0, 0.0), (0.0, 0.0, 0.01))
    return EstimateState(0.0, x, y, 0.0, c, Ellipse(40.0, 40.0, 0.0, 80.0), False, True)


def test_event_loop_keeps_ticking_while_a_big_frame_is_matched(
    tmp_path: Path, sim_db_path: tuple[Path, list[SimLandmark]]
) -> None:
    # Five candidates around the origin. Work is made heavier than the defaults (more
    # features) so that one match takes longer than MAX_LAG_S: matching on the loop fails.
    db = create_db(tmp_path / "five.sqlite", Origin(0.0, 0.0), OrbConfig(n_features=2000))
    for i in range(5):
        db.add(f"c{i}", facade(500 + i), x_m=3.0 * i, y_m=0.0)
    big = cv2.resize(facade(502), (1232, 1616))  # the camera's full resolution
    rec = Recogniser(db, RecogniserConfig(frame_orb=OrbConfig(n_features=5000, max_side_px=1616)))
    # As the car does before its loop starts (App.running): the numba functions the gate
    # shares with the core are loaded now. Loading them holds the GIL for a few hundred ms, so
    # without it the first match stalled the loop whenever this test ran first in a process.
    from guidance.core.warmup import warm_up

    warm_up()
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # a match on one core, the loop on the other (2-core machine)

    async def main() -> tuple[float, int, list[float]]:
        lags: list[float] = []
        done = asyncio.Event()

        async def ticker() -> None:
            deadline = time.monotonic()
            while not done.is_set():
                deadline += TICK_S
                await asyncio.sleep(max(0.0, deadline - time.monotonic()))
                lags.append(time.monotonic() - deadline)

        async with asyncio.TaskGroup() as tg:
            tg.create_task(ticker())
            results = []
            for k in range(3):
                frame = CameraFrame(0.5 * k, big)
                results.append(await recognise_async(rec, frame, _state(0.0, 0.0)))
            done.set()
        fixes = sum(r.fix is not None for r in results)
        assert all(len(r.evidence) == 5 for r in results)
        assert all(r.landmark_id is not None for r in results), [r.reason for r in results]
        return max(lags), fixes, [r.elapsed_s for r in results]

    try:
        worst, fixes, elapsed = asyncio.run(main())
    finally:
        cv2.setNumThreads(threads)
    db.close()
    assert fixes == 1  # confirmed on the second frame, then held off (one fix per pass)
    # Relative to the work itself, so the check holds on fast and slow machines alike: a
    # match run on the loop would stall it for a whole match; off the loop, the ticker is
    # never late by half of one (nor by more than MAX_LAG_S).
    assert worst < min(MAX_LAG_S, 0.5 * float(np.median(elapsed))), (
        f"event loop stalled {worst * 1000:.0f} ms; a match takes "
        f"{np.median(elapsed) * 1000:.0f} ms"
    )
    assert np.median(elapsed) > 4 * TICK_S  # heavy enough to have stalled several ticks
