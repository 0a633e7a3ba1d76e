"""Telemetry over real zenoh sessions on loopback (no multicast, tcp/tls on 127.0.0.1 only).

Covers: message fields, every kind, rate without gaps, liveliness vanishing after
SIGKILL, late joiners, remote goals (off by default, on when enabled, malformed
refused), zenoh unreachable then reachable, the example TLS and access-control
configs in config/zenoh/, and the [telemetry] config table.
"""

from __future__ import annotations

import asyncio
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from guidance.core.messages import Ellipse, EstimateState, Health, LandmarkFix, Prompt, Target
from guidance.core.plan.navigator import Decision, ExitOption
from guidance.errors import UserError
from guidance.outputs.kinds import (
    DECISION,
    HEALTH,
    LANDMARK,
    PROMPT,
    STATE,
    HealthReport,
    LandmarkReport,
    OutputContext,
)
from guidance.outputs.messages import LandmarkRejection
from guidance.telemetry.client import MonitorClient, TelemetryEvent
from guidance.telemetry.config import TelemetryConfig, TlsConfig
from guidance.telemetry.publisher import Telemetry
from guidance.telemetry.session import open_session, parse_goal, session_config

REPO = Path(__file__).resolve().parents[3]
ZENOH_EXAMPLES = REPO / "config" / "zenoh"

PUBLISHER = r"""
import sys, time
from guidance.core.messages import Ellipse, EstimateState, Prompt, Target
from guidance.outputs.kinds import PROMPT, STATE, OutputContext
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
port, vid, rate = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
tel = Telemetry(TelemetryConfig(vehicle_id=vid, listen=(f"tcp/127.0.0.1:{port}",)))
tel.start()
period, i, next_t = 1.0 / rate, 0, time.monotonic()
while True:
    t = time.monotonic()
    cov = ((4.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.01))
    state = EstimateState(t, float(i), 0.0, 0.0, cov, Ellipse(2.0, 1.0, 0.0, 4.0), False, True)
    tel.send(STATE, state, OutputContext(speed_mps=5.0, target=Target(100.0, 0.0, "goal", None)))
    if i % 25 == 0:
        tel.send(PROMPT, Prompt(t, f"prompt {i}", 0, "turn"))
    i += 1
    next_t += period
    time.sleep(max(0.0, next_t - time.monotonic()))
"""


# -- helpers ------------------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def tcp(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def make_state(t_s: float = 1.0, x_m: float = 10.0, y_m: float = 20.0) -> EstimateState:
    cov = ((9.0, 1.0, 0.0), (1.0, 4.0, 0.0), (0.0, 0.0, 0.01))
    return EstimateState(
        t_s, x_m, y_m, math.radians(100.0), cov, Ellipse(6.2, 3.9, 0.2, 12.4), False, True
    )


def wait_for(
    client: MonitorClient,
    predicate: Callable[[TelemetryEvent], bool],
    timeout_s: float = 5.0,
) -> TelemetryEvent:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        event = client.get(0.05)
        if event is not None and predicate(event):
            return event
    raise AssertionError(f"no matching telemetry event within {timeout_s} s")


