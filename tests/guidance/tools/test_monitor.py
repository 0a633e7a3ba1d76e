"""``guidance monitor``: fleet view, snapshot PNG, and the command against a live publisher."""

from __future__ import annotations

import io
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from rich.cells import cell_len

from guidance.telemetry.client import TelemetryEvent
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
from guidance.tools.monitor import (
    FleetView,
    car_row,
    compass_deg,
    health_summary,
    render_table,
    write_snapshot,
)

REPO = Path(__file__).resolve().parents[3]

PUBLISHER = r"""
import math, sys, time
from guidance.core.messages import Ellipse, EstimateState, Health, Prompt, Target
from guidance.outputs.kinds import HEALTH, PROMPT, STATE, HealthReport, OutputContext
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
port, vid = int(sys.argv[1]), sys.argv[2]
tel = Telemetry(TelemetryConfig(vehicle_id=vid, listen=(f"tcp/127.0.0.1:{port}",)))
tel.start()
i, next_t = 0, time.monotonic()
while True:
    t = i * 0.02
    a = 3.0 + t
    cov = ((a * a / 4, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.01))
    st = EstimateState(t, 10.0 * t, 5.0 * math.sin(t), 0.3, cov, Ellipse(a, 1.0, 0.2, 2 * a),
                       False, True)
    ctx = OutputContext(speed_mps=10.0, target=Target(300.0, 0.0), goal=(300.0, 0.0))
    tel.send(STATE, st, ctx)
    if i % 25 == 0:
        tel.send(PROMPT, Prompt(t, f"In 200 metres, turn left ({i})", 0, "turn"))
        odometry = Health("odometry", "ok", True, True, 0.02, rate_hz=50.0)
        tel.send(HEALTH, HealthReport(t, {"odometry": odometry}))
    i += 1
    next_t += 0.02
    time.sleep(max(0.0, next_t - time.monotonic()))
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def publisher() -> Iterator[Callable[[str], int]]:
    procs: list[subprocess.Popen[bytes]] = []

    def start(vehicle_id: str = "car1") -> int:
        port = free_port()
        procs.append(
            subprocess.Popen(
                [sys.executable, "-c", PUBLISHER, str(port), vehicle_id],
                cwd=REPO,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        return port

    yield start
    for p in procs:
        p.kill()
        p.wait(5)


def monitor(*args: str, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


# -- fleet view (no zenoh) -----------------------------------------------------------------------
def event(
    kind: str, vid: str = "car1", late: bool = False, at: float = 100.0, **msg: Any
) -> TelemetryEvent:
    return TelemetryEvent(kind, vid, f"guidance/{vid}/{kind}", msg or None, at, late)


def state(seq: int, x: float, y: float, t_s: float) -> dict[str, Any]:
    return {
        "seq": seq,
        "t_s": t_s,
        "x_m": x,
        "y_m": y,
        "heading_rad": math.pi / 2,
        "heading_deg": 90.0,
        "lost": False,
        "ellipse": {
            "semi_major_m": 5.0,
            "semi_minor_m": 2.0,
            "orientation_rad": 0.0,
            "major_axis_m": 10.0,
        },
        "target": {"x_m": x + 30.0, "y_m": y + 40.0, "kind": "landmark", "id": 2},
        "goal": {"x_m": 500.0, "y_m": 500.0},
    }


def test_fleet_view_rows_gaps_late_join_and_vanishing_cars() -> None:
    view = FleetView()
    view.apply(event("alive"))
    view.apply(event("state", at=100.0, **state(1, 0.0, 0.0, 0.0)))
    view.apply(event("state", at=101.0, **state(4, 10.0, 0.0, 12.0)))  # 2 and 3 lost
    assert not view.apply(event("state", late=True, **state(4, 10.0, 0.0, 12.0)))  # duplicate
    view.apply(event("prompt", at=101.0, seq=1, t_s=12.0, text="Turn right"))
    view.apply(
        event(
            "health",
            at=101.0,
            seq=1,
            t_s=12.0,
            ok=False,
            inputs={
                "compass": {"alive": False, "valid": False},
                "odometry": {"alive": True, "valid": True},
            },
            components={"telemetry": {"counters": {"dropped": 3, "dropped_superseded": 3}}},
        )
    )
    car = view.cars["car1"]
    assert car.gaps == 2 and list(car.track) == [(0.0, 0.0), (10.0, 0.0)]
    assert len(car.ellipses) == 2  # t_s 0 and 12 are more than 10 s apart
    row = car_row(car, now_s=103.5)
    assert row["x_m"] == "10.0" and row["major_axis_m"] == "10.0"
    assert row["compass_deg"] == "0"  # heading_rad pi/2 (north, CCW from east): compass 0
    assert row["distance_m"] == "50" and row["target"] == "landmark (40, 40)"
    assert row["prompt"] == "Turn right" and row["age_s"] == "2.5"
    assert row["health"] == "compass down (3 dropped)"
    view.apply(event("gone"))
    assert "car1" not in view.cars and "car1" in view.gone
    view.apply(event("alive"))
    assert view.cars["car1"].track  # a car that comes back keeps its track


def test_a_track_keeps_a_point_every_two_metres_and_ends_at_the_newest_position() -> None:
    """States 0.5 m apart: the track keeps one point each TRACK_STEP_M (2 m), its last point
    is always the newest position, and ``track_since`` gives what was written after a
    generation (the replaced newest point included), with the car's index of the first."""
    from guidance.tools.monitor_view import TRACK_STEP_M

    assert TRACK_STEP_M == 2.0
    view = FleetView()
    for i in range(11):  # x = 0, 0.5, ... 5.0
        view.apply(event("state", at=100.0 + i, **state(i + 1, 0.5 * i, 0.0, float(i))))
    car = view.cars["car1"]
    assert list(car.track) == [(0.0, 0.0), (2.0, 0.0), (4.0, 0.0), (5.0, 0.0)]
    assert car.track_total == 4 and view.generation == 11
    start, points = car.track_since(10)  # only the newest position was written after 10
    assert (start, points) == (3, [(5.0, 0.0)])
    generation = view.generation
    view.apply(event("state", at=112.0, **state(12, 5.5, 0.0, 11.0)))  # replaces (5, 0)
    view.apply(event("state", at=113.0, **state(13, 6.5, 0.0, 12.0)))  # 2.5 m on: kept
    assert car.track_since(generation) == (3, [(6.5, 0.0)])
    assert car.track_since(view.generation) == (4, [])
    assert car.track_since(0) == (0, list(car.track))


