"""Publish-to-receive latency of telemetry state on loopback (issue 6 acceptance).

Two processes, two zenoh sessions on the same machine: a car process publishes
``guidance.state`` at --rate Hz through ``Telemetry.send`` (the state row) (the path the
app uses: latest-value slot, publisher thread, zenoh with DROP + express), a
monitor process (this one) receives it through ``MonitorClient``. ``t_s`` in the
payload is the car's ``time.monotonic()`` at the publish call and the monitor
stamps arrival with ``time.monotonic()``: CLOCK_MONOTONIC is shared by all
processes of one machine, so the difference is the one-way latency.

    .venv/bin/python benchmarks/telemetry_latency.py [--rate 50] [--duration 20]

Prints the latency median, p90, p99 and max, messages lost (sequence gaps
seen by the monitor, plus the car's own drop counters), and what a
``send`` call costs the car's loop.
"""

from __future__ import annotations

import argparse
import itertools
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from guidance.telemetry.client import MonitorClient

CAR = r"""
import json, sys, time
import numpy as np
from guidance.core.messages import Ellipse, EstimateState, Target
from guidance.outputs.kinds import STATE, OutputContext
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
port, rate, duration = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
tel = Telemetry(TelemetryConfig(vehicle_id="bench", listen=(f"tcp/127.0.0.1:{port}",)))
tel.start()
print("up", flush=True)
sys.stdin.readline()  # the monitor is subscribed
cov = ((4.0, 0.1, 0.0), (0.1, 2.0, 0.0), (0.0, 0.0, 0.01))
ell = Ellipse(4.1, 2.8, 0.3, 8.2)
period, n = 1.0 / rate, int(round(duration * rate))
cost = np.empty(n)
next_t = time.monotonic()
for i in range(n):
    next_t += period
    time.sleep(max(0.0, next_t - time.monotonic()))
    t0 = time.monotonic()
    tel.send(STATE, EstimateState(t0, 1.0 * i, 2.0, 0.5, cov, ell, False, True), OutputContext(
        speed_mps=8.0, target=Target(300.0, 100.0, "goal", None), method="hybrid"))
    cost[i] = time.monotonic() - t0
time.sleep(0.5)
h = tel.health()
hot = np.empty(2000)  # back-to-back calls: the call itself, without the wake-up after a sleep
state = EstimateState(0.0, 0.0, 2.0, 0.5, cov, ell, False, True)
for i in range(len(hot)):
    t0 = time.perf_counter()
    tel.send(STATE, state, OutputContext(speed_mps=8.0))
    hot[i] = time.perf_counter() - t0
tel.close()
dropped = {k.removeprefix("dropped_"): v for k, v in h.counters.items() if k.startswith("dropped_")}
print(json.dumps({"sent": n, "published": h.counters["published"], "dropped": dropped,
                  "call_median_us": float(np.median(cost) * 1e6),
                  "call_p99_us": float(np.percentile(cost, 99) * 1e6),
                  "call_max_us": float(cost.max() * 1e6),
                  "hot_median_us": float(np.median(hot) * 1e6),
                  "hot_p99_us": float(np.percentile(hot, 99) * 1e6)}), flush=True)
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=float, default=50.0, help="publish rate, Hz (default 50)")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds (default 20)")
    args = ap.parse_args()

    port = free_port()
    n_sent = round(args.duration * args.rate)
    car = subprocess.Popen(
        [sys.executable, "-c", CAR, str(port), str(args.rate), str(args.duration)],
        cwd=Path(__file__).resolve().parents[1],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert car.stdin is not None and car.stdout is not None
    latencies: list[float] = []
    seqs: list[int] = []
    try:
        if car.stdout.readline().strip() != "up":
            print("car process failed to start", file=sys.stderr)
            return 1
        with MonitorClient([f"tcp/127.0.0.1:{port}"], vehicle="bench") as mon:
            deadline = time.monotonic() + 10
            while mon.peers() == 0 and time.monotonic() < deadline:
                time.sleep(0.01)
            time.sleep(0.3)  # let the subscription reach the car
            car.stdin.write("go\n")
            car.stdin.flush()
            end = time.monotonic() + args.duration + 2.0
            while time.monotonic() < end:
                e = mon.get(0.1)
                if e is None or e.kind != "state" or e.late_join or e.message is None:
                    continue
                if int(e.message["seq"]) > n_sent:  # the car's back-to-back cost test
                    continue
                latencies.append(e.received_s - float(e.message["t_s"]))
                seqs.append(int(e.message["seq"]))
        report = json.loads(car.stdout.readline())
    finally:
        if car.poll() is None:
            car.kill()
        car.wait()

    lat_ms = np.array(latencies) * 1e3
    gaps = sum(b - a - 1 for a, b in itertools.pairwise(seqs) if b > a + 1)
    missing = report["sent"] - len(seqs)
    print(
        f"telemetry latency, loopback, {args.rate:g} Hz for {args.duration:g} s "
        f"(two processes, two zenoh sessions, tcp/127.0.0.1)"
    )
    print(
        f"  received {len(seqs)} of {report['sent']} state messages "
        f"(missing {missing}; sequence gaps {gaps}; car drops {report['dropped'] or 0})"
    )
    if len(lat_ms):
        print(
            f"  latency  median {np.median(lat_ms):.3f} ms   p90 {np.percentile(lat_ms, 90):.3f} ms"
            f"   p99 {np.percentile(lat_ms, 99):.3f} ms   max {lat_ms.max():.3f} ms"
        )
    print(
        f"  send call (state) in the {args.rate:g} Hz loop (first call after a sleep): "
        f"median {report['call_median_us']:.1f} us, p99 {report['call_p99_us']:.1f} us, "
        f"max {report['call_max_us']:.1f} us"
    )
    print(
        f"  send call (state) back-to-back (no wake-up cost): median "
        f"{report['hot_median_us']:.1f} us, p99 {report['hot_p99_us']:.1f} us"
    )
    return 0 if len(lat_ms) else 1


if __name__ == "__main__":
    sys.exit(main())