def wait_until(cond: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


@pytest.fixture
def car_port() -> int:
    return free_port()


@pytest.fixture
def publisher_process() -> Iterator[Callable[..., subprocess.Popen[bytes]]]:
    procs: list[subprocess.Popen[bytes]] = []

    def start(
        port: int, vehicle_id: str = "car1", rate_hz: float = 50.0
    ) -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(
            [sys.executable, "-c", PUBLISHER, str(port), vehicle_id, str(rate_hz)],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(5)
        if proc.stderr is not None:
            proc.stderr.close()


# -- messages ---------------------------------------------------------------------------------
def test_state_reaches_a_subscriber_with_the_documented_fields(car_port: int) -> None:
    origin = (42.444, -76.5019)
    cfg = TelemetryConfig(vehicle_id="car7", listen=(tcp(car_port),), origin_lat_lon_deg=origin)
    with Telemetry(cfg) as tel, MonitorClient([tcp(car_port)]) as mon:
        wait_for(mon, lambda e: e.kind == "alive" and e.vehicle_id == "car7")
        assert wait_until(tel.has_subscribers)
        tel.send(
            STATE,
            make_state(),
            OutputContext(
                speed_mps=8.5,
                target=Target(300.0, 120.0, "landmark", 4),
                goal=(500.0, 200.0),
                method="hybrid",
                mode="landmark",
                chance=0.73,
            ),
        )
        msg = wait_for(mon, lambda e: e.kind == "state").message
    assert msg is not None
    assert msg["schema"] == "guidance.state/1"
    assert msg["vehicle_id"] == "car7" and msg["seq"] == 1
    assert msg["t_s"] == 1.0 and abs(msg["wall_time_unix_s"] - time.time()) < 60
    assert (msg["x_m"], msg["y_m"]) == (10.0, 20.0)
    assert msg["heading_rad"] == pytest.approx(math.radians(100.0))
    assert msg["heading_deg"] == pytest.approx(100.0)
    assert msg["covariance"] == [[9.0, 1.0, 0.0], [1.0, 4.0, 0.0], [0.0, 0.0, 0.01]]
    assert msg["ellipse"] == {
        "semi_major_m": 6.2,
        "semi_minor_m": 3.9,
        "orientation_rad": 0.2,
        "major_axis_m": 12.4,
    }
    assert msg["speed_mps"] == 8.5
    target = {k: msg["target"][k] for k in ("x_m", "y_m", "kind", "id")}
    assert target == {"x_m": 300.0, "y_m": 120.0, "kind": "landmark", "id": 4}
    assert (msg["goal"]["x_m"], msg["goal"]["y_m"]) == (500.0, 200.0)
    # WGS-84 beside the local metres: back through pymap3d's inverse, to a millimetre
    import pymap3d

    assert msg["origin"] == {"lat_deg": origin[0], "lon_deg": origin[1]}
    for point, (x, y) in ((msg, (10.0, 20.0)), (msg["target"], (300.0, 120.0)),
                          (msg["goal"], (500.0, 200.0))):  # fmt: skip
        e, n, _u = pymap3d.geodetic2enu(point["lat_deg"], point["lon_deg"], 0.0, *origin, 0.0)
        assert (e, n) == (pytest.approx(x, abs=1e-3), pytest.approx(y, abs=1e-3))
    assert msg["heading_deg_true"] == pytest.approx(350.0)  # 100° CCW from east
    assert msg["chance"] == 0.73
    assert (msg["method"], msg["mode"], msg["lost"], msg["healthy"]) == (
        "hybrid",
        "landmark",
        False,
        True,
    )


def test_every_message_kind_is_published(car_port: int) -> None:
    option = ExitOption(0, 0.0, 0.0, 0.1, 0.0, 0.1)
    decision = Decision(
        t_s=2.0,
        exit_index=1,
        exit_heading_rad=math.pi / 2,
        turn_rad=math.pi / 2,
        options=(option, ExitOption(1, math.pi / 2, math.pi / 2, 0.05, 0.0, 0.05)),
        target_x_m=0.0,
        target_y_m=400.0,
        target_kind="goal",
        target_id=None,
        intersection_id=3,
        revisit=False,
        mode="goal",
        reason="smallest angle to target",
    )
    cfg = TelemetryConfig(vehicle_id="car2", listen=(tcp(car_port),))
    with Telemetry(cfg) as tel, MonitorClient([tcp(car_port)], vehicle="car2") as mon:
        wait_for(mon, lambda e: e.kind == "alive")
        assert wait_until(tel.has_subscribers)
        tel.send(DECISION, decision)
        tel.send(PROMPT, Prompt(2.0, "In 100 metres, turn left", 2, "turn"))
        tel.send(
            LANDMARK,
            LandmarkReport(
                2.5,
                matches=[LandmarkFix(2.5, 17, 120.0, 80.0, 5.0)],
                rejections=[
                    LandmarkRejection("outside_gate", 9),
                    LandmarkRejection("ratio_test", 11, "12 good of 40"),
                ],
                gated=3,
            ),
        )
        tel.send(
            HEALTH,
            HealthReport(
                3.0,
                {
                    "odometry": Health(
                        "odometry", "ok", True, True, 0.02, rate_hz=50.0, expected_rate_hz=50.0
                    ),
                    "compass": Health(
                        "compass",
                        "silent",
                        False,
                        False,
                        6.5,
                        "silent for 6.5 s",
                        rate_hz=0.0,
                        expected_rate_hz=10.0,
                    ),
                },
            ),
        )
        got: dict[str, dict] = {}
        deadline = time.monotonic() + 5
        while len(got) < 4 and time.monotonic() < deadline:
            e = mon.get(0.05)
            if e is not None and e.message is not None:
                got[e.kind] = dict(e.message)
    assert set(got) == {"decision", "prompt", "landmark", "health"}
    d = got["decision"]
    assert d["schema"] == "guidance.decision/1" and d["exit_index"] == 1
    assert d["turn_deg"] == pytest.approx(90.0) and len(d["options"]) == 2
    assert d["target"]["kind"] == "goal" and d["reason"] == "smallest angle to target"
    assert got["prompt"]["text"] == "In 100 metres, turn left" and got["prompt"]["priority"] == 2
    lm = got["landmark"]
    assert lm["matches"][0]["landmark_id"] == 17 and lm["matches"][0]["sigma_m"] == 5.0
    assert [r["reason"] for r in lm["rejections"]] == ["outside_gate", "ratio_test"]
    h = got["health"]
    assert h["ok"] is False
    assert h["inputs"]["compass"] == {
        "name": "compass",
        "status": "silent",
        "alive": False,
        "valid": False,
        "ok": False,
        "age_s": 6.5,
        "rate_hz": 0.0,
        "expected_rate_hz": 10.0,
        "detail": "silent for 6.5 s",
        "warning": "",
        "counters": {},
        "info": {},
    }
    tel_health = h["components"]["telemetry"]
    assert tel_health["status"] in ("starting", "up") and tel_health["name"] == "telemetry"
    assert tel_health["counters"]["published"] >= 0 and tel_health["info"] == {"mode": "peer"}


def test_non_finite_numbers_become_null(car_port: int) -> None:
    bad = EstimateState(
        1.0,
        float("nan"),
        0.0,
        0.0,
        ((float("inf"), 0, 0), (0, 1, 0), (0, 0, 1)),
        Ellipse(1, 1, 0, 2),
        False,
        False,
    )
    with (
        Telemetry(TelemetryConfig(listen=(tcp(car_port),))) as tel,
        MonitorClient([tcp(car_port)]) as mon,
    ):
        wait_for(mon, lambda e: e.kind == "alive")
        assert wait_until(tel.has_subscribers)
        tel.send(STATE, bad)
        msg = wait_for(mon, lambda e: e.kind == "state").message
    assert msg is not None and msg["x_m"] is None and msg["covariance"][0][0] is None


def test_a_malformed_message_is_counted_and_publishing_goes_on(car_port: int) -> None:
    with (
        Telemetry(TelemetryConfig(listen=(tcp(car_port),))) as tel,
        MonitorClient([tcp(car_port)]) as mon,
    ):
        wait_for(mon, lambda e: e.kind == "alive")
        assert wait_until(tel.has_subscribers)
        tel.send(DECISION, object())  # type: ignore[arg-type]
        tel.send(STATE, make_state(t_s=5.0))
        e = wait_for(mon, lambda e: e.kind == "state")
        assert e.message is not None and e.message["t_s"] == 5.0
        assert wait_until(lambda: tel.health().counters.get("dropped_encode_error") == 1)
        assert tel.health().counters["dropped"] == 1


# -- rate, liveliness, late join ---------------------------------------------------------------
def test_monitor_gets_50hz_without_gaps_and_sees_the_car_vanish_after_sigkill(
    car_port: int, publisher_process: Callable[..., subprocess.Popen[bytes]]
) -> None:
    proc = publisher_process(car_port, "car9", 50.0)
    with MonitorClient([tcp(car_port)]) as mon:
        wait_for(mon, lambda e: e.kind == "alive" and e.vehicle_id == "car9", timeout_s=10)

        # from 1 s in: until the car's publisher thread first sends, its latest-value slot
        # supersedes states (counted by the car), a gap that is not the link's or the monitor's
        def settled(e: TelemetryEvent) -> bool:
            return e.kind == "state" and not e.late_join and (e.message or {}).get("seq", 0) > 50

        first = wait_for(mon, settled)
        seqs = [first.message["seq"]] if first.message else []
        t0 = first.received_s
        while time.monotonic() - t0 < 2.0:
            e = mon.get(0.05)
            if e is not None and e.kind == "state" and not e.late_join and e.message:
                seqs.append(e.message["seq"])
        rate_hz = (len(seqs) - 1) / (time.monotonic() - t0)
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "gaps in the state sequence"
        assert 40.0 < rate_hz < 60.0

        os.kill(proc.pid, signal.SIGKILL)
        killed = time.monotonic()
        gone = wait_for(mon, lambda e: e.kind == "gone" and e.vehicle_id == "car9", timeout_s=10)
        assert gone.received_s - killed < 5.0


def test_late_joiner_gets_the_latest_state_at_once(car_port: int) -> None:
    with Telemetry(TelemetryConfig(vehicle_id="car3", listen=(tcp(car_port),))) as tel:
        for i in range(3):
            tel.send(STATE, make_state(t_s=float(i), x_m=float(i)))
            time.sleep(0.05)
        tel.send(PROMPT, Prompt(2.0, "Arrived", 0, "info"))
        assert wait_until(lambda: tel.health().counters["published"] >= 4)
        with MonitorClient([tcp(car_port)]) as mon:
            wait_for(mon, lambda e: e.kind == "alive")
            mon.query_latest()
            late: dict[str, dict] = {}
            deadline = time.monotonic() + 5
            while len(late) < 2 and time.monotonic() < deadline:
                e = mon.get(0.05)
                if e is not None and e.late_join and e.message is not None:
                    late[e.kind] = dict(e.message)
    assert late["state"]["seq"] == 3 and late["state"]["x_m"] == 2.0
    assert late["prompt"]["text"] == "Arrived"


# -- remote goal --------------------------------------------------------------------------------
def test_remote_goal_is_refused_by_default(car_port: int) -> None:
    goals: list[tuple[float, float]] = []
    cfg = TelemetryConfig(vehicle_id="car4", listen=(tcp(car_port),))
    assert cfg.allow_remote_goal is False
    with (
        Telemetry(cfg, on_goal=lambda x, y: goals.append((x, y))) as tel,
        MonitorClient([tcp(car_port)]) as mon,
    ):
        wait_for(mon, lambda e: e.kind == "alive")
        # the car declares no goal subscription: nothing matches, nothing is put
        assert mon.send_goal("car4", 100.0, 200.0, wait_s=1.0) is False
        assert goals == []
        assert tel.health().counters["goals_accepted"] == 0


def test_remote_goal_accepted_when_enabled_and_handed_to_the_event_loop(
    car_port: int, loopback_acl: str
) -> None:
    cfg = TelemetryConfig(
        vehicle_id="car5",
        listen=(tcp(car_port),),
        allow_remote_goal=True,
        zenoh_config=loopback_acl,
        max_goal_range_m=10_000.0,
    )

    async def main() -> tuple[tuple[float, float], bool, Telemetry]:
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[tuple[float, float]] = loop.create_future()
        loop_thread = threading.get_ident()
        on_loop: list[bool] = []

        def on_goal(x: float, y: float) -> None:
            on_loop.append(threading.get_ident() == loop_thread)
            if not fut.done():
                fut.set_result((x, y))

        tel = Telemetry(cfg, on_goal=on_goal, loop=loop)
        tel.start()
        mon = MonitorClient([tcp(car_port)])
        try:
            await asyncio.to_thread(mon.open)
            await asyncio.to_thread(wait_for, mon, lambda e: e.kind == "alive")
            # each is put once the car's goal subscription has reached the monitor, reliably
            # (it was a put 0.2 s after "alive", lost on a loaded machine before the car's
            # subscription arrived: CI timed out waiting for it)
            sent = await asyncio.to_thread(mon.send_goal, "car5", 1e9, 0.0)  # out of range
            sent &= await asyncio.to_thread(mon.send_goal, "car5", 350.0, -120.0)
            assert sent
            goal = await asyncio.wait_for(fut, 10.0)
        finally:
            mon.close()
            tel.close()
        return goal, all(on_loop), tel

    goal, on_loop_thread, tel = asyncio.run(main())
    assert goal == (350.0, -120.0)
    assert on_loop_thread
    counters = tel.health().counters
    assert counters["goals_accepted"] == 1 and counters["goals_refused"] == 1


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"not json",
        b"[1,2]",
        b'{"x_m": 1}',
        b'{"x_m": "1", "y_m": 2}',
        b'{"x_m": NaN, "y_m": 0}',
        b'{"x_m": 1, "y_m": 2, "schema": "other/1"}',
        b'{"x_m": true, "y_m": 2}',
    ],
)
def test_malformed_goals_are_refused(payload: bytes) -> None:
    with pytest.raises(ValueError):
        parse_goal(payload, 1000.0)