def test_health_summary_without_health() -> None:
    assert health_summary(None) == "-"
    assert health_summary({"inputs": {"cam": {"alive": True, "valid": False}}}) == "cam invalid"


def test_compass_heading_is_clockwise_from_north() -> None:
    # The messages' heading is counter-clockwise from east; people read compass headings.
    assert compass_deg(0.0) == 90.0  # east
    assert compass_deg(math.pi / 2) == 0.0  # north
    assert compass_deg(math.pi) == 270.0  # west
    assert compass_deg(-math.pi / 2) == 180.0  # south
    assert compass_deg(math.radians(60.0)) == pytest.approx(30.0)  # north-east-ish
    assert compass_deg(math.radians(90.2)) == 0.0  # 359.8 is shown as 0, never "360"


HOSTILE_PROMPT = "In 200 metres, turn [bold red]left[/] \x1b[31mnow\x1b[0m\x07 [/]\nthen (25)"


def awkward_fleet() -> FleetView:
    """Long numbers, a lost car, a long health line and a prompt full of markup and escapes."""
    view = FleetView()
    s1 = state(1, -12345.678, 21.34, 1.0)
    s1["heading_rad"], s1["target"] = 0.3, {"x_m": 300.0, "y_m": 0.0, "kind": "goal", "id": None}
    s1["chance"] = 0.42
    view.apply(event("state", "car1", **s1))
    view.apply(event("prompt", "car1", seq=1, t_s=1.0, text=HOSTILE_PROMPT))
    view.apply(
        event(
            "health",
            "car1",
            seq=1,
            t_s=1.0,
            inputs={"compass": {"alive": False}, "camera": {"alive": True, "valid": False}},
            components={"telemetry": {"counters": {"dropped": 3, "dropped_superseded": 3}}},
        )
    )
    s2 = state(1, 1.0, 2.0, 1.0)
    s2["heading_rad"], s2["lost"] = -1.2, True
    s2["ellipse"] = {**s2["ellipse"], "major_axis_m": 123.4}
    view.apply(event("state", "van-7", **s2))
    return view


