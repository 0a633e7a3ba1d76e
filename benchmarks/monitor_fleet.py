"""How many cars one ``guidance monitor --json`` keeps up with (issue 24).

One local zenoh router (its own process); K fake cars, each a zenoh *client session* of that
router with a liveliness token under ``guidance/<id>``, publishing a real ``guidance.state``
message (the output table's encoder) on ``guidance/<id>/state`` at --rate Hz with
``CongestionControl.DROP`` and express, like the car's publisher. The cars are spread over
--fleet-procs processes (one publishing thread each, absolute deadlines) so the sessions are
real but the machine is not spent on 1000 interpreters. The monitor is the product's command,
``guidance monitor --connect ROUTER --json --timeout S``, run as a child; this script
reads its stdout and stamps each line's arrival with CLOCK_MONOTONIC, which the cars also use
for ``t_s``, so age = arrival - t_s is the age of what the monitor shows. With ``--feed web``
(or ``both``, the default) the child is ``guidance monitor --web`` instead, read as the page
reads it (``/api/fleet``, then ``?since=..&epoch=..``, every ``poll_ms`` of ``/api/config``):
the ages are what the page shows between answers, and, on the line below, a car's age in
each answer. The window opens ``SETTLE_S`` after the monitor first showed a state, and the
monitor's CPU is read over the window. ``--no-reference`` leaves out the reference
subscriber (it doubles what the router sends).

Printed per K: states received (% of those published during the window), each car's largest
gap between shown states (median over cars), the age of each car's shown state sampled every
17 ms (p50/p99/max over cars and samples, and the fraction of samples within 1 s), the
monitor's CPU (user+sys seconds / wall seconds, from wait4), and in brackets what a reference
subscriber got from the router and the router's and fleet's CPU (losses upstream of the
monitor). With zenoh's shared memory on (its default) one process could open only 351
client sessions and the router accept about 600; ``session_config`` turns it off, so 1000
cars are 1000 sessions over ``--fleet-procs`` processes. Figures: docs/telemetry.md,
"Measured".

    .venv/bin/python benchmarks/monitor_fleet.py --cars 1 10 30 100 --duration 10
    .venv/bin/python benchmarks/monitor_fleet.py --cars 10 100 300 --before 4bf690d
    .venv/bin/python benchmarks/monitor_fleet.py --cars 1000 --fleet-procs 4
    .venv/bin/python benchmarks/monitor_fleet.py --cars 5 30 --car plain --feed json-late
    .venv/bin/python benchmarks/monitor_fleet.py --router-restart 10
    .venv/bin/python benchmarks/monitor_fleet.py --cars 5 30 --car plain --feed json-late
    .venv/bin/python benchmarks/monitor_fleet.py --router-restart 1000 --car raw --fleet-procs 4

``--car plain`` publishes as another program would (the stall of issue 41: zenoh's defaults,
a dict dumped at each put); ``--feed json-late`` reads ``--json``'s output only once the
window is over, as a script using ``subprocess.communicate`` does: states are counted by
their ``t_s`` in the window, a gap is between ``t_s``, and ages are not measured.

``--before REV`` also runs the monitor of git revision REV (its packages extracted
with ``git archive`` into a temporary directory, first on PYTHONPATH), on the same fleet, and
prints both rows side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from _fleet import (
    FLEET,
    REFERENCE,
    ROOT,
    ROUTER,
    Seen,
    cpu_s,
    free_port,
    monitor_proc,
    read_output,
    spawn,
)

SETTLE_S = 3.0
"""How long after the monitor first showed a state the window opens: at 1,000 cars its first
looks take the fleet's replies to its query and the states queued meanwhile (1-2 s old)."""
STARTUP_S = 20.0
"""The longest a monitor may take to show its first state before the window opens anyway."""
LATE_STARTUP_S = 6.0
"""``--feed json-late``: the monitor's output is not read until the window is over, so the
window opens this long after the monitor started (its start-up here is 2-3 s)."""