def test_goal_parsing_accepts_a_plain_goal() -> None:
    assert parse_goal(b'{"x_m": 3, "y_m": -4.5}', 1000.0) == (3.0, -4.5)


def assert_never_blocks(took: list[float]) -> None:
    """Calls that never wait for the network: 99% under 1 ms. The worst one is allowed the
    thread-switch and scheduling jitter of a loaded two-core machine (up to tens of ms), still
    below any network wait (zenoh's connect timeout is seconds)."""
    took = sorted(took)
    p99, worst = took[int(0.99 * (len(took) - 1))], took[-1]
    assert p99 < 0.001 and worst < 0.5, f"p99 {p99 * 1e3:.2f} ms, worst {worst * 1e3:.1f} ms"


# -- unreachable zenoh, non-blocking publishing ----------------------------------------------------
def test_unreachable_router_keeps_the_car_running_then_connects(car_port: int) -> None:
    cfg = TelemetryConfig(
        vehicle_id="car6", mode="client", connect=(tcp(car_port),), retry_period_s=0.3
    )
    tel = Telemetry(cfg)
    tel.start()
    router = None
    try:
        assert wait_until(lambda: tel.health().status == "down", 5.0)
        assert "Unable to connect" in tel.health().detail
        took = []
        for i in range(500):
            t0 = time.perf_counter()
            tel.send(STATE, make_state(t_s=float(i)))
            tel.send(PROMPT, Prompt(float(i), "p", 0, "info"))
            took.append(time.perf_counter() - t0)
        assert_never_blocks(took)
        dropped = tel.health().counters
        assert dropped.get("dropped_superseded", 0) > 400
        assert dropped.get("dropped_fifo_full", 0) > 400

        router = open_session(session_config(mode="router", listen=[tcp(car_port)]))
        assert wait_until(lambda: tel.health().status == "up" and tel.health().valid, 10.0)
        with MonitorClient([tcp(car_port)]) as mon:
            wait_for(mon, lambda e: e.kind == "alive" and e.vehicle_id == "car6")
            assert wait_until(tel.has_subscribers)
            tel.send(STATE, make_state(t_s=999.0))
            e = wait_for(mon, lambda e: e.kind == "state" and not e.late_join)
            assert e.message is not None and e.message["t_s"] == 999.0
    finally:
        tel.close()
        if router is not None:
            router.close()
    assert tel.health().status == "closed"


