"""Malformed telemetry never ends a monitor (issue 14, item 8): a rogue peer on loopback
publishes messages of the wrong shape (``ellipse`` as a list, health ``inputs`` as a list,
``x_m`` of 10^400, NaN, deep nesting, terminal escapes and rich markup in a prompt) among good
ones. ``guidance monitor --json``, the live view and the web page's fleet data go on; each
bad message is counted and shown as such, and no NaN, infinity or 400-digit number is shown.
Real zenoh sessions on 127.0.0.1 with multicast scouting off, a real monitor process."""

from __future__ import annotations

import io
import json
import re
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rich.console import Console

from guidance.telemetry.client import MonitorClient, TelemetryEvent
from guidance.tools.monitor_view import FleetView, car_row, render_table
from guidance.tools.web.server import car_json

REPO = Path(__file__).resolve().parents[2]

GOOD_STATE = (
    '{"schema":"guidance.state/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"x_m":12.5,'
    '"y_m":-3.0,"heading_rad":0.5,"ellipse":{"semi_major_m":4.0,"semi_minor_m":2.0,'
    '"orientation_rad":0.1,"major_axis_m":8.0},"lost":false,"healthy":true}'
)
ESCAPES = "\x1b]0;pwned\x07\x1b[2J\x1b[31m[bold red]BOOM[/bold red]\u202e"
HOSTILE: list[tuple[str, str]] = [
    (
        "state",
        GOOD_STATE.replace('"ellipse":{', '"ellipse":[').replace('8.0},"lost"', '8.0],"lost"'),
    ),
    ("state", GOOD_STATE.replace('"x_m":12.5', '"x_m":1' + "0" * 400)),
    ("state", GOOD_STATE.replace('"x_m":12.5', '"x_m":NaN')),
    ("state", GOOD_STATE.replace('"y_m":-3.0', '"y_m":-Infinity')),
    ("state", GOOD_STATE.replace('"lost":false', '"target":"over there"')),
    ("state", GOOD_STATE.replace('"t_s":1.0', '"t_s":[' * 200 + "]" * 200)),
    (
        "health",
        '{"schema":"guidance.health/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"ok":true,'
        '"inputs":["odometry","compass"]}',
    ),
    (
        "health",
        '{"schema":"guidance.health/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"ok":true,'
        '"inputs":{"odometry":"fine"}}',
    ),
    (
        "health",
        '{"schema":"guidance.health/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"ok":true,'
        '"inputs":{},"components":{"telemetry":{"dropped":{"state":1e400}}}}',
    ),
    ("prompt", '{"schema":"guidance.prompt/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"text":{}}'),
    (
        "prompt",
        '{"schema":"guidance.prompt/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"text":"'
        + "x" * 10_000
        + '"}',
    ),
    ("decision", '{"schema":"guidance.decision/1","vehicle_id":"car1","seq":SEQ,"options":7}'),
]
GOOD: list[tuple[str, str]] = [
    ("state", GOOD_STATE),
    (
        "prompt",
        '{"schema":"guidance.prompt/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"text":'
        + json.dumps("Turn left " + ESCAPES)
        + "}",
    ),
    (
        "health",
        '{"schema":"guidance.health/1","vehicle_id":"car1","seq":SEQ,"t_s":1.0,"ok":true,'
        '"inputs":{"odometry":{"alive":true,"valid":true,"rate_hz":50.0}},'
        '"components":{"telemetry":{"dropped":"many"},"weird":[1,2]}}',
    ),
]

