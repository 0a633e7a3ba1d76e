"""Issue 23, item 1: a rogue Zenoh peer whose keys carry an invalid vehicle id (``a b``, ``<x>``,
65 characters, a newline) is one dropped, counted sample where events are made
(``MonitorClient``), never an error of a monitor: ``guidance monitor --json``, the live table and
``--web`` go on serving the good car. Real Zenoh sessions on 127.0.0.1, multicast scouting off;
the monitors run as real processes where they are commands."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from guidance.core.messages import Ellipse, EstimateState
from guidance.outputs.kinds import STATE
from guidance.telemetry.client import MonitorClient, TelemetryEvent
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
from guidance.telemetry.session import open_session, session_config
from guidance.tools.web.server import WebMonitor

REPO = Path(__file__).resolve().parents[2]
BAD_IDS = ("a b", "<x>", "a" * 65, "car\n1")
COV = ((4.0, 0.0, 0.0), (0.0, 4.0, 0.0), (0.0, 0.0, 0.01))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def tcp(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def state_body(vid: str, seq: int) -> bytes:
    body = {"schema": "guidance.state/1", "vehicle_id": vid, "seq": seq, "t_s": seq * 0.1,
            "x_m": 1.0, "y_m": 2.0}  # fmt: skip
    return json.dumps(body).encode()


class Fleet:
    """A good car (the real ``Telemetry``, publishing a state every 50 ms) and a rogue peer
    (a bare session) holding liveliness tokens and putting states under invalid ids."""

    def __init__(self) -> None:
        self.car_port, self.rogue_port = free_port(), free_port()
        self.car = Telemetry(TelemetryConfig(vehicle_id="good", listen=(tcp(self.car_port),)))
        self.rogue = open_session(session_config(mode="peer", listen=[tcp(self.rogue_port)]))
        self.tokens = [self.rogue.liveliness().declare_token(f"guidance/{v}") for v in BAD_IDS]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fleet", daemon=True)

    @property
    def connect(self) -> list[str]:
        return [tcp(self.car_port), tcp(self.rogue_port)]

    def _run(self) -> None:
        i = 0
        while not self._stop.wait(0.05):
            i += 1
            est = EstimateState(i * 0.05, float(i), 0.0, 0.0, COV, Ellipse(2, 2, 0, 4), False, True)
            self.car.send(STATE, est)
            for v in BAD_IDS:
                self.rogue.put(f"guidance/{v}/state", state_body(v, i))

    def __enter__(self) -> Fleet:
        self.car.start()
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        for t in self.tokens:
            t.undeclare()
        self.rogue.close()
        self.car.close()


@pytest.fixture
def fleet() -> Iterator[Fleet]:
    with Fleet() as f:
        yield f


def events_for(client: MonitorClient, seconds: float) -> list[TelemetryEvent]:
    out, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        e = client.get(0.1)
        if e is not None:
            out.append(e)
    return out


def test_the_client_drops_and_counts_every_bad_key_and_hands_out_only_the_good_car(
    fleet: Fleet,
) -> None:
    with MonitorClient(fleet.connect) as client:
        client.query_latest()
        events = events_for(client, 3.0)
    ids = {e.vehicle_id for e in events}
    assert ids == {"good"}, ids
    assert any(e.kind == "alive" for e in events) and any(e.kind == "state" for e in events)
    # the tokens (once each) and the states under bad keys (many): all counted, none handed out
    assert client.bad_keys >= len(BAD_IDS) * 2, client.bad_keys


def monitor_cli(*args: str, timeout: float = 40.0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "200"}
    return subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", *args],
        cwd=REPO, capture_output=True, text=True, timeout=timeout, env=env,
    )  # fmt: skip


def connect_args(fleet: Fleet) -> list[str]:
    return [a for ep in fleet.connect for a in ("--connect", ep)]


def test_monitor_json_goes_on_printing_the_good_car(fleet: Fleet) -> None:
    r = monitor_cli("--json", "--timeout", "4", *connect_args(fleet))
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    ids = {line.get("vehicle_id") for line in lines}
    assert ids == {"good"}, ids
    assert sum(1 for line in lines if line.get("schema") == "guidance.state/1") > 10
    assert "must be 1-64 characters" not in r.stderr and "Traceback" not in r.stderr


def test_the_live_table_goes_on_showing_the_good_car(fleet: Fleet) -> None:
    r = monitor_cli("--timeout", "4", *connect_args(fleet))
    assert r.returncode == 0, r.stderr
    assert "good" in r.stdout and "Traceback" not in r.stderr
    assert "must be 1-64 characters" not in r.stderr


def test_the_web_monitor_keeps_folding_the_good_car(fleet: Fleet) -> None:
    with MonitorClient(fleet.connect) as client, WebMonitor(client, "127.0.0.1", 0) as web:
        time.sleep(2.0)
        first = web.fleet()
        time.sleep(1.0)
        later = web.fleet()
        folding = [t for t in web._threads if t.name == "web-events"]
        assert folding and folding[0].is_alive()
    assert [c["vehicle_id"] for c in later["cars"]] == ["good"]
    assert later["messages"] > first["messages"] > 0  # still folding, not frozen
    assert later["bad_keys"] >= len(BAD_IDS) * 2 and later["server"]["fold_errors"] == 0


def test_the_fold_thread_survives_an_event_it_cannot_fold(fleet: Fleet) -> None:
    """Whatever one event does (here the fold itself raises once), the thread counts it and
    folds the next ones."""
    with MonitorClient(fleet.connect) as client:
        web = WebMonitor(client, "127.0.0.1", 0)
        real_apply, calls = web.view.apply, {"n": 0}

        def apply_failing_once(event: Any) -> bool:
            calls["n"] += 1
            if calls["n"] == 1:
                raise RuntimeError("boom")
            return real_apply(event)

        web.view.apply = apply_failing_once  # type: ignore[method-assign]
        with web:
            time.sleep(2.0)
            snap = web.fleet()
            alive = all(t.is_alive() for t in web._threads if t.name == "web-events")
    assert alive and snap["server"]["fold_errors"] == 1
    assert [c["vehicle_id"] for c in snap["cars"]] == ["good"] and snap["messages"] > 0


def test_an_id_with_a_trailing_newline_is_not_a_vehicle_id() -> None:
    from guidance.errors import UserError
    from guidance.telemetry.keys import is_vehicle_id, validate_vehicle_id

    assert not is_vehicle_id("car1\n") and is_vehicle_id("car-1.a_B")
    with pytest.raises(UserError):
        validate_vehicle_id("car1\n")