def rendered(view: FleetView, width: int, terminal: bool) -> str:
    from rich.console import Console

    out = io.StringIO()
    console = Console(file=out, width=width, force_terminal=terminal, color_system=None)
    console.print(render_table(view, 102.5, "guidance monitor: tcp/127.0.0.1:7447"))
    return out.getvalue()


EXPECTED_FIELDS = (
    # every value whole, with its label and unit: a split number fails one of these
    "x -12345.7 m",
    "y 21.3 m",
    "hdg 73°",  # 0.3 rad CCW from east
    "axis 10.0 m",
    "chance 40 %",
    "to goal (300, 0): 12646 m",
    "age 2.5 s",
    "health: camera invalid, compass down (3 dropped)",
    "x 1.0 m",
    "hdg 159°",  # -1.2 rad
    "axis 123.4 m LOST",
)


@pytest.mark.parametrize("terminal", [True, False], ids=["tty", "piped"])
def test_80_columns_and_piped_output_never_split_a_number(terminal: bool) -> None:
    text = rendered(awkward_fleet(), 80, terminal)
    lines = text.splitlines()
    assert all(len(line) <= 80 for line in lines), text
    assert "…" not in text and "hdg: compass heading, degrees clockwise from north" in text
    for f in EXPECTED_FIELDS:
        assert f in text, f"{f!r} not whole in:\n{text}"
    # One block per car: it starts with the car id, its other lines are indented.
    starts = [line.split()[0] for line in lines[2:] if not line.startswith(" ")]
    assert starts == ["car1", "van-7"], text
    # The prompt is plain text: markup shown as typed, escapes and control characters gone.
    assert 'prompt: "In 200 metres, turn [bold red]left[/] now [/] then (25)"' in " ".join(
        line.strip() for line in lines
    )
    assert "\x1b" not in text and "\x07" not in text and "[31m" not in text


def test_wide_terminal_gets_the_table_with_whole_numbers() -> None:
    text = rendered(awkward_fleet(), 200, True)
    assert "major axis m" in text and "last prompt" in text and "┃ car" in text
    assert "clockwise from north" in text and "…" not in text
    car1 = next(line for line in text.splitlines() if line.startswith("│ car1"))
    cells = [c.strip() for c in car1.strip("│").split("│")]
    assert cells[:9] == [
        "car1",
        "-12345.7",
        "21.3",
        "73",
        "10.0",
        "40 %",
        "goal (300, 0)",
        "12646",
        "2.5",
    ]
    assert "[bold red]left[/]" in text and "\x1b" not in text
    # Narrower than the table needs: the per-car layout, not a squeezed table.
    narrow = rendered(awkward_fleet(), 120, True)
    assert "┃" not in narrow and all(f in narrow for f in EXPECTED_FIELDS)


def test_markup_in_a_prompt_is_never_interpreted_even_in_colour() -> None:
    from rich.console import Console

    view = FleetView()
    view.apply(event("state", "car1", **state(1, 0.0, 0.0, 0.0)))
    view.apply(event("prompt", "car1", seq=1, t_s=0.0, text="[/] [link=http://x]go[/link]"))
    for width in (80, 200):
        out = io.StringIO()
        console = Console(file=out, width=width, force_terminal=True, color_system="truecolor")
        console.print(render_table(view, 100.0, "t"))  # markup parsing would raise on "[/]"
        text = out.getvalue()
        assert "[link=http://x]go[/link]" in text and "\x1b]8;" not in text  # no hyperlink


def test_an_empty_fleet_says_so() -> None:
    assert "(no car seen yet)" in rendered(FleetView(), 80, False)
    assert "(no car seen yet)" in rendered(FleetView(), 200, True)


