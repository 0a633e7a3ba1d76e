"""One id, one car (issue 41): two publishers behind one vehicle id are an alarm on that car,
in ``monitor --json`` and on the web map, and neither is dropped; a car that restarts, a
message delivered twice and two cars with their own ids are not. The rule
(``guidance.tools.monitor_ids``) on its own first, then real zenoh sessions on loopback."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from test_monitor_stall import _conf, _free_port, _state

from guidance.core.messages import Ellipse, EstimateState
from guidance.outputs.kinds import STATE, OutputContext
from guidance.telemetry.client import MonitorClient
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
from guidance.tools.monitor_ids import ALARM_HOLD_S, TRACK_IDLE_S, Publishers
from guidance.tools.web.server import WebMonitor

REPO = Path(__file__).resolve().parents[3]


def _msg(seq: int, x: float) -> dict[str, Any]:
    return {"seq": seq, "t_s": seq / 10, "x_m": x}


# -- the rule --------------------------------------------------------------------------------
def test_interleaved_sequence_numbers_are_two_publishers() -> None:
    p, now, alarms = Publishers(), 0.0, []
    for n in range(20):  # two cars started together: the same numbers, other positions
        for car in (0, 1):
            now += 0.05
            alarms.append(p.see("state", _msg(n, 100.0 * car + n), "", now))
    assert alarms[3] and "sequence numbers" in alarms[-1]


def test_a_car_that_restarts_is_not_two() -> None:
    p, now = Publishers(), 0.0
    for n in list(range(1, 50)) + list(range(1, 50)):  # seq and session start again
        now += 0.1
        source = "aaaa" if now < 5.0 else "bbbb"
        assert p.see("state", _msg(n, float(n)), source, now) == ""


def test_a_message_delivered_twice_is_not_two() -> None:
    p, now = Publishers(), 0.0
    for n in range(1, 40):
        now += 0.1
        for _twice in range(2):
            assert p.see("state", _msg(n, float(n)), "", now) == ""


def test_two_zenoh_sessions_are_two_publishers_and_the_alarm_goes_when_one_does() -> None:
    p, now = Publishers(), 0.0
    for _ in range(1, 10):  # no seq: the sources alone say it
        now += 0.1
        p.see("state", {"t_s": now}, "aaaa", now)
        alarm = p.see("state", {"t_s": now}, "bbbb", now)
    assert "2 zenoh sessions" in alarm
    last = now
    while now < last + max(ALARM_HOLD_S, TRACK_IDLE_S) + 0.5:
        now += 0.1
        alarm = p.see("state", {"t_s": now}, "bbbb", now)
    assert alarm == ""


# -- real sessions -----------------------------------------------------------------------------
def _publish(cars: list[Telemetry], stop: threading.Event) -> None:
    cov = ((4.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 0.01))
    n = 0
    while not stop.wait(0.1):
        n += 1
        for i, tel in enumerate(cars):
            st = EstimateState(0.1 * n, 100.0 * i + n, 5.0, 0.3, cov, Ellipse(2, 1, 0, 4), False,
                               True)  # fmt: skip
            tel.send(STATE, st, OutputContext(speed_mps=10.0))


@pytest.fixture
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    session = zenoh.open(_conf("router", endpoint))
    yield endpoint
    session.close()


@pytest.fixture
def twins_and_solo(router: str) -> Iterator[list[Telemetry]]:
    """Two of the project's cars configured with one id ("twin") and one with its own, each
    its own client session of the router, publishing states at 10 Hz."""
    cars = [
        Telemetry(TelemetryConfig(vehicle_id=vid, mode="client", connect=(router,)))
        for vid in ("twin", "twin", "solo")
    ]
    for tel in cars:
        tel.start()
    stop = threading.Event()
    thread = threading.Thread(target=_publish, args=(cars, stop))
    thread.start()
    yield cars
    stop.set()
    thread.join()
    for tel in cars:
        tel.close()


def test_monitor_json_shows_the_alarm_and_keeps_both(
    router: str, twins_and_solo: list[Telemetry]
) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", "--connect", router, "--json",
         "--timeout", "6"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    ).stdout  # fmt: skip
    lines = [json.loads(line) for line in out.splitlines()]
    alarms = [m for m in lines if m["schema"] == "guidance.alarm/1"]
    assert {m["vehicle_id"] for m in alarms} == {"twin"}, alarms
    assert alarms[0]["active"] and "TWO PUBLISHERS" in alarms[0]["detail"]
    states = [m for m in lines if m["schema"] == "guidance.state/1"]
    xs = {m["x_m"] for m in states if m["vehicle_id"] == "twin"}
    assert any(x < 100 for x in xs) and any(100 <= x < 200 for x in xs), "both twins' states"


def test_web_map_shows_the_alarm_on_that_car(router: str, twins_and_solo: list[Telemetry]) -> None:
    client = MonitorClient([router]).open()
    web = WebMonitor(client, "127.0.0.1", 0).start()
    try:
        deadline, cars = time.monotonic() + 15.0, {}
        while time.monotonic() < deadline:
            cars = {c["vehicle_id"]: c for c in web.fleet()["cars"]}
            alarm = cars.get("twin", {}).get("alarm", "")
            if "zenoh sessions" in alarm and cars.get("solo", {}).get("state"):
                break
            time.sleep(0.2)
        assert "zenoh sessions" in cars["twin"]["alarm"], cars.get("twin")
        assert cars["solo"]["alarm"] == ""
    finally:
        web.close()
        client.close()


def test_another_programs_twins_without_source_info_are_found_by_their_seq(router: str) -> None:
    """Two plain zenoh sessions publishing as "ext" (no source info, their own seq from 0,
    the same numbers at the same time), and one as "ext2": the alarm on "ext" only."""
    sessions = [zenoh.open(_conf("client", router)) for _ in range(3)]
    ids = ("ext", "ext", "ext2")
    pubs = [
        s.declare_publisher(f"guidance/{vid}/state") for s, vid in zip(sessions, ids, strict=True)
    ]
    mon = subprocess.Popen(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", "--connect", router, "--json",
         "--timeout", "8"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30.0
        while not all(p.matching_status.matching for p in pubs):
            assert time.monotonic() < deadline and mon.poll() is None
            time.sleep(0.05)
        for n in range(30):
            for i, (pub, vid) in enumerate(zip(pubs, ids, strict=True)):
                pub.put(json.dumps(_state(vid, n, n / 10.0, i)))
            time.sleep(0.1)
        out, _err = mon.communicate(timeout=60)
    finally:
        if mon.poll() is None:
            mon.kill()
            mon.wait()
        for s in sessions:
            s.close()
    alarms = [m for m in map(json.loads, out.splitlines()) if m["schema"] == "guidance.alarm/1"]
    assert {m["vehicle_id"] for m in alarms} == {"ext"}, alarms
    assert "sequence numbers" in alarms[0]["detail"]


def test_two_simulated_drives_side_by_side_are_two_cars(tmp_path: Path) -> None:
    """``guidance sim`` with seeds 3 and 4 on one config (one listen endpoint): each drive
    has its own id, the second joins the first's endpoint, and a monitor there sees both."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    cfg = tmp_path / "sim.toml"
    cfg.write_text(
        (REPO / "config" / "sim.toml").read_text().replace("tcp/127.0.0.1:7447", endpoint)
    )
    sims = []
    for seed in (3, 4):
        sims.append(subprocess.Popen(
            [sys.executable, "-m", "guidance.tools.cli", "sim", "--config", str(cfg), "--seed",
             str(seed), "--speed", "1", "--no-voice", "--no-record", "--no-png", "--out",
             str(tmp_path / f"out{seed}")],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        ))  # fmt: skip
    try:
        client = MonitorClient([endpoint]).open()
        seen: dict[str, set[int]] = {}
        try:
            # two simulators start (imports, the numba warm-up) and publish: seconds on an idle
            # machine, over 40 s once on a loaded one; the loop ends as soon as both are seen
            deadline = time.monotonic() + 180.0
            while time.monotonic() < deadline and not (
                len(seen) == 2 and all(len(s) >= 20 for s in seen.values())
            ):
                event = client.get(0.25)
                if event is not None and event.kind == "state" and event.message:
                    seen.setdefault(event.vehicle_id, set()).add(event.message["seq"])
        finally:
            client.close()
    finally:
        for p in sims:
            p.terminate()
        errs = [p.communicate(timeout=30)[1] for p in sims]
    ids = sorted(seen)
    assert [i.split("-")[0] for i in ids] == ["sim3", "sim4"], (ids, errs)
    assert all(len(s) >= 20 for s in seen.values()), {k: len(v) for k, v in seen.items()}