@dataclass
class Row:
    label: str
    cars: int
    received_pct: float
    gap_s: float
    age_p50_s: float
    age_p99_s: float
    age_max_s: float
    fresh_pct: float
    cpu_pct: float
    delivered_pct: float = float("nan")
    """What the reference subscriber got of the states published in the window."""
    router_cpu_pct: float = float("nan")
    fleet_cpu_pct: float = float("nan")
    feed: tuple[float, float, float, float] | None = None
    """Web: the age of each car's state in each /api/fleet response as it arrived (p50, p99,
    max, % within 1 s); the row's ages are what the page shows between polls."""


def _poll_web(port: int, seen: Seen, stop: threading.Event, period_s: float = 0.25) -> None:
    """What the web page does: ``GET /api/fleet`` every ``poll_ms`` of ``/api/config``,
    then with the last answer's ``since`` and ``epoch``; each car's state recorded with the
    arrival of the whole response."""
    import urllib.request

    url = f"http://127.0.0.1:{port}/api/fleet"
    while not stop.is_set():  # the page's own period, as it reads it
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/config", timeout=5.0) as r:
                period_s = json.loads(r.read())["poll_ms"] / 1000.0
            break
        except OSError:
            stop.wait(0.1)
    since = ""  # after the first answer, only the track points written since (as the page)
    next_t = time.monotonic()
    while not stop.is_set():
        try:
            with urllib.request.urlopen(url + since, timeout=5.0) as r:
                body = r.read()
            now = time.monotonic()
            seen.responses += 1
            fleet = json.loads(body)
            since = f"?since={fleet['generation']}&epoch={fleet['epoch']}"
            for car in fleet["cars"]:
                st = car.get("state") or {}
                if isinstance(st.get("t_s"), float):
                    seen.states.setdefault(car["vehicle_id"], []).append(
                        (now, st["t_s"], st["seq"])
                    )
                    seen.feed_ages.append((now, now - st["t_s"]))
        except OSError:  # not serving yet, or gone at the end
            pass
        next_t += period_s
        stop.wait(max(0.0, next_t - time.monotonic()))


def _stats(
    label: str,
    seen: Seen,
    t0: float,
    t1: float,
    starts: dict[str, np.ndarray],
    cpu: float,
    late: bool = False,
) -> Row:
    """Figures over the window [t0, t1] (the fleet publishing, the monitor settled); a car's
    states expected are the rounds its process published in the window (``starts``). With
    ``late`` (the output read only after the window) the states are those stamped in the
    window, a gap is one between their ``t_s``, and no age is measured (nan)."""
    ids = sorted(starts)
    expected = sum(int(np.sum((st >= t0) & (st <= t1))) for st in starts.values())
    got, gaps, ages = 0, [], []
    grid = np.arange(t0, t1, 0.0173)  # not a divisor of the 0.1 s period
    at = 1 if late else 0  # the time a state counts at: its t_s, or its arrival
    for vid in ids:
        every = seen.states.get(vid, [])
        rows = [r for r in every if t0 <= r[at] <= t1]
        got += len({r[2] for r in rows})
        arrivals = [t0] + [r[at] for r in rows] + [t1]
        gaps.append(float(np.max(np.diff(arrivals))))
        if late:
            continue
        if not every:
            ages.extend([t1 - t0] * len(grid))
            continue
        arr = np.array([r[0] for r in every])  # what the monitor showed at each grid time
        ts = np.array([r[1] for r in every])
        idx = np.searchsorted(arr, grid, side="right") - 1
        shown = np.where(idx >= 0, ts[np.clip(idx, 0, None)], t0 - 2.0)  # none: since start
        ages.extend((grid - shown).tolist())
    a = np.array(ages or [float("nan")])
    return Row(
        label, len(ids), 100.0 * min(1.0, got / max(1, expected)), float(np.median(gaps)),
        float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.max()),
        100.0 * float(np.mean(a <= 1.0)) if not late else float("nan"), cpu,
    )  # fmt: skip