def test_port_in_use_reports_down_without_raising(car_port: int) -> None:
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", car_port))
        blocker.listen()
        with Telemetry(TelemetryConfig(listen=(tcp(car_port),), retry_period_s=0.2)) as tel:
            tel.send(STATE, make_state())
            assert wait_until(lambda: tel.health().status == "down")
            assert "Address already in use" in tel.health().detail


def test_joining_a_taken_port_needs_a_zenoh_peer_there(car_port: int) -> None:
    """``join_if_taken`` (the simulator's): a port held by something that is not a zenoh peer
    is still a car that is down, with zenoh's reason."""
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", car_port))
        blocker.listen()
        cfg = TelemetryConfig(listen=(tcp(car_port),), retry_period_s=0.2, join_if_taken=True)
        with Telemetry(cfg) as tel:
            tel.send(STATE, make_state())
            assert wait_until(lambda: tel.health().status == "down")
            assert "Address already in use" in tel.health().detail


def test_disabled_telemetry_opens_nothing() -> None:
    with Telemetry(TelemetryConfig(enabled=False)) as tel:
        tel.send(STATE, make_state())
        h = tel.health()
        assert h.status == "disabled" and h.counters["published"] == 0


# -- configuration ------------------------------------------------------------------------------
def test_config_from_the_example_toml_table() -> None:
    doc = tomllib.loads((ZENOH_EXAMPLES / "telemetry.example.toml").read_text())
    cfg = TelemetryConfig.from_mapping(doc["telemetry"], base_dir=ZENOH_EXAMPLES)
    assert cfg == TelemetryConfig()
    assert cfg.mode == "peer" and cfg.listen == ("tcp/127.0.0.1:7447",)
    assert cfg.multicast_scouting is False and cfg.allow_remote_goal is False