def test_snapshot_png_has_tracks_and_labelled_axes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import matplotlib.figure

    view = FleetView()
    for vid, dy in (("car1", 0.0), ("car2", 50.0)):
        view.apply(event("alive", vid))
        for i in range(30):
            view.apply(event("state", vid, **state(i + 1, 10.0 * i, dy + i, 1.0 * i)))
    view.apply(event("gone", "car2"))
    saved: list[matplotlib.figure.Figure] = []
    real_savefig = matplotlib.figure.Figure.savefig

    def spy(self: matplotlib.figure.Figure, *a: Any, **k: Any) -> None:
        saved.append(self)
        real_savefig(self, *a, **k)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    path = write_snapshot(view, tmp_path / "snap" / "tracks.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000
    ax = saved[0].axes[0]
    assert ax.get_xlabel() == "x east (m)" and ax.get_ylabel() == "y north (m)"
    legend = ax.get_legend()
    assert legend is not None
    labels = [t.get_text() for t in legend.get_texts()]
    assert {"car1 track", "car2 (gone) track", "2-sigma ellipse", "target", "goal"} <= set(labels)


# -- the command ---------------------------------------------------------------------------------
def test_json_count_prints_messages_and_exits_0(
    publisher: Callable[[str], int], tmp_path: Path
) -> None:
    port = publisher("van7")
    png = tmp_path / "tracks.png"
    r = monitor(
        "--connect",
        f"tcp/127.0.0.1:{port}",
        "--json",
        "--count",
        "20",
        "--timeout",
        "20",
        "--snapshot",
        str(png),
    )
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    data = [m for m in lines if m["schema"] != "guidance.liveliness/1"]
    assert len(data) == 20
    assert {"schema": "guidance.liveliness/1", "vehicle_id": "van7", "alive": True} in lines
    states = [m for m in data if m["schema"] == "guidance.state/1"]
    assert states and all(m["vehicle_id"] == "van7" for m in data)
    assert {"x_m", "y_m", "heading_deg", "ellipse", "target", "t_s"} <= set(states[0])
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_vehicle_filter_and_timeout_with_nothing_exits_1(publisher: Callable[[str], int]) -> None:
    port = publisher("car1")
    r = monitor(
        "--connect", f"tcp/127.0.0.1:{port}", "--vehicle", "car2", "--json", "--timeout", "1.5"
    )
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr.startswith("guidance monitor: no messages received from")
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_bad_endpoint_is_one_clear_line() -> None:
    r = monitor("--connect", "127.0.0.1:7447", "--json", "--timeout", "1")
    assert r.returncode == 2
    assert r.stderr.strip() == (
        "guidance monitor: error: bad zenoh endpoint '127.0.0.1:7447': expected "
        "<protocol>/<address>, e.g. tcp/127.0.0.1:7447 or tls/localhost:7447"
    )
    r = monitor("--connect", "tcp/127.0.0.1:7447", "--zenoh-config", "/nonexistent.json5")
    assert r.returncode == 2 and "zenoh config file not found" in r.stderr
    assert "Traceback" not in r.stderr


def catches_sigusr1(pid: int) -> bool:
    """The process has a handler for SIGUSR1 (the SigCgt mask in /proc/PID/status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    for line in status.splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (signal.SIGUSR1 - 1)))
    return False


def test_live_view_table_and_sigusr1_snapshot(
    publisher: Callable[[str], int], tmp_path: Path
) -> None:
    port = publisher("car1")
    png = tmp_path / "live.png"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "guidance.tools.cli",
            "monitor",
            "--connect",
            f"tcp/127.0.0.1:{port}",
            "--timeout",
            "15",
            "--snapshot",
            str(png),
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "80"},  # piped, 80 columns
    )
    try:
        # Signal only once the handler is installed (SIGUSR1 would otherwise end the process):
        # the start-up time of `guidance` depends on what its subcommands import.
        deadline = time.monotonic() + 12.0
        while not catches_sigusr1(proc.pid):
            assert time.monotonic() < deadline and proc.poll() is None, "monitor did not start"
            time.sleep(0.05)
        time.sleep(1.0)  # let some messages arrive (the monitor runs 15 s from here)
        # a snapshot is a matplotlib figure drawn and saved: about a second here, several on a
        # loaded machine (a CI run beside two spinning processes waited out 2.5 s)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not png.exists():
            os.kill(proc.pid, signal.SIGUSR1)  # ask for a snapshot while it runs
            time.sleep(0.3)
        assert png.exists() and proc.poll() is None, "no snapshot on SIGUSR1"
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "snapshot written" in out and "degrees clockwise from north" in out
    assert all(len(line) <= 80 for line in out.splitlines()) and "…" not in out, out
    # Piped: one block per car, every value whole with its label and unit.
    block = out[out.index("\ncar1 ") :]
    for pattern in (
        r"x -?\d+\.\d m",
        r"y -?\d+\.\d m",
        r"hdg \d{1,3}°",
        r"axis \d+\.\d m",
        r"to goal \(300, 0\): \d+ m",
        r"age \d+\.\d s",
        r"health: ok",
        r'prompt: "In 200 metres, turn left \(\d+\)"',
    ):
        assert re.search(pattern, block), f"{pattern} not whole in:\n{out}"


def test_send_goal_reaches_a_car_that_allows_it(loopback_acl: str) -> None:
    port = free_port()
    goals: list[tuple[float, float]] = []
    cfg = TelemetryConfig(
        vehicle_id="car3",
        listen=(f"tcp/127.0.0.1:{port}",),
        allow_remote_goal=True,
        zenoh_config=loopback_acl,
    )
    with Telemetry(cfg, on_goal=lambda x, y: goals.append((x, y))):
        r = monitor(
            "--connect", f"tcp/127.0.0.1:{port}", "--vehicle", "car3", "--send-goal", "120", "-45.5"
        )
    assert r.returncode == 0, r.stderr
    assert goals == [(120.0, -45.5)]
    r = monitor("--connect", f"tcp/127.0.0.1:{port}", "--send-goal", "1", "2")
    assert r.returncode == 2 and "--send-goal needs --vehicle ID" in r.stderr


def test_send_goal_to_a_car_that_does_not_listen_says_so() -> None:
    """A car without remote goals declares no goal subscription: the goal is not put and the
    operator is told why, instead of "sent"."""
    port = free_port()
    cfg = TelemetryConfig(vehicle_id="car6", listen=(f"tcp/127.0.0.1:{port}",))
    with Telemetry(cfg):
        r = monitor(
            "--connect", f"tcp/127.0.0.1:{port}", "--vehicle", "car6", "--timeout", "2",
            "--send-goal", "120", "-45.5",
        )  # fmt: skip
    assert r.returncode == 1, r.stdout
    assert "goal not sent: no car 'car6' listening for remote goals" in r.stderr
    assert "allow_remote_goal = true" in r.stderr and "Traceback" not in r.stderr


def fleet_with_a_gone_car() -> FleetView:
    """Three cars with a goal, health and a long prompt; car2 then loses its liveliness token."""
    view = FleetView()
    for i, vid in enumerate(("car1", "car2", "car3")):
        s = state(1, 100.0 * i + 0.5, 20.25, 1.0)
        s["target"] = {"x_m": 300.0, "y_m": 0.0, "kind": "goal", "id": None}
        view.apply(event("state", vid, **s))
        inputs = {"compass": {"alive": True, "valid": True}}
        components = {"telemetry": {"counters": {"dropped": 31}}}
        view.apply(event("health", vid, seq=1, t_s=1.0, inputs=inputs, components=components))
        text = "In 200 metres, at the roundabout, take the second exit"
        view.apply(event("prompt", vid, seq=1, t_s=1.0, text=text))
    gone = event("gone", "car2")
    view.apply(TelemetryEvent("gone", "car2", gone.key, None, 96.0))
    return view


@pytest.mark.parametrize("width", [80, 100, 120, 132, 160])
def test_a_gone_car_stays_as_a_gone_row_and_the_view_fits_the_terminal(width: int) -> None:
    text = rendered(fleet_with_a_gone_car(), width, True)
    lines = text.splitlines()
    assert all(cell_len(line) <= width for line in lines), f"wider than {width}:\n{text}"
    flat = " ".join(line.strip(" │") for line in lines)
    assert "car1" in flat and "car3" in flat and "car2" in flat and "GONE" in flat, text
    assert "100.5" in text  # car2's last x
    # when it went (96.0 on the monitor's clock, drawn at 102.5) and that its position is its last
    view = fleet_with_a_gone_car()
    row = car_row(view.gone["car2"], 102.5)
    assert row["health"] == "GONE 6 s ago: liveliness token dropped (last position)"
    assert row["x_m"] == "100.5" and not row["health"].startswith("ok")
    assert text.index("car3") < text.index("car2")  # live cars first, then the gone ones
    words = " ".join(flat.split())  # "(31 dropped)" is explained on the screen that shows it
    assert "(31 dropped)" in words and "dropped: messages the car made but did not send" in words


@pytest.mark.parametrize("width", [80, 160])
def test_a_thousand_cars_fill_the_terminal_those_needing_a_look_first(width: int) -> None:
    """1,000 cars on a terminal of 30 lines: no more lines than that, the count of the cars not
    shown, and first the ones needing a look (gone, then lost), not car0000-car0020."""
    from rich.console import Console

    view = FleetView()
    for i in range(1000):
        s = state(1, float(i), 0.0, 1.0)
        if i == 700:
            s["lost"] = True
        view.apply(event("state", f"car{i:04d}", **s))
    view.apply(TelemetryEvent("gone", "car0500", "guidance/car0500", None, 96.0))
    out = io.StringIO()
    console = Console(file=out, width=width, height=30, force_terminal=True, color_system=None)
    console.print(render_table(view, 102.5, "guidance monitor"))
    text = out.getvalue()
    assert len(text.splitlines()) <= 30, text
    assert "car0500" in text and "GONE" in text and "car0700" in text, text
    assert text.index("car0500") < text.index("car0700") < text.index("car0000"), text
    shown = len(set(re.findall(r"car\d{4}", text)))
    assert f"{1000 - shown} more cars not shown" in " ".join(text.split()), text


def fleet_without_prompts() -> FleetView:
    """Short values everywhere and no prompt: the last column's header is its widest cell."""
    view = FleetView()
    for i in range(3):
        view.apply(event("state", f"car4761{i}", **state(1, 1500.0 * i + 101.0, 0.0, 1.0)))
    return view


@pytest.mark.parametrize("width", range(60, 200, 3))
def test_the_table_is_never_wider_than_the_terminal(width: int) -> None:
    """Never cut at the right edge (the console crops what is wider, so a cut table's lines
    are no longer than the screen but lose their right border): the table's every line ends
    with a border, or the per-car layout is used."""
    for view in (fleet_with_a_gone_car(), awkward_fleet(), fleet_without_prompts()):
        text = rendered(view, width, True)
        lines = text.splitlines()
        assert all(cell_len(line) <= width for line in lines), text
        if "┏" in text:
            top = next(i for i, line in enumerate(lines) if "┏" in line)
            bottom = next(i for i, line in enumerate(lines) if "└" in line)
            assert all(line.rstrip()[-1] in "┓┃┩│┘" for line in lines[top : bottom + 1]), text


def test_json_says_when_a_killed_car_went_and_where_it_last_was() -> None:
    """Two cars; car2 is killed with SIGKILL: --json prints its alive:false line with how long
    since its last message and its last position (the last state it printed)."""
    ports = {"car1": free_port(), "car2": free_port()}
    cars = {
        vid: subprocess.Popen(
            [sys.executable, "-c", PUBLISHER, str(port), vid],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for vid, port in ports.items()
    }
    connect = [a for p in ports.values() for a in ("--connect", f"tcp/127.0.0.1:{p}")]
    mon = subprocess.Popen(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", *connect, "--json", "--timeout=30"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    lines: list[dict[str, Any]] = []
    try:
        assert mon.stdout is not None
        killed = False
        for text in mon.stdout:
            line = json.loads(text)
            lines.append(line)
            states = [m for m in lines if m["schema"] == "guidance.state/1"]
            if not killed and {m["vehicle_id"] for m in states} == set(ports) and len(states) > 40:
                cars["car2"].send_signal(signal.SIGKILL)
                killed = True
            if line["schema"] == "guidance.liveliness/1" and not line["alive"]:
                break
    finally:
        for p in (*cars.values(), mon):
            p.kill()
            p.wait(10)
    gone = lines[-1]
    assert gone["vehicle_id"] == "car2" and gone["alive"] is False, lines[-3:]
    last = [m for m in lines if m["schema"] == "guidance.state/1" and m["vehicle_id"] == "car2"][-1]
    assert gone["last_position"] == {k: last[k] for k in ("t_s", "x_m", "y_m", "lat_deg",
                                                          "lon_deg")}  # fmt: skip
    assert 0.0 <= gone["last_message_s_ago"] < 5.0
