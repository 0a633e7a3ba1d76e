"""Back-pressure from the CAN reader (issue 14, item 10), with the real App, the real CanOdometry
on a python-can virtual bus and a sender blasting wheel-speed frames as fast as it can (about
20,000 frames/s asked for; what the machine manages is measured).

Before: every increment was one callback on the loop (78k queued for 10 s at 20,000 frames/s,
1-15 s loop lag, false "odometry silent"). Now the reader folds increments together while the
loop has more than ``BACKLOG_LIMIT`` messages unprocessed: the queue stays bounded, no distance
is lost, and the loop stays on time.

Honest under load (issue 40: it failed once in a full ``make test`` at load 8): the claims
about time (the loop's lag, no false "odometry silent") are judged against what the machine
did, measured, not assumed. Each thread's run-queue wait (``/proc/self/task/TID/schedstat``:
the time it was ready to run and the kernel ran something else) and the sender's own send
times are recorded; a lag is the app's only beyond what the kernel withheld from the loop's
thread or, through the GIL, from any thread of the process, and "silent" is false only while
frames were being sent and neither the reader nor the loop was held off the CPU. On an idle
machine the waits are a few ms and the bounds are the old ones.
"""

from __future__ import annotations

import asyncio
import bisect
import itertools
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager

import can
import pytest

from drivers._reader import BACKLOG_LIMIT
from drivers.can_decode import MAX_GAP_S
from drivers.can_odometry import CanOdometry, CanOdometryConfig
from guidance.app.app import App
from guidance.app.settings import LoopSettings
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import WheelOdometry
from guidance.core.pipeline import Outputs, Pipeline, PipelineConfig
from guidance.core.plan.navigator import Method, NavigatorConfig
from hal_sim.sim_can import SimCanWheels

SPEED_MPS = 10.0
BLAST_S = 10.0
"""As long as the flood measured in issue 14 (20,000 frames/s for 10 s)."""
RATE_HZ = 20_000.0


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    with leak_check(grace_s=3.0, ignore_threads=("asyncio_",), ptys=False):
        yield


def _run_delay_s(tid: int) -> float:
    """Seconds thread ``tid`` of this process has waited on a run queue (ready, not running)."""
    try:
        with open(f"/proc/self/task/{tid}/schedstat") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        return 0.0


def _blast(
    channel: str, stop: threading.Event, sent: list[int], when: list[float], tids: list[int]
) -> None:
    """Send the wheels' frames back to back at up to RATE_HZ frames/s, on the wall clock
    (``when``: the monotonic time of each batch sent)."""
    tids.append(threading.get_native_id())
    wheels = SimCanWheels(channel)
    wheels.set_speeds(SPEED_MPS, SPEED_MPS)
    frames = wheels.encode()
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        t0 = time.monotonic()
        n = 0
        while not stop.is_set() and time.monotonic() - t0 < BLAST_S:
            for f in frames:
                bus.send(f)
                n += 1
            when.append(time.monotonic())
            ahead = n / RATE_HZ - (time.monotonic() - t0)
            if ahead > 0:
                time.sleep(ahead)
        sent.append(n)
    finally:
        bus.shutdown()


