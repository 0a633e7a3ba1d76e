"""``guidance monitor``: watch one car or a fleet live, print messages for scripts, plot tracks.

Live view (default): every car seen, with pose, compass heading, major axis,
target and distance to it, last prompt, health and the age of the last message, as a
table on a wide terminal and one block per car at 80 columns or piped
(``guidance.tools.monitor_view``); a car goes when its liveliness token goes (its
process ended or the link dropped). Press ``s`` or send SIGUSR1 for a PNG snapshot
of the tracks, ``q`` to quit. ``--json`` prints each message as one JSON line instead (plus
``guidance.liveliness/1`` lines when cars appear or vanish). ``--count`` and
``--timeout`` end the run: exit 0 if any message arrived, 1 (with one line on
stderr) if none did. All zenoh work goes through ``guidance.telemetry``.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

from guidance.errors import UserError
from guidance.telemetry.client import MonitorClient, TelemetryEvent
from guidance.telemetry.config import check_endpoint
from guidance.telemetry.keys import DEFAULT_CONNECT, KINDS
from guidance.tools.monitor_output import LineWriter
from guidance.tools.monitor_view import (
    CarView,
    FleetView,
    car_row,
    compass_deg,
    health_summary,
    render_table,
)

__all__ = [
    "CarView",
    "FleetView",
    "car_row",
    "compass_deg",
    "health_summary",
    "register",
    "render_table",
    "run",
    "write_snapshot",
]

LIVELINESS_SCHEMA = "guidance.liveliness/1"
ALARM_SCHEMA = "guidance.alarm/1"


def write_snapshot(view: FleetView, path: Path) -> Path:
    """PNG of every car's track, current 2-sigma ellipse, past ellipses, target and goal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from guidance.tools.plotting import ellipse_patch

    fig, ax = plt.subplots(figsize=(8, 8), dpi=100)
    try:
        cars = {**view.gone, **view.cars}
        colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        drew_ellipse = drew_target = drew_goal = False
        for i, vid in enumerate(sorted(cars)):
            car, colour = cars[vid], colours[i % len(colours)]
            label = vid if car.alive else f"{vid} (gone)"
            if car.track:
                xs, ys = zip(*car.track, strict=True)
                ax.plot(xs, ys, "-", color=colour, lw=1.2, label=f"{label} track")
                ax.plot(xs[-1:], ys[-1:], "o", color=colour, ms=6)
            for x, y, a, b, th in car.ellipses:
                ax.add_patch(ellipse_patch(x, y, a, b, th, color=colour, lw=0.6, alpha=0.5))
            s = car.state or {}
            ell = s.get("ellipse") or {}
            if all(isinstance(v, int | float) for v in (s.get("x_m"), s.get("y_m"))) and all(
                isinstance(ell.get(k), int | float)
                for k in ("semi_major_m", "semi_minor_m", "orientation_rad")
            ):
                ax.add_patch(
                    ellipse_patch(
                        s["x_m"], s["y_m"], ell["semi_major_m"], ell["semi_minor_m"],
                        ell["orientation_rad"], color=colour, lw=1.5,
                        label=None if drew_ellipse else "2-sigma ellipse",
                    )
                )  # fmt: skip
                drew_ellipse = True
            target, goal = s.get("target") or {}, s.get("goal") or {}
            if isinstance(target.get("x_m"), int | float):
                ax.plot(
                    [target["x_m"]],
                    [target["y_m"]],
                    "x",
                    color=colour,
                    ms=9,
                    mew=2,
                    label=None if drew_target else "target",
                )
                drew_target = True
            if isinstance(goal.get("x_m"), int | float):
                ax.plot(
                    [goal["x_m"]],
                    [goal["y_m"]],
                    "*",
                    color=colour,
                    ms=13,
                    label=None if drew_goal else "goal",
                )
                drew_goal = True
        ax.set_xlabel("x east (m)")
        ax.set_ylabel("y north (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
        ax.set_title(
            f"guidance monitor: {len(view.cars)} car(s) live, {time.strftime('%Y-%m-%d %H:%M:%S')}"
        )
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="best", fontsize="small")
        else:
            ax.text(0.5, 0.5, "no track received", ha="center", transform=ax.transAxes)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path)
    finally:
        plt.close(fig)
    return path