def run_k(
    k: int,
    duration: float,
    rate: float,
    procs: int,
    car: str,
    per_session: int,
    monitors: list[tuple[str, str | None, str]],
    reference: bool = True,
) -> list[Row]:
    port = free_port()
    router_ep = f"tcp/127.0.0.1:{port}"
    router = spawn(ROUTER, router_ep)
    fleet: list[subprocess.Popen[str]] = []
    rows: list[Row] = []
    windows: list[tuple[str, Seen, float, float, float, list[float]]] = []
    lates: list[bool] = []
    """(monitor, what it printed, window, its CPU, [router CPU, fleet CPUs..., delivered])"""
    try:
        assert router.stdout is not None and router.stdout.readline().strip() == "up"
        n_procs = max(1, min(procs, k))
        share = [k // n_procs + (1 if i < k % n_procs else 0) for i in range(n_procs)]
        first = 0
        for n in share:
            fleet.append(
                spawn(FLEET, router_ep, f"{rate:g}", str(first), str(n), car, str(per_session))
            )
            first += n
        for p in fleet:
            assert p.stdout is not None and p.stdout.readline().strip() == "up"
        for p in fleet:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
        time.sleep(1.0)
        for label, path, feed in monitors:  # one after the other, on the same running fleet
            seen = Seen()
            ref = spawn(REFERENCE, router_ep) if reference else None
            assert ref is None or (ref.stdout and ref.stdout.readline().strip() == "up")
            web_port = free_port() if feed == "web" else None
            mon = monitor_proc(router_ep, duration + STARTUP_S + 5.0, path, web_port)
            stop_polling = threading.Event()
            late = feed == "json-late"
            reader = threading.Thread(target=read_output, args=(mon, seen), daemon=True)
            if late:  # read after the window, as subprocess.communicate does
                time.sleep(LATE_STARTUP_S - SETTLE_S)
            elif web_port is None:
                reader = threading.Thread(target=read_output, args=(mon, seen), daemon=True)
            else:
                reader = threading.Thread(
                    target=_poll_web, args=(web_port, seen, stop_polling), daemon=True
                )
            if not late:
                reader.start()
            # the window opens SETTLE_S after the monitor first showed a state (its start-up:
            # imports, the query of the fleet and the replies, is not what is measured)
            up_by = time.monotonic() + STARTUP_S
            while (
                not late
                and not seen.showed_a_state()
                and time.monotonic() < up_by
                and mon.poll() is None
            ):
                time.sleep(0.05)
            t0 = time.monotonic() + SETTLE_S
            time.sleep(SETTLE_S)
            cpu0 = cpu_s(mon.pid)
            others0 = [cpu_s(p.pid) for p in [router, *fleet]]
            time.sleep(duration)
            t1 = time.monotonic()
            wall = t1 - t0
            cpu = 100.0 * (cpu_s(mon.pid) - cpu0) / wall
            others = [
                (cpu_s(p.pid) - c0) / wall for p, c0 in zip([router, *fleet], others0, strict=True)
            ]
            if mon.poll() is not None:
                print(f"  ({label}: the monitor ended early)", file=sys.stderr)
            if late:
                reader.start()
                time.sleep(2.0)  # what it held comes out
            mon.terminate()
            mon.wait()
            stop_polling.set()
            reader.join(2.0)
            seen.parse()
            delivered = -1
            if ref is not None:
                assert ref.stdin is not None and ref.stdout is not None
                ref.stdin.write(f"{t0} {t1}\n")
                ref.stdin.flush()
                delivered = int(ref.stdout.readline())
                ref.wait()
            windows.append((label, seen, t0, t1, cpu, [*others, delivered]))
            lates.append(late)
        for p in fleet:
            assert p.stdin is not None
            p.stdin.write("stop\n")
            p.stdin.flush()
        starts: dict[str, np.ndarray] = {}
        for p in fleet:
            assert p.stdout is not None
            report = json.loads(p.stdout.readline() or "{}")
            for i in range(report["first"], report["first"] + report["n"]):
                starts[f"car{i:04d}"] = np.array(report["starts"])
            if report.get("late_rounds", 0) > report.get("rounds", 1) * 0.05:
                print(f"  (a fleet process was behind: {report['late_rounds']} of "
                      f"{report['rounds']} rounds late)", file=sys.stderr)  # fmt: skip
        for (label, seen, t0, t1, cpu, others), late in zip(windows, lates, strict=True):
            row = _stats(label, seen, t0, t1, starts, cpu, late)
            in_feed = np.array([a for t, a in seen.feed_ages if t0 <= t <= t1])
            if in_feed.size:
                p50, p99 = (float(np.percentile(in_feed, q)) for q in (50, 99))
                row.feed = (p50, p99, float(in_feed.max()), 100.0 * float(np.mean(in_feed <= 1)))
            row.router_cpu_pct, row.fleet_cpu_pct = 100 * others[0], 100 * sum(others[1:-1])
            expected = sum(int(np.sum((st >= t0) & (st <= t1))) for st in starts.values())
            if others[-1] >= 0:
                row.delivered_pct = 100.0 * min(1.0, others[-1] / max(1, expected))
            rows.append(row)
    finally:
        for p in [*fleet, router]:
            if p.poll() is None:
                p.kill()
            p.wait()
    return rows


def router_restart(
    k: int, rate: float, car_kind: str = "telemetry", procs_n: int = 1, down_s: float = 2.0
) -> tuple[float, int]:
    """K cars (``telemetry``: the car's own publisher; ``raw``: a session, publisher and token
    each, over ``procs_n`` processes) and one monitor through a router that is killed and,
    ``down_s`` later, started again on the same port: how long after it is back until every
    car's state is shown again (max over cars), and how many cars came back."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs = [spawn(ROUTER, ep)]
    try:
        assert procs[0].stdout is not None and procs[0].stdout.readline().strip() == "up"
        share = [k // procs_n + (1 if i < k % procs_n else 0) for i in range(procs_n)]
        cars = [
            spawn(FLEET, ep, f"{rate:g}", str(sum(share[:i])), str(n), car_kind, "1")
            for i, n in enumerate(share)
        ]
        procs.extend(cars)
        for car in cars:
            assert car.stdin is not None and car.stdout is not None
            assert car.stdout.readline().strip() == "up"
        for car in cars:
            assert car.stdin is not None
            car.stdin.write("go\n")
            car.stdin.flush()
        seen = Seen()
        mon = monitor_proc(ep, 20.0 + down_s, None)
        procs.append(mon)  # type: ignore[arg-type]
        threading.Thread(target=read_output, args=(mon, seen), daemon=True).start()
        time.sleep(4.0)
        procs[0].kill()
        procs[0].wait()
        time.sleep(down_s)
        procs[0] = spawn(ROUTER, ep)
        assert procs[0].stdout is not None and procs[0].stdout.readline().strip() == "up"
        up = time.monotonic()
        time.sleep(12.0)
        seen.parse()
        back = [
            min((a for a, _, _ in rows if a > up), default=None) for rows in seen.states.values()
        ]
        times = [b - up for b in back if b is not None]
        return (max(times) if len(times) == k else float("inf")), len(times)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()


def _before_tree(rev: str, tmp: Path) -> str:
    packages = ["guidance", "hal_sim", "drivers", "landmark_db"]  # the CLI imports them all
    tar = subprocess.run(
        ["git", "archive", rev, *packages], cwd=ROOT, check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(tmp)], input=tar, check=True)
    return str(tmp)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cars", type=int, nargs="+", default=[1, 10, 30, 100])
    ap.add_argument("--duration", type=float, default=10.0, help="measured seconds per K")
    ap.add_argument("--rate", type=float, default=10.0, help="state messages per car per s")
    ap.add_argument("--fleet-procs", type=int, default=2, help="processes holding the cars")
    ap.add_argument(
        "--car",
        choices=("raw", "telemetry", "plain"),
        default="raw",
        help="raw: a session, a publisher and a token per car; telemetry: the car's Telemetry; "
        "plain: another program's car, zenoh's defaults and json.dumps (the stall's repro)",
    )
    ap.add_argument(
        "--cars-per-session",
        type=int,
        default=1,
        metavar="N",
        help="raw cars sharing one client session (this zenoh's router in Python refuses "
        "client sessions beyond about 350: 4 gives 1000 cars on 250 sessions)",
    )
    ap.add_argument("--before", metavar="REV", help="also run the monitor of this git revision")
    ap.add_argument(
        "--no-reference",
        action="store_true",
        help="no reference subscriber (it doubles what the router sends; 'delivered' is nan)",
    )
    ap.add_argument(
        "--feed",
        choices=("json", "web", "both", "json-late", "all"),
        default="both",
        help="what is measured: --json's lines, the web map's /api/fleet, both in turn; "
        "json-late: --json read only after the window (subprocess.communicate), all: the three",
    )
    ap.add_argument(
        "--router-restart",
        type=int,
        metavar="K",
        help="only: K cars, the router killed and restarted; seconds until all are back",
    )
    args = ap.parse_args()
    if args.router_restart:
        worst, n = router_restart(args.router_restart, args.rate, args.car, args.fleet_procs)
        what = "the car's Telemetry" if args.car == "telemetry" else "raw sessions"
        print(
            f"router restart, {args.router_restart} cars ({what}, client mode): "
            f"{n} came back without restarting the monitor, the last {worst:.1f} s after the "
            "router was up again"
        )
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        monitors: list[tuple[str, str | None, str]] = []
        feeds = {"both": ("json", "web"), "all": ("json", "web", "json-late")}.get(
            args.feed, (args.feed,)
        )
        for feed in feeds:
            if args.before:
                tree = _before_tree(args.before, Path(tmp))
                monitors.append((f"before ({args.before}) {feed}", tree, feed))
            monitors.append((f"this tree {feed}", None, feed))
        print(
            f"guidance monitor --json (what it prints) and --web (GET /api/fleet as often "
            f"as the page does), K cars at {args.rate:g} Hz through one local router, "
            f"{args.duration:g} s measured per K ({os.cpu_count()} CPUs)"
        )
        head = (
            f"{'monitor':<22}{'cars':>5}{'states':>9}{'max gap':>9}{'age p50':>9}"
            f"{'p99':>7}{'max':>7}{'fresh<1s':>10}{'CPU':>7}"
            "   (router delivered; router, fleet CPU)"
        )
        print(head)
        for k in args.cars:
            for r in run_k(
                k,
                args.duration,
                args.rate,
                args.fleet_procs,
                args.car,
                args.cars_per_session,
                monitors,
                not args.no_reference,
            ):
                print(
                    f"{r.label:<22}{r.cars:>5}{r.received_pct:>8.1f}%{r.gap_s:>8.2f}s"
                    f"{r.age_p50_s:>8.2f}s{r.age_p99_s:>6.2f}s{r.age_max_s:>6.2f}s"
                    f"{r.fresh_pct:>9.1f}%{r.cpu_pct:>6.0f}%"
                    f"   ({r.delivered_pct:.1f} %; {r.router_cpu_pct:.0f} %,"
                    f" {r.fleet_cpu_pct:.0f} %)",
                    flush=True,
                )
                if r.feed is not None:
                    print(
                        f"{'  (in each response)':<22}{'':>5}{'':>9}{'':>9}{r.feed[0]:>8.2f}s"
                        f"{r.feed[1]:>6.2f}s{r.feed[2]:>6.2f}s{r.feed[3]:>9.1f}%",
                        flush=True,
                    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
