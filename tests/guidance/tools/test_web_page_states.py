"""Issue 23, item 3: one car's state that the web page cannot draw never breaks the map for the
other cars, in a real headless Chromium (the system's ``chromium`` + ``chromium-driver``, driven
by selenium as in test_web_browser.py; nothing downloaded).

* End to end (real Zenoh on 127.0.0.1, multicast scouting off): a rogue car sends one good state,
  then states the page cannot draw (``lat_deg`` without ``lon_deg``, ``lon_deg: null``, a goal
  without ``y_m``, an origin without ``lon_deg``). The monitor's check (the state's schema)
  rejects and counts each one, and the good car goes on moving on the page.
* The page alone: the same states (and a car whose entry is broken beyond any schema) served
  straight to the page, past the check: each car is drawn on its own, the good one moves on.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_web_browser import CHROMEDRIVER, CHROMIUM, browser, cars, wait_for

from guidance.core.messages import Ellipse, EstimateState
from guidance.outputs.kinds import STATE, OutputContext
from guidance.telemetry.client import MonitorClient
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
from guidance.telemetry.session import open_session, session_config
from guidance.tools.web.server import WebMonitor

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        CHROMIUM is None or CHROMEDRIVER is None,
        reason="needs the Debian packages chromium and chromium-driver (.ci/run installs them)",
    ),
]

ORIGIN = {"lat_deg": 42.444, "lon_deg": -76.5019}
COV = ((4.0, 0.0, 0.0), (0.0, 4.0, 0.0), (0.0, 0.0, 0.01))
UNDRAWABLE: dict[str, dict[str, Any]] = {
    "lat_deg without lon_deg": {"lat_deg": 42.445},
    "lon_deg null": {"lat_deg": 42.445, "lon_deg": None},
    "a goal without y_m": {"goal": {"x_m": 300.0}},
    "an origin without lon_deg": {"origin": {"lat_deg": 42.444}},
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def state(vid: str, seq: int, **fields: Any) -> dict[str, Any]:
    body = {"schema": "guidance.state/1", "vehicle_id": vid, "seq": seq, "t_s": seq * 0.1,
            "x_m": -50.0, "y_m": 40.0, "heading_rad": 0.0, "origin": dict(ORIGIN),
            "goal": {"x_m": 100.0, "y_m": 100.0}}  # fmt: skip
    return {**body, **fields}


def status(driver: Any) -> tuple[str, str, str]:
    """The status line: its class, its text and the cars it could not draw."""
    return tuple(  # type: ignore[return-value]
        driver.execute_script(
            "const s = document.getElementById('status');"
            "return [s.className, s.textContent, s.dataset.undrawn || ''];"
        )
    )


class GoodCar:
    """The real ``Telemetry`` of car ``good``, driving east: a state every 50 ms."""

    def __init__(self, port: int) -> None:
        origin = (ORIGIN["lat_deg"], ORIGIN["lon_deg"])
        cfg = TelemetryConfig(
            vehicle_id="good", listen=(f"tcp/127.0.0.1:{port}",), origin_lat_lon_deg=origin
        )
        self.tel = Telemetry(cfg)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="good-car", daemon=True)

    def _run(self) -> None:
        i = 0
        while not self._stop.wait(0.05):
            i += 1
            est = EstimateState(i * 0.05, float(i), 0.0, 0.0, COV, Ellipse(2, 2, 0, 4), False, True)
            self.tel.send(STATE, est, OutputContext(goal=(400.0, 0.0)))

    def __enter__(self) -> GoodCar:
        self.tel.start()
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        self.tel.close()


@pytest.fixture
def driver(tmp_path: Path) -> Iterator[Any]:
    d = browser(tmp_path)
    try:
        yield d
    finally:
        d.quit()


def test_states_the_page_cannot_draw_are_rejected_and_the_good_car_stays_drawn(
    driver: Any,
) -> None:
    good_port, rogue_port = free_port(), free_port()
    rogue = open_session(session_config(mode="peer", listen=[f"tcp/127.0.0.1:{rogue_port}"]))
    connect = [f"tcp/127.0.0.1:{good_port}", f"tcp/127.0.0.1:{rogue_port}"]
    try:
        with GoodCar(good_port), MonitorClient(connect) as client:
            web = WebMonitor(client, "127.0.0.1", 0).start()
            try:
                driver.get(web.url)
                seq = 1
                rogue.put("guidance/rogue/state", json.dumps(state("rogue", seq)))
                wait_for(
                    lambda: (
                        {"good", "rogue"} <= cars(driver).keys()
                        and cars(driver)["good"]["x"] is not None
                    ),
                    30.0,
                    "both cars drawn",
                )
                for what, fields in UNDRAWABLE.items():
                    bad_before = web.fleet()["bad_messages"]
                    x_before = cars(driver)["good"]["x"]
                    for _ in range(10):
                        seq += 1
                        rogue.put("guidance/rogue/state", json.dumps(state("rogue", seq, **fields)))
                        time.sleep(0.1)
                    time.sleep(1.0)  # two polls of the page
                    cls, text, _ = status(driver)
                    assert cls != "error" and "unreachable" not in text, (what, text)
                    now = cars(driver)
                    assert now["good"]["x"] != x_before, f"good car frozen after {what}"
                    assert now["rogue"]["x"] == -50.0, what  # its last good state, drawn
                    assert web.fleet()["bad_messages"] >= bad_before + 10, (
                        f"{what}: the monitor's check let it through"
                    )
            finally:
                web.close()
    finally:
        rogue.close()


def test_the_page_draws_each_car_on_its_own(driver: Any) -> None:
    """States served to the page past the check (as if the schema had a gap): each bad car
    costs only its own drawing; one broken beyond any schema is listed as not drawn."""
    web = WebMonitor(MonitorClient(["tcp/127.0.0.1:9"]), "127.0.0.1", 0)
    polls = {"n": 0}

    def car(vid: str, st: dict[str, Any] | None, track: Any) -> dict[str, Any]:
        return {"vehicle_id": vid, "alive": True, "age_s": 0.1, "state": st, "track": track,
                "prompt": "", "health": {"ok": True, "summary": "ok"}, "messages": 1,
                "bad_messages": 0, "bad": "", "gaps": 0}  # fmt: skip

    def fleet(*_query: Any) -> dict[str, Any]:
        polls["n"] += 1
        n = polls["n"]
        bad = [
            car(f"bad{i}", state(f"bad{i}", n, **fields), [[0.0, 0.0], [1.0, 1.0]])
            for i, fields in enumerate(UNDRAWABLE.values(), start=1)
        ]
        broken = car("bad5", state("bad5", n), None)  # no track list at all
        good = car("good", state("good", n, x_m=float(n)), [[0.0, 0.0], [float(n), 0.0]])
        return {"schema": "guidance.fleet/1", "cars": [*bad, broken, good], "messages": n,
                "bad_messages": 0, "bad_keys": 0, "server": {}}  # fmt: skip

    web.fleet = fleet  # type: ignore[method-assign]
    with web:
        driver.get(web.url)
        first = wait_for(lambda: cars(driver).get("good", {}).get("x"), 20.0, "the good car")
        wait_for(lambda: cars(driver)["good"]["x"] != first, 10.0, "the good car to move")
        cls, text, undrawn = status(driver)
        assert cls != "error" and "unreachable" not in text, text
        assert undrawn == "bad5" and "not drawn: bad5" in text
        shown = cars(driver)
        assert shown["good"]["goal"] and shown["good"]["track"], shown["good"]
        for vid in ("bad1", "bad2", "bad3", "bad4"):
            assert shown[vid]["x"] == -50.0 and shown[vid]["card_text"], vid
        geo = driver.execute_script(
            "return [...document.querySelectorAll('li.card .geo')].map(e => e.textContent)"
        )
        assert not any("undefined" in g or "NaN" in g for g in geo), geo