def test_config_table_with_tls_and_relative_paths(tmp_path: Path) -> None:
    cfg = TelemetryConfig.from_mapping(
        {
            "vehicle_id": "van-2",
            "mode": "client",
            "connect": "tls/10.0.0.1:7447",
            "tls": {"root_ca_certificate": "pki/ca.pem", "mutual": True},
        },
        base_dir=tmp_path,
    )
    assert cfg.connect == ("tls/10.0.0.1:7447",)
    assert cfg.tls == TlsConfig(root_ca_certificate=str(tmp_path / "pki/ca.pem"), mutual=True)


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        ({"listen": ["localhost:7447"]}, "bad zenoh endpoint"),
        ({"mode": "router"}, "mode"),
        ({"vehicle_id": "car/1"}, "vehicle id"),
        ({"vehicle_id": "*"}, "vehicle id"),
        ({"allow_remote_goal": "yes"}, "allow_remote_goal"),
        ({"mode": "client"}, "connect"),
        ({"retry_period_s": 0}, "> 0"),
        ({"colour": "red"}, "unknown key"),
        ({"tls": {"certificate": "x"}}, "root_ca_certificate"),
    ],
)
def test_bad_config_is_a_user_error(table: dict, needle: str) -> None:
    with pytest.raises(UserError, match=needle):
        TelemetryConfig.from_mapping(table)


