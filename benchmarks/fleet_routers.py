"""A fleet through two linked routers against one, in the same run, and a router killed
mid-run (issue 41).

Each K: first one router (every car a client of it), then two linked routers (half the cars
list ``A,B``, half ``B,A``, so each router carries half; the monitor is a client of A and
sees B's cars through the link), the same fleet processes' kind of cars (``--car``: raw
sessions, or ``plain`` as another program publishes). ``guidance monitor --json`` is the
product's command, read as ``monitor_fleet.py`` reads it: per car, the age of its shown state
sampled every 17 ms over the window (p50/p99/max, share within 1 s) and the share of states
printed. In the two-router run, router B is then killed: for each of B's cars, the time from
the kill until a state it made after the kill is printed (max over cars), and how many came
back within 2 s, without restarting the monitor.

    .venv/bin/python benchmarks/fleet_routers.py --cars 100 300 --duration 8
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time

import numpy as np
from _fleet import FLEET, ROUTER, Seen, cpu_s, free_port, monitor_proc, read_output, spawn
from monitor_fleet import SETTLE_S, Row, _stats

BACK_WITHIN_S = 2.0


def _up(proc: object) -> None:
    out = proc.stdout  # type: ignore[attr-defined]
    assert out is not None and out.readline().strip() == "up"


def _run(k: int, duration: float, rate: float, procs: int, car: str, two: bool,
         kill_b: bool) -> tuple[Row, tuple[float, int, int] | None]:  # fmt: skip
    a, b = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    routers = [spawn(ROUTER, a)]
    if two:
        routers.append(spawn(ROUTER, b, a))
    fleet = []
    mon = None
    try:
        for r in routers:
            _up(r)
        share = [k // procs + (1 if i < k % procs else 0) for i in range(procs)]
        first = 0
        for i, n in enumerate(share):
            connect = f"{b},{a}" if two and i % 2 else f"{a},{b}" if two else a
            fleet.append(spawn(FLEET, connect, f"{rate:g}", str(first), str(n), car, "1"))
            first += n
        on_b = {f"car{j:04d}" for i, n in enumerate(share) if two and i % 2
                for j in range(sum(share[:i]), sum(share[:i]) + n)}  # fmt: skip
        for p in fleet:
            _up(p)
        for p in fleet:
            p.stdin.write("go\n")  # type: ignore[union-attr]
            p.stdin.flush()  # type: ignore[union-attr]
        seen = Seen()
        mon = monitor_proc(a, duration + 40.0, None)
        threading.Thread(target=read_output, args=(mon, seen), daemon=True).start()
        up_by = time.monotonic() + 20.0
        while not seen.showed_a_state() and time.monotonic() < up_by:
            time.sleep(0.05)
        time.sleep(SETTLE_S)
        t0 = time.monotonic()
        cpu0 = cpu_s(mon.pid)
        time.sleep(duration)
        t1 = time.monotonic()
        cpu = 100.0 * (cpu_s(mon.pid) - cpu0) / (t1 - t0)
        failover = None
        if kill_b and two:
            routers[1].kill()
            routers[1].wait()
            killed = time.monotonic()
            time.sleep(BACK_WITHIN_S + 3.0)
        seen.parse()
        for p in fleet:
            p.stdin.write("stop\n")  # type: ignore[union-attr]
            p.stdin.flush()  # type: ignore[union-attr]
        starts = {}
        for p in fleet:
            rep = json.loads(p.stdout.readline() or "{}")  # type: ignore[union-attr]
            for j in range(rep["first"], rep["first"] + rep["n"]):
                starts[f"car{j:04d}"] = np.array(rep["starts"])
        row = _stats(f"{'two routers' if two else 'one router'}", seen, t0, t1, starts, cpu)
        if kill_b and two:
            backs = []
            for vid in on_b:  # the first state made after the kill, as printed
                after = [arr for arr, t_s, _seq in seen.states.get(vid, []) if t_s >= killed]
                backs.append(min(after) - killed if after else float("inf"))
            failover = (max(backs), sum(x <= BACK_WITHIN_S for x in backs), len(backs))
        return row, failover
    finally:
        for p in [*fleet, *routers, *([mon] if mon is not None else [])]:
            if p.poll() is None:
                p.kill()
            p.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cars", type=int, nargs="+", default=[100, 300])
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--fleet-procs", type=int, default=2)
    ap.add_argument("--car", choices=("raw", "plain"), default="raw")
    args = ap.parse_args()
    print(f"guidance monitor --json through one router, then two linked routers (the monitor on "
          f"A, half the cars on B), {args.rate:g} Hz, {args.duration:g} s per run, "
          f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"{'run':<14}{'cars':>5}{'states':>9}{'age p50':>9}{'p99':>7}{'max':>7}{'fresh<1s':>10}"
          f"{'CPU':>7}   B killed: B's cars back (max; within {BACK_WITHIN_S:g} s)")  # fmt: skip
    for k in args.cars:
        for two in (False, True):
            r, fo = _run(k, args.duration, args.rate, args.fleet_procs, args.car, two, two)
            tail = "" if fo is None else f"   {fo[0]:.2f} s, {fo[1]} of {fo[2]}"
            print(f"{r.label:<14}{r.cars:>5}{r.received_pct:>8.1f}%{r.age_p50_s:>8.2f}s"
                  f"{r.age_p99_s:>6.2f}s{r.age_max_s:>6.2f}s{r.fresh_pct:>9.1f}%{r.cpu_pct:>6.0f}%"
                  f"{tail}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