ROGUE = r"""
import json, sys, time, zenoh
from guidance.telemetry.session import open_session, session_config
port, cases = int(sys.argv[1]), json.loads(sys.argv[2])
s = open_session(session_config(mode="peer", listen=[f"tcp/127.0.0.1:{port}"]))
token = s.liveliness().declare_token("guidance/car1")
seq = 0
while True:
    for kind, text in cases:
        seq += 1
        s.put(f"guidance/car1/{kind}", text.replace("SEQ", str(seq)).encode())
        time.sleep(0.01)
"""


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture
def rogue() -> Iterator[int]:
    """A peer publishing the hostile messages, then the good ones, over and over."""
    port = _free_port()
    cases = json.dumps([*HOSTILE, *GOOD])
    proc = subprocess.Popen(
        [sys.executable, "-c", ROGUE, str(port), cases],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        yield port
    finally:
        proc.kill()
        proc.wait(5)


def _strict_json(line: str) -> object:
    def refuse(name: str) -> float:
        raise AssertionError(f"{name} in {line[:80]}")

    return json.loads(line, parse_constant=refuse)


def _no_huge_or_non_finite(text: str) -> None:
    assert not re.search(r"\d{20}", text), text
    assert not re.search(r"\b(nan|inf|infinity)\b", text, re.I), text


def test_the_fleet_view_live_table_and_web_data_survive_hostile_messages(rogue: int) -> None:
    view = FleetView()
    client = MonitorClient([f"tcp/127.0.0.1:{rogue}"])
    with client:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not (
            view.bad_messages >= 2 * len(HOSTILE) and view.messages >= 2 * len(GOOD)
        ):
            event = client.get(0.2)
            if event is not None:
                view.apply(event)  # before: AttributeError, OverflowError, TypeError...
    assert view.bad_messages >= 2 * len(HOSTILE) and view.messages >= 2 * len(GOOD)
    car = view.cars["car1"]
    assert car.bad_messages == view.bad_messages
    row = car_row(car, time.monotonic())
    assert row["x_m"] == "12.5" and row["y_m"] == "-3.0"
    assert "bad message" in row["health"]
    assert "BOOM" in row["prompt"] and "\x1b" not in row["prompt"] and "pwned" not in row["prompt"]
    for width, terminal in ((80, False), (80, True), (250, True)):
        buf = io.StringIO()
        console = Console(file=buf, width=width, force_terminal=terminal, color_system="standard")
        console.print(render_table(view, time.monotonic(), "guidance monitor"))
        text = re.sub(r"\x1b\[[0-9;]*m", "", buf.getvalue())  # rich's own colours
        assert "\x1b" not in text and "pwned" not in text and "\u202e" not in text
        assert "[bold red]BOOM" in text  # markup shown as text, never interpreted
        assert "bad messages left out" in text
        _no_huge_or_non_finite(text)
    web = json.dumps(car_json(car, time.monotonic()), allow_nan=False)  # the page's JSON
    _no_huge_or_non_finite(web)
    assert '"bad_messages":' in web.replace(" ", "")


def test_monitor_json_keeps_going_and_prints_only_good_finite_messages(rogue: int) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", "--connect",
         f"tcp/127.0.0.1:{rogue}", "--json", "--count", "30", "--timeout", "20"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    lines = [_strict_json(line) for line in r.stdout.splitlines()]
    data = [m for m in lines if isinstance(m, dict) and m.get("schema") != "guidance.liveliness/1"]
    assert len(data) == 30
    assert {m["schema"] for m in data} <= {
        "guidance.state/1",
        "guidance.prompt/1",
        "guidance.health/1",
    }
    for m in data:
        if m["schema"] == "guidance.state/1":
            assert m["x_m"] == 12.5 and isinstance(m["ellipse"], dict)
    _no_huge_or_non_finite(r.stdout)


def test_the_live_view_keeps_drawing(rogue: int, tmp_path: Path) -> None:
    """The live view, piped (its per-car layout), for 3 s of hostile traffic: it ends on
    its timeout, not on a traceback, and what it drew has no raw escape."""
    r = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", "--connect",
         f"tcp/127.0.0.1:{rogue}", "--timeout", "4"],
        cwd=REPO, capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert "car1" in r.stdout and "bad message" in r.stdout
    assert "pwned" not in r.stdout and "\x07" not in r.stdout
    _no_huge_or_non_finite(r.stdout)


JSON_LEAVES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.floats(),  # NaN and infinities included
    st.text(max_size=20),
    st.sampled_from(["\x1b[2J", "[bold]x[/bold]", "\u202e", "\n\r\t"]),
)
JSON_VALUES = st.recursive(
    JSON_LEAVES,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=12), inner, max_size=4)
    ),
    max_leaves=20,
)
FIELDS = {
    "state": [
        "x_m",
        "y_m",
        "heading_rad",
        "heading_deg",
        "ellipse",
        "target",
        "goal",
        "lost",
        "t_s",
        "seq",
    ],
    "health": ["inputs", "components", "ok", "seq"],
    "prompt": ["text", "kind", "priority", "seq"],
    "decision": ["options", "target", "exit_index"],
}


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    kind=st.sampled_from(sorted(FIELDS)),
    data=st.data(),
)
def test_fuzzed_messages_never_crash_the_view_or_show_a_non_finite_number(
    kind: str, data: st.DataObject
) -> None:
    """In process (no zenoh): any JSON value at any field the display reads."""
    msg: dict[str, object] = {"schema": f"guidance.{kind}/1", "vehicle_id": "car1", "t_s": 1.0}
    for field in data.draw(st.lists(st.sampled_from(FIELDS[kind]), min_size=1, max_size=4)):
        msg[field] = data.draw(JSON_VALUES)
    view = FleetView()
    view.apply(TelemetryEvent(kind, "car1", f"guidance/car1/{kind}", msg, 0.0))
    car = view.cars["car1"]
    row = car_row(car, 1.0)
    for width in (80, 200):
        buf = io.StringIO()
        Console(file=buf, width=width, force_terminal=False).print(render_table(view, 1.0, "m"))
        text = buf.getvalue() + json.dumps(row)
        assert "\x1b" not in text
        _no_huge_or_non_finite(text.replace("is not a finite number", ""))
    json.dumps(car_json(car, 1.0), allow_nan=False)