def test_bad_endpoint_is_a_clear_user_error() -> None:
    with pytest.raises(UserError, match="bad zenoh endpoint 'foo'"):
        MonitorClient(["foo"])
    with pytest.raises(UserError, match="cannot open zenoh session: Unable to connect") as err:
        open_session(session_config(mode="client", connect=[tcp(free_port())]))
    assert ".rs:" not in str(err.value) and "/root/" not in str(err.value)


# -- example security configs (config/zenoh/) ------------------------------------------------------
def example_config(
    name: str, tmp_path: Path, replacements: dict[str, str] | None = None, out: str = ""
) -> str:
    """An example file with its placeholder paths (and any other strings) replaced."""
    text = (ZENOH_EXAMPLES / name).read_text()
    text = text.replace("/etc/guidance/zenoh/", f"{tmp_path}/")
    for old, new in (replacements or {}).items():
        assert old in text, f"{old!r} not in {name}"
        text = text.replace(old, new)
    path = tmp_path / (out or f"test-{name}")
    path.write_text(text)
    return str(path)


def goal_scenario(
    car_cfg: TelemetryConfig, car_endpoint: str, monitors: dict[str, str | None]
) -> tuple[list[tuple[float, float]], dict]:
    """Each monitor (name -> its zenoh config, None: no credentials) watches and sends a goal."""
    goals: list[tuple[float, float]] = []
    seen: dict[str, dict[str, bool]] = {}
    with Telemetry(car_cfg, on_goal=lambda x, y: goals.append((x, y))) as tel:
        tel.send(STATE, make_state())
        assert wait_until(lambda: tel.health().status == "up")
        for i, (name, zcfg) in enumerate(monitors.items()):
            mon = MonitorClient([car_endpoint], zenoh_config=zcfg or "")
            try:
                mon.open()
                kinds: set[str] = set()
                deadline = time.monotonic() + 1.5
                mon.query_latest()
                tel.send(STATE, make_state(t_s=2.0))
                while time.monotonic() < deadline:
                    e = mon.get(0.05)
                    if e is not None:
                        kinds.add("late_state" if e.late_join else e.kind)
                        if {"alive", "late_state", "state"} <= kinds:
                            break
                    if "alive" in kinds and "late_state" not in kinds:
                        mon.query_latest()
                        time.sleep(0.1)
                    tel.send(STATE, make_state(t_s=3.0))
                # a monitor refused at the link waits for no subscription it cannot see
                mon.send_goal("car1", 10.0 * (i + 1), 5.0, wait_s=3.0 if mon.peers() else 0.0)
                time.sleep(0.4)
                seen[name] = {
                    "connected": mon.peers() > 0,
                    "alive": "alive" in kinds,
                    "state": "state" in kinds,
                    "late_state": "late_state" in kinds,
                }
            finally:
                mon.close()
    return goals, seen