def test_a_can_flood_is_coalesced_the_loop_queue_stays_bounded_and_no_distance_is_lost() -> None:
    channel = f"test-flood-{os.getpid()}"
    pipeline = Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
            navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            start_xy_m=(0.0, 0.0),
            goal_xy_m=(5000.0, 0.0),
            start_heading_rad=0.0,
            expected_rates_hz={"odometry": 50.0},
        )
    )
    silent_at: list[float] = []

    times: list[float] = []

    def listen(msg: object, out: Outputs) -> None:
        for h in out.health:
            if h.status.name == "odometry" and not h.status.alive:
                silent_at.append(time.monotonic())
        if isinstance(msg, WheelOdometry) and out.accepted:
            times.append(msg.t_s)

    odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=channel, bitrate=None))
    backlog: list[int] = []
    sent: list[int] = []
    blast_end: list[float] = []
    send_times: list[float] = []
    tids: dict[str, list[int]] = {"loop": [], "reader": [], "sender": []}
    waits: list[tuple[float, dict[str, float]]] = []  # (monotonic, run-queue wait per role)

    def sample_waits() -> None:
        roles = {r: sum(_run_delay_s(t) for t in ts) for r, ts in tids.items()}
        roles["process"] = sum(_run_delay_s(int(t)) for t in os.listdir("/proc/self/task"))
        waits.append((time.monotonic(), roles))

    async def scenario() -> App:
        app = App(pipeline, sources={"odometry": odo}, loop=LoopSettings(tick_hz=50, max_lag_s=0.5))
        app.listeners.append(listen)
        stop = threading.Event()
        async with app.running():
            tids["loop"].append(threading.get_native_id())
            tids["reader"] += [
                t.native_id
                for t in threading.enumerate()
                if t.name.startswith(odo.name) and t.native_id
            ]
            sender = threading.Thread(
                target=_blast, args=(channel, stop, sent, send_times, tids["sender"]), name="blast"
            )
            sender.start()
            try:
                t_end = time.monotonic() + BLAST_S + 1.0
                while time.monotonic() < t_end:
                    backlog.append(app.backlog())
                    sample_waits()
                    await asyncio.sleep(0.01)
            finally:
                stop.set()
                await asyncio.to_thread(sender.join)
                blast_end.append(time.monotonic())
            await asyncio.sleep(0.3)  # the reader hands over what it held
        return app

    app = asyncio.run(scenario())
    stats = odo.stats()
    print(f"sent {sent} frames, stats {stats}, max backlog {max(backlog)}, {app.lag_summary()}")
    assert tids["reader"] and tids["sender"] and len(waits) > 100  # the waits were measured
    assert sent and sent[0] > 10_000  # a real flood (several thousand frames per second)
    assert max(backlog) <= BACKLOG_LIMIT + 2  # bounded, not tens of thousands
    assert stats.get("coalesced", 0) > 0
    # Issue 23, item 10: the reader's lag under the flood is no clock step, and no frame is
    # rejected as time going back.
    # A frame after a silence longer than the decoder's bound is rejected as a gap: the app's
    # fault only if frames were being sent and the reader was on the CPU meanwhile (on a
    # machine at load 19 the sender or the reader was held off for over a second).
    send_gap = max((b - a for a, b in itertools.pairwise(send_times)), default=0.0)
    reader_held = max(
        (b[1]["reader"] - a[1]["reader"] for a, b in itertools.pairwise(waits)), default=0.0
    )
    gaps = stats.get("rejected_gap", 0)
    machine = send_gap >= 0.5 * MAX_GAP_S or reader_held >= 0.5 * MAX_GAP_S
    print(f"longest send gap {send_gap * 1e3:.0f} ms, reader held off {reader_held * 1e3:.0f} ms")
    assert stats.get("clock_steps", 0) == 0 and stats["rejected"] == gaps, stats
    assert gaps == 0 or machine, (stats, send_gap, reader_held)
    lag = app.lag_summary()
    # The loop's thread is held off by the kernel directly (its own run-queue wait) or through
    # the GIL: a thread of this process preempted while it holds the GIL stops the loop too,
    # and the loop then sleeps on the GIL, not on a run queue (a full make test at load 17:
    # a lag of 1.83 s while the loop's own wait was 0.16 s). The sum of every thread's wait
    # over the interval bounds both.
    withheld_s = max(
        (b[1]["process"] - a[1]["process"] for a, b in itertools.pairwise(waits)), default=0.0
    )
    print(f"longest run-queue wait of the process between samples: {withheld_s * 1e3:.0f} ms")
    assert lag["loop_lag_max_ms"] is not None
    assert lag["loop_lag_max_ms"] < 500 + 1000 * withheld_s, (lag, withheld_s)
    # Never a false "odometry silent" while frames arrive (it is true once the flood ended).
    false_silent = [
        t
        for t in silent_at
        if t <= blast_end[0] - 0.9
        and _frames_flowed(send_times, t - 1.0, t)
        and _withheld(waits, t - 1.5, t, ("reader", "loop")) < 0.5
    ]
    assert not false_silent, (false_silent, blast_end, silent_at[:5])
    # No distance lost: 10 m/s over the span of the first to the last increment (one frame
    # period of the first increment is not in it).
    span = times[-1] - times[0]
    assert pipeline.estimate.odometer_m == pytest.approx(SPEED_MPS * span, rel=0.02, abs=0.5)


def _frames_flowed(send_times: list[float], t0: float, t1: float) -> bool:
    """Whether the sender sent frames in every half second of [t0, t1] (else the silence was
    real: the sender itself was held off the CPU)."""
    i = bisect.bisect_left(send_times, t0)
    last = t0
    for t in send_times[i:]:
        if t > t1:
            break
        if t - last > 0.5:
            return False
        last = t
    return t1 - last <= 0.5


def _withheld(
    waits: list[tuple[float, dict[str, float]]], t0: float, t1: float, roles: tuple[str, ...]
) -> float:
    """The longest run-queue wait over [t0, t1] of the threads of ``roles`` (from the samples
    around it)."""
    times = [w[0] for w in waits]
    i0 = max(0, bisect.bisect_right(times, t0) - 1)
    i1 = min(len(waits) - 1, bisect.bisect_left(times, t1))
    if i1 <= i0:
        return 0.0
    return max(waits[i1][1][r] - waits[i0][1][r] for r in roles)
