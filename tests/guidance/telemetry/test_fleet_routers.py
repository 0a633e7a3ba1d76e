"""A fleet past one router (issue 41): the shipped mesh configs, a car failing over from a
router that dies to the other while a monitor on the survivor keeps it, and a car no router
takes saying so. Real routers and sessions on loopback."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import zenoh

from guidance.core.messages import Ellipse, EstimateState
from guidance.outputs.kinds import STATE, OutputContext
from guidance.telemetry.client import MonitorClient
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry

CONFIGS = Path(__file__).resolve().parents[3] / "config" / "zenoh"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _router(
    name: str, listen: str, connect: list[str], max_sessions: int | None = None
) -> zenoh.Session:
    """A shipped router config with loopback endpoints in place of the fleet's hosts."""
    conf = zenoh.Config.from_file(str(CONFIGS / name))
    conf.insert_json5("listen/endpoints", json.dumps([listen]))
    conf.insert_json5("connect/endpoints", json.dumps(connect))
    if max_sessions is not None:
        conf.insert_json5("transport/unicast/max_sessions", str(max_sessions))
    return zenoh.open(conf)


def test_the_shipped_mesh_configs_are_linked_routers_with_a_session_limit() -> None:
    for name, other in (("router-a.json5", "router-b"), ("router-b.json5", "router-a")):
        conf = zenoh.Config.from_file(str(CONFIGS / name))
        assert json.loads(conf.get_json("mode")) == "router"
        assert int(json.loads(conf.get_json("transport/unicast/max_sessions"))) >= 1000
        assert any(other in ep for ep in json.loads(conf.get_json("connect/endpoints")))


def _send(tel: Telemetry, i: int) -> None:
    cov = ((4.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 0.01))
    tel.send(STATE, EstimateState(0.1 * i, i, 0.0, 0.0, cov, Ellipse(2, 1, 0, 4), False, True),
             OutputContext(speed_mps=10.0))  # fmt: skip


def test_a_car_fails_over_to_the_other_router_within_2_s() -> None:
    a, b = (f"tcp/127.0.0.1:{_free_port()}" for _ in range(2))
    ra = _router("router-a.json5", a, [])
    rb = _router("router-b.json5", b, [a])
    cars = {
        "on_b": Telemetry(TelemetryConfig(vehicle_id="on_b", mode="client", connect=(b, a))),
        "on_a": Telemetry(TelemetryConfig(vehicle_id="on_a", mode="client", connect=(a, b))),
    }
    mon = MonitorClient([a], mode="client").open()
    try:
        for tel in cars.values():
            tel.start()
        last: dict[str, float] = {}
        first_after: dict[str, float] = {}  # first state made after B died, when it was shown
        cut = [float("inf")]

        def pump(until: float, i0: int) -> int:
            i = i0
            while time.monotonic() < until:
                for tel in cars.values():
                    _send(tel, i)
                i += 1
                end = time.monotonic() + 0.1
                while (rest := end - time.monotonic()) > 0:
                    e = mon.get(rest)
                    if e is not None and e.kind == "state" and e.message is not None:
                        last[e.vehicle_id] = time.monotonic()
                        if e.message["x_m"] >= cut[0]:
                            first_after.setdefault(e.vehicle_id, time.monotonic())
            return i

        i = pump(time.monotonic() + 4.0, 0)
        assert set(last) == {"on_a", "on_b"}, "the monitor on A sees the car on B"
        rb.close()  # router B dies
        killed = time.monotonic()
        cut[0] = i
        pump(killed + 4.0, i)
        back = first_after["on_b"] - killed
        assert 0 < back <= 2.0, f"the car on B is shown again {back:.2f} s after B died"
    finally:
        mon.close()
        for tel in cars.values():
            tel.close()
        ra.close()


def test_a_car_no_router_takes_says_so() -> None:
    a = f"tcp/127.0.0.1:{_free_port()}"
    nobody = f"tcp/127.0.0.1:{_free_port()}"
    router = _router("router-a.json5", a, [], max_sessions=2)
    cars = [Telemetry(TelemetryConfig(vehicle_id=f"c{i}", mode="client", connect=(a,),
                                      retry_period_s=0.5)) for i in range(3)]  # fmt: skip
    lost = Telemetry(TelemetryConfig(vehicle_id="lost", mode="client", connect=(nobody,),
                                     retry_period_s=0.5))  # fmt: skip
    try:
        for tel in cars:
            tel.start()
            time.sleep(0.3)
        lost.start()
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and not (
            cars[2].health().status == "down" and lost.health().status == "down"
        ):
            time.sleep(0.1)
        full, gone = cars[2].health(), lost.health()
        assert [c.health().valid for c in cars[:2]] == [True, True]
        assert not full.valid and "no router took this car" in full.detail
        assert "refused the session" in full.detail and full.warning
        assert "did not answer" in gone.detail and "refused" not in gone.detail
    finally:
        for tel in [*cars, lost]:
            tel.close()
        router.close()