def test_usrpwd_access_control_only_the_operator_sets_a_goal(tmp_path: Path, car_port: int) -> None:
    shutil.copy(ZENOH_EXAMPLES / "passwords.example.txt", tmp_path / "passwords.txt")
    car_cfg = TelemetryConfig(
        listen=(tcp(car_port),),
        allow_remote_goal=True,
        zenoh_config=example_config("car-usrpwd-acl.json5", tmp_path),
    )
    viewer = example_config("monitor-usrpwd.json5", tmp_path)
    operator = example_config(
        "monitor-usrpwd.json5",
        tmp_path,
        {'"viewer"': '"operator"', "change-me-viewer": "change-me-operator"},
        out="operator.json5",
    )
    intruder = example_config(
        "monitor-usrpwd.json5", tmp_path, {"change-me-viewer": "guess"}, out="intruder.json5"
    )
    goals, seen = goal_scenario(
        car_cfg,
        tcp(car_port),
        {"viewer": viewer, "intruder": intruder, "anonymous": None, "operator": operator},
    )
    assert goals == [(40.0, 5.0)], "only the operator (4th monitor) may set a goal"
    assert seen["viewer"] == {"connected": True, "alive": True, "state": True, "late_state": True}
    assert seen["operator"]["state"]
    for name in ("intruder", "anonymous"):
        assert seen[name] == {
            "connected": False,
            "alive": False,
            "state": False,
            "late_state": False,
        }