# -- command line -----------------------------------------------------------------------------
def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "monitor",
        help="watch cars' telemetry live (table, JSON lines, PNG snapshot)",
        description=(
            "Watch cars' telemetry: a live table (s: PNG snapshot, q: quit; SIGUSR1: snapshot), "
            "or JSON lines for scripts. Exit 0 if messages arrived, 1 if none did."
        ),
    )
    p.add_argument(
        "--connect",
        metavar="ENDPOINT",
        action="append",
        help=f"zenoh endpoint of a car or router, repeatable (default {DEFAULT_CONNECT})",
    )
    p.add_argument("--vehicle", default="all", metavar="ID|all", help="one car or all (default)")
    p.add_argument("--json", action="store_true", help="print one JSON message per line")
    p.add_argument("--count", type=_positive_int, metavar="N", help="exit after N messages")
    p.add_argument("--timeout", type=_positive_float, metavar="S", help="exit after S seconds")
    p.add_argument(
        "--snapshot", type=Path, metavar="PNG", help="PNG of the tracks (on exit, s, SIGUSR1)"
    )
    p.add_argument(
        "--zenoh-config",
        metavar="JSON5",
        default="",
        help="zenoh config file for this monitor (TLS certificates, credentials): config/zenoh/",
    )
    p.add_argument(
        "--send-goal",
        nargs=2,
        type=float,
        metavar=("X_M", "Y_M"),
        help="ask --vehicle ID to drive to a new goal (obeyed only if the car allows it)",
    )
    p.add_argument(
        "--web",
        nargs="?",
        const="127.0.0.1:8765",
        metavar="HOST:PORT",
        help="serve a live map of the fleet to a browser (default 127.0.0.1:8765; port 0: any)",
    )
    p.add_argument(
        "--allow-remote",
        action="store_true",
        help="let --web bind an address other than loopback (see docs/telemetry.md first)",
    )
    p.add_argument(
        "--tiles",
        metavar="URL",
        default="",
        help="--web map tiles from this server, e.g. http://tiles.lan/{z}/{x}/{y}.png",
    )
    p.set_defaults(func=run)


def _positive_int(text: str) -> int:
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError("must be > 0")
    return value


def _positive_float(text: str) -> float:
    value = float(text)
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError("must be > 0")
    return value


DRAW_EVERY_S = 0.25
DRAW_SHARE = 0.2
"""The live view draws 4 times a second, less often when a draw takes longer than a fifth of
that (a table of 40 of 1,000 cars takes 0.1-0.2 s): at most a fifth of its time drawing, the
rest folding what arrives."""

GC_THRESHOLDS = (50_000, 20, 50)
"""The monitor's garbage collector: a young collection every 50,000 allocations (Python's 700).
At 1,000 cars a monitor makes ten thousand short-lived messages a second while it holds every
car's state and track: with the default, collecting took a fifth of its CPU (py-spy)."""