def make_pki(directory: Path, names: tuple[str, ...]) -> None:
    """A CA and certificates (CN=name, SAN localhost/127.0.0.1) made with openssl."""

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=directory, check=True, capture_output=True)

    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    run(
        "req",
        "-x509",
        *ec,
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
        "-days",
        "2",
        "-subj",
        "/CN=guidance-test-ca",
    )
    for name in names:
        run("req", *ec, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}")
        (directory / f"{name}.ext").write_text(
            "subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth,clientAuth\n"
        )
        run(
            "x509",
            "-req",
            "-in",
            f"{name}.csr",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-days",
            "2",
            "-out",
            f"{name}.pem",
            "-extfile",
            f"{name}.ext",
        )


needs_openssl = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not found")


@needs_openssl
def test_tls_example_configs_carry_telemetry_on_loopback(tmp_path: Path, car_port: int) -> None:
    make_pki(tmp_path, ("car", "operator"))
    endpoint = f"tls/127.0.0.1:{car_port}"
    car_cfg = TelemetryConfig(
        listen=(endpoint,), zenoh_config=example_config("car-tls.json5", tmp_path)
    )
    monitor_cfg = example_config("monitor-tls.json5", tmp_path)
    with Telemetry(car_cfg) as tel, MonitorClient([endpoint], zenoh_config=monitor_cfg) as mon:
        wait_for(mon, lambda e: e.kind == "alive", timeout_s=10)
        assert wait_until(tel.has_subscribers)
        tel.send(STATE, make_state(x_m=42.0))
        e = wait_for(mon, lambda e: e.kind == "state")
        assert e.message is not None and e.message["x_m"] == 42.0
        # A plain-TCP session cannot talk to the TLS listener.
        with MonitorClient([f"tcp/127.0.0.1:{car_port}"]) as plain:
            time.sleep(0.5)
            assert plain.peers() == 0


@needs_openssl
def test_mtls_access_control_only_the_operator_certificate_sets_a_goal(
    tmp_path: Path, car_port: int
) -> None:
    make_pki(tmp_path, ("car", "operator", "viewer"))
    endpoint = f"tls/127.0.0.1:{car_port}"
    car_cfg = TelemetryConfig(
        listen=(endpoint,),
        allow_remote_goal=True,
        zenoh_config=example_config("car-mtls-acl.json5", tmp_path),
    )
    monitors = {
        name: example_config(
            "monitor-mtls.json5", tmp_path, {"monitor.": f"{name}."}, out=f"{name}.json5"
        )
        for name in ("viewer", "operator")
    }
    no_cert = example_config("monitor-tls.json5", tmp_path)
    goals, seen = goal_scenario(car_cfg, endpoint, {**monitors, "no-certificate": no_cert})
    assert goals == [(20.0, 5.0)], "only CN=operator (2nd monitor) may set a goal"
    assert seen["viewer"] == {"connected": True, "alive": True, "state": True, "late_state": True}
    assert seen["no-certificate"]["connected"] is False and not seen["no-certificate"]["state"]


def test_a_non_finite_angle_loses_its_field_not_the_message() -> None:
    from guidance.outputs.messages import _wrap_deg

    assert _wrap_deg(math.inf) is None and _wrap_deg(math.nan) is None
    assert _wrap_deg(3 * math.pi) == pytest.approx(180.0)
    assert _wrap_deg(-math.pi / 2) == pytest.approx(-90.0)


def test_a_router_takes_a_fleet_of_client_sessions_with_shared_memory_off() -> None:
    """Issue 24: 1,000 cars through one router. With zenoh's shared memory on (its default),
    every session holds shared-memory file descriptors: one process could open 351 client
    sessions and a router accept about 600. ``session_config`` turns it off (without a file),
    so here one process opens 450 client sessions of one router on loopback."""
    import json as _json

    from guidance.telemetry.session import open_session, session_config

    port = free_port()
    conf = session_config(mode="router", listen=[tcp(port)])
    assert _json.loads(conf.get_json("transport/shared_memory/enabled")) is False
    router = open_session(conf)
    sessions = []
    try:
        for _ in range(450):
            sessions.append(open_session(session_config(mode="client", connect=[tcp(port)])))
        assert len(sessions) == 450
    finally:
        for s in sessions:
            s.close()
        router.close()