def calm_gc() -> None:
    """Move what start-up made out of the collector's way and collect less often."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(*GC_THRESHOLDS)


def run(args: argparse.Namespace) -> int:
    endpoints: Sequence[str] = args.connect or [DEFAULT_CONNECT]
    for ep in endpoints:
        check_endpoint(ep)
    web = getattr(args, "web", None)
    if web is not None:
        from guidance.tools.web.server import check_web_args

        check_web_args(web, allow_remote=args.allow_remote, tiles=args.tiles)
    calm_gc()
    client = MonitorClient(endpoints, vehicle=args.vehicle, zenoh_config=args.zenoh_config)
    client.open()
    try:
        if web is not None:
            from guidance.tools.web.server import serve

            return serve(
                client, web, allow_remote=args.allow_remote, tiles=args.tiles,
                timeout_s=args.timeout, announce=lambda line: print(line, flush=True),
            )  # fmt: skip
        if args.send_goal is not None:
            return _send_goal(client, args)
        if args.json:
            return _run_json(client, args)
        return _run_live(client, args)
    finally:
        client.close()


def _send_goal(client: MonitorClient, args: argparse.Namespace) -> int:
    if args.vehicle == "all":
        raise UserError("--send-goal needs --vehicle ID")
    deadline = time.monotonic() + (args.timeout or 5.0)
    while client.peers() == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    if client.peers() == 0:
        print(
            f"guidance monitor: no zenoh peer reachable at {', '.join(client.connect)}",
            file=sys.stderr,
        )
        return 1
    x_m, y_m = args.send_goal
    rest = max(0.5, deadline - time.monotonic())
    if not client.send_goal(args.vehicle, x_m, y_m, wait_s=rest):
        print(
            f"guidance monitor: goal not sent: no car {args.vehicle!r} listening for remote goals "
            f"within {rest:.1f} s (is it running, with allow_remote_goal = true in its "
            "[telemetry] config?)",
            file=sys.stderr,
        )
        return 1
    print(
        f"goal ({x_m:.1f}, {y_m:.1f}) m delivered to {args.vehicle}; "
        "the car applies it only if its range check and access control allow"
    )
    return 0


def _events(
    client: MonitorClient, deadline: float | None, stop: threading.Event
) -> Iterator[TelemetryEvent | None]:
    """Events as they come; None every 0.25 s of quiet so the caller can refresh."""
    while not stop.is_set():
        wait = 0.25 if deadline is None else min(0.25, deadline - time.monotonic())
        if wait <= 0:
            return
        yield client.get(wait)


def _no_messages(client: MonitorClient, timeout: float | None) -> int:
    within = f" within {timeout:g} s" if timeout else ""
    print(
        f"guidance monitor: no messages received from {', '.join(client.connect)}{within} "
        "(is the car running, and are the endpoint and certificates right?)",
        file=sys.stderr,
    )
    return 1


def liveliness_line(view: FleetView, event: TelemetryEvent) -> dict[str, Any]:
    """The ``guidance.liveliness/1`` line of a car appearing or going: a gone car's line also
    says when its last message came (``last_message_s_ago``, monitor clock) and where it last
    was (``last_position``: the last state's t_s, x_m, y_m, lat_deg, lon_deg, or null)."""
    line: dict[str, Any] = {
        "schema": LIVELINESS_SCHEMA,
        "vehicle_id": event.vehicle_id,
        "alive": event.kind == "alive",
    }
    car = view.gone.get(event.vehicle_id)
    if event.kind == "gone" and car is not None:
        last = car.last_received_s
        line["last_message_s_ago"] = None if last is None else round(event.received_s - last, 3)
        s = car.state or {}
        line["last_position"] = (
            {k: s.get(k) for k in ("t_s", "x_m", "y_m", "lat_deg", "lon_deg")} if s else None
        )
    return line


def alarm_line(view: FleetView, vehicle_id: str) -> dict[str, Any]:
    """The ``guidance.alarm/1`` line of a car whose alarm came (``active``) or went: two
    publishers behind its vehicle id (``guidance.tools.monitor_ids``), with why."""
    car = view.cars.get(vehicle_id) or view.gone.get(vehicle_id)
    text = "" if car is None else car.alarm
    return {
        "schema": ALARM_SCHEMA,
        "vehicle_id": vehicle_id,
        "alarm": "two_publishers",
        "active": bool(text),
        "detail": text,
    }


def _json_line(
    client: MonitorClient, view: FleetView, event: TelemetryEvent
) -> Mapping[str, Any] | None:
    """What ``--json`` prints for one event (None: nothing, e.g. a bad or repeated message)."""
    if event.kind == "alive" and event.vehicle_id not in view.cars:
        client.query_latest(event.vehicle_id)
    if not view.apply(event):
        return None
    if event.kind in ("alive", "gone"):
        return liveliness_line(view, event)
    if event.kind in KINDS and event.message is not None:
        return event.message
    return None


def _run_json(client: MonitorClient, args: argparse.Namespace) -> int:
    view = FleetView()
    stop = threading.Event()
    deadline = None if args.timeout is None else time.monotonic() + args.timeout
    client.query_latest()
    writer = LineWriter(sys.stdout)
    """Writes on its own thread: a reader of stdout that is behind never holds this loop
    away from zenoh (``monitor_output``, the stall of issue 41)."""
    lines: list[str] = []
    """Handed over once per batch (one write and flush per batch whatever stdout's buffering:
    PYTHONUNBUFFERED made each line a system call, a third of the monitor's time at 1,000
    cars)."""
    try:
        for event in _events(client, deadline, stop):
            line = None if event is None else _json_line(client, view, event)
            if line is not None:
                lines.append(json.dumps(line, separators=(",", ":")))
            for vid in view.take_alarm_changes():
                lines.append(json.dumps(alarm_line(view, vid), separators=(",", ":")))
            if lines and not client.pending():
                writer.put("\n".join(lines) + "\n")
                lines.clear()
            if writer.broken or (args.count is not None and view.messages >= args.count):
                break
        if lines:
            writer.put("\n".join(lines) + "\n")
    finally:
        writer.close()
    if writer.broken:  # e.g. piped into head: silence the exit-time flush
        with contextlib.suppress(OSError):
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115
    if args.snapshot is not None:
        write_snapshot(view, args.snapshot)
    return 0 if view.messages else _no_messages(client, args.timeout)


def _run_live(client: MonitorClient, args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    console = Console(stderr=False)
    view = FleetView()
    stop = threading.Event()
    snap = threading.Event()
    deadline = None if args.timeout is None else time.monotonic() + args.timeout
    snapshot_path: Path = args.snapshot or Path(
        f"guidance-monitor-{time.strftime('%Y%m%d-%H%M%S')}.png"
    )
    title = f"guidance monitor: {', '.join(client.connect)}"
    client.query_latest()

    def on_usr1(_sig: int, _frame: FrameType | None) -> None:
        snap.set()

    old_usr1 = signal.signal(signal.SIGUSR1, on_usr1) if hasattr(signal, "SIGUSR1") else None
    status = ""
    try:
        with (
            _keys() as read_key,
            Live(
                render_table(view, time.monotonic(), title),
                console=console,
                auto_refresh=False,  # drawn here, between events: never while one is folded
                transient=False,
            ) as live,
        ):
            next_draw = 0.0
            for event in _events(client, deadline, stop):
                if event is not None:
                    if event.kind == "alive" and event.vehicle_id not in view.cars:
                        client.query_latest(event.vehicle_id)
                    view.apply(event)
                    if args.count is not None and view.messages >= args.count:
                        stop.set()
                key = read_key()
                if key in ("q", "Q"):
                    stop.set()
                elif key in ("s", "S"):
                    snap.set()
                if snap.is_set():
                    snap.clear()
                    status = f"snapshot written: {write_snapshot(view, snapshot_path)}"
                now = time.monotonic()
                if now >= next_draw or stop.is_set():
                    live.update(render_table(view, now, title, status), refresh=True)
                    drawn = time.monotonic()
                    next_draw = drawn + max(DRAW_EVERY_S, (drawn - now) / DRAW_SHARE)
    finally:
        if old_usr1 is not None:
            signal.signal(signal.SIGUSR1, old_usr1)
    if args.snapshot is not None:
        console.print(f"snapshot written: {write_snapshot(view, args.snapshot)}")
    if deadline is not None or args.count is not None:
        return 0 if view.messages else _no_messages(client, args.timeout)
    return 0


@contextlib.contextmanager
def _keys() -> Iterator[Any]:
    """Single key presses from a terminal without waiting for Enter; no-op when not a TTY."""
    stdin = sys.stdin
    if stdin is None or not stdin.isatty():
        yield lambda: None
        return
    import termios
    import tty

    fd = stdin.fileno()
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)

        def read_key() -> str | None:
            ready, _, _ = select.select([fd], [], [], 0)
            return os.read(fd, 1).decode(errors="replace") if ready else None

        yield read_key
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
