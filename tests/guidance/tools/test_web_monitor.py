"""``guidance monitor --web`` server: the fleet API over real Zenoh on loopback, the packaged
assets, and the binding and Host rules (the browser test is
tests/guidance/tools/test_web_browser.py)."""

from __future__ import annotations

import http.client
import json
import re
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import pytest

from guidance.core.messages import Ellipse, EstimateState, Prompt
from guidance.errors import UserError
from guidance.outputs.kinds import PROMPT, STATE, OutputContext
from guidance.telemetry.client import MonitorClient
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
from guidance.tools.web.server import WebMonitor, check_web_args, parse_bind

REPO = Path(__file__).resolve().parents[3]
ORIGIN = (42.444, -76.5019)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def get(url_port: int, path: str, host: str | None = None) -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", url_port, timeout=5)
    try:
        conn.putrequest("GET", path, skip_host=host is not None)
        if host is not None:
            conn.putheader("Host", host)
        conn.endheaders()
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


def wait_until(cond: Callable[[], Any], timeout_s: float = 30.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.05)
    return cond()


@pytest.fixture
def car_and_web() -> Iterator[tuple[Telemetry, WebMonitor]]:
    port = free_port()
    cfg = TelemetryConfig(
        vehicle_id="van7", listen=(f"tcp/127.0.0.1:{port}",), origin_lat_lon_deg=ORIGIN
    )
    tel = Telemetry(cfg)
    tel.start()
    client = MonitorClient([f"tcp/127.0.0.1:{port}"]).open()
    web = WebMonitor(client, "127.0.0.1", 0).start()
    try:
        # zenoh keeps nothing for a subscriber not yet linked: the tests send once the car
        # sees the monitor (about a second here; a CI run beside two spinning processes sent
        # into the void and waited out 10 s)
        assert wait_until(lambda: tel.health().counters.get("peers", 0) >= 1, 60.0)
        yield tel, web
    finally:
        web.close()
        client.close()
        tel.close()


def test_fleet_api_shows_a_live_car_with_its_state_prompt_and_health(
    car_and_web: tuple[Telemetry, WebMonitor],
) -> None:
    tel, web = car_and_web
    port = web.httpd.server_address[1]
    cov = ((9.0, 1.0, 0.0), (1.0, 4.0, 0.0), (0.0, 0.0, 0.01))
    for i in range(5):
        tel.send(
            STATE,
            EstimateState(
                float(i), 10.0 * i, 0.0, 0.0, cov, Ellipse(6.2, 3.9, 0.2, 12.4), False, True
            ),
            OutputContext(goal=(300.0, 0.0)),
        )
        time.sleep(0.1)
    tel.send(PROMPT, Prompt(4.0, "<img src=x onerror=alert(1)> turn left", 0, "turn"))

    def fleet() -> dict[str, Any] | None:
        _status, _h, body = get(port, "/api/fleet")
        data = json.loads(body)
        cars = data["cars"]
        ok = cars and cars[0]["prompt"] and cars[0]["state"] and cars[0]["state"]["x_m"] == 40.0
        return data if ok else None

    data = wait_until(fleet)
    assert data is not None, get(port, "/api/fleet")
    car = data["cars"][0]
    assert car["vehicle_id"] == "van7" and car["alive"] is True
    assert car["state"]["lat_deg"] == pytest.approx(ORIGIN[0], abs=1e-3)
    assert car["state"]["ellipse"]["semi_major_m"] == 6.2
    assert car["track"][-1] == [40.0, 0.0] and len(car["track"]) >= 2
    assert car["prompt"].startswith("<img")  # sent as data; the page sets it as text
    assert 0.0 <= car["age_s"] < 5.0
    assert car["health"] == {"ok": None, "summary": "-", "dropped": 0, "dropped_by_reason": {},
                             "dropped_text": ""}  # fmt: skip
    assert car["gone"] == "" and car["gone_s_ago"] is None


def test_after_the_first_poll_only_new_track_points_are_sent() -> None:
    """1,000 cars: a poll with the last answer's generation and epoch carries each car's new
    points only (from ``track_start``), and is small; a stale epoch or a generation from the
    future gets the whole tracks again."""
    from guidance.telemetry.client import TelemetryEvent
    from guidance.tools.web.server import fleet_query

    web = WebMonitor(MonitorClient(["tcp/127.0.0.1:9"]), "127.0.0.1", 0)
    try:

        def drive(step: int) -> None:
            for i in range(1000):
                msg = {"schema": "guidance.state/1", "vehicle_id": f"car{i:04d}", "seq": step,
                       "t_s": float(step), "x_m": 3.0 * step, "y_m": float(i)}  # fmt: skip
                web.view.apply(TelemetryEvent("state", f"car{i:04d}", "k", msg, float(step)))

        for step in range(1, 101):
            drive(step)
        whole = web.fleet()
        assert all(len(c["track"]) == 100 and c["track_start"] is None for c in whole["cars"])
        drive(101)
        new = web.fleet(whole["generation"], whole["epoch"])
        assert all(c["track_start"] == 100 and c["track"] == [[303.0, c["state"]["y_m"]]]
                   for c in new["cars"])  # fmt: skip
        big = len(json.dumps(whole, separators=(",", ":")))
        small = len(json.dumps(new, separators=(",", ":")))
        assert small < big / 3, (small, big)
        for since, epoch in ((whole["generation"], "other"), (10**9, whole["epoch"])):
            again = web.fleet(since, epoch)
            assert all(c["track_start"] is None and len(c["track"]) == 101 for c in again["cars"])
    finally:
        web.httpd.server_close()
    assert fleet_query("/api/fleet?since=12&epoch=ab") == (12, "ab")
    for bad in ("/api/fleet?since=-1", "/api/fleet?since=1e3", "/api/fleet?since=" + "9" * 400,
                "/api/fleet?" + "&".join(f"a{i}=1" for i in range(20)), "/api/fleet"):  # fmt: skip
        assert fleet_query(bad)[0] is None, bad


def test_an_answer_is_bounded_and_built_outside_the_fold_lock(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Issue 40 (a low): ``/api/fleet?since=0`` returned every car's unthinned track (4.3 MB
    for 50 cars) and built it while holding the lock the folding thread needs (3.5 s). Now a
    car with more new points than ``TRACK_POINTS_SENT`` gets its whole track thinned (as
    without ``since``; ``track_start`` null, the page replaces its copy), under the lock only
    bounded copies are taken, and the JSON is built after it is released."""
    from guidance.telemetry.client import TelemetryEvent
    from guidance.tools.web import server
    from guidance.tools.web.server import TRACK_POINTS_SENT

    web = WebMonitor(MonitorClient(["tcp/127.0.0.1:9"]), "127.0.0.1", 0)
    try:
        n_points = 2 * TRACK_POINTS_SENT + 7
        for step in range(1, n_points + 1):
            for i in range(3):
                msg = {"schema": "guidance.state/1", "vehicle_id": f"car{i}", "seq": step,
                       "t_s": float(step), "x_m": 3.0 * step, "y_m": float(i)}  # fmt: skip
                web.view.apply(TelemetryEvent("state", f"car{i}", "k", msg, float(step)))
        real = server.car_json
        held: list[bool] = []

        def spy(*args: Any, **kw: Any) -> dict[str, Any]:
            held.append(web.lock.locked())
            return real(*args, **kw)

        monkeypatch.setattr(server, "car_json", spy)
        whole = web.fleet()
        since_0 = web.fleet(0, whole["epoch"])
        assert held == [False] * 6  # three cars, two answers: none built under the lock
        for a, b in zip(whole["cars"], since_0["cars"], strict=True):
            assert a["track_start"] is None and b["track_start"] is None
            assert len(a["track"]) == TRACK_POINTS_SENT and b["track"] == a["track"]
            assert a["track"][0] == [3.0, a["state"]["y_m"]]
            assert a["track"][-1] == [3.0 * n_points, a["state"]["y_m"]]
        # a page that is only a little behind still gets only the new points
        recent = web.fleet(whole["generation"] - 3 * TRACK_POINTS_SENT, whole["epoch"])
        assert all(c["track_start"] == n_points - TRACK_POINTS_SENT for c in recent["cars"])
        assert all(len(c["track"]) == TRACK_POINTS_SENT for c in recent["cars"])
    finally:
        web.httpd.server_close()


def test_page_and_assets_come_from_the_package_with_a_strict_csp(
    car_and_web: tuple[Telemetry, WebMonitor],
) -> None:
    _tel, web = car_and_web
    port = web.httpd.server_address[1]
    status, headers, body = get(port, "/")
    assert status == 200 and b'<script src="/static/app.js">' in body
    csp = headers["content-security-policy"]
    assert "script-src 'self'" in csp and "default-src 'none'" in csp
    assert headers["x-content-type-options"] == "nosniff"
    for name in ("app.js", "style.css"):
        status, _h, served = get(port, f"/static/{name}")
        packaged = resources.files("guidance.tools.web").joinpath("static", name).read_bytes()
        assert status == 200 and served == packaged
    assert get(port, "/static/../server.py")[0] == 404
    assert json.loads(get(port, "/api/config")[2])["tiles"] == ""


def test_no_cdn_every_asset_is_local() -> None:
    static = resources.files("guidance.tools.web").joinpath("static")
    names = sorted(p.name for p in static.iterdir())
    assert names == ["app.js", "index.html", "style.css"]
    for name in names:
        text = static.joinpath(name).read_text()
        urls = set(re.findall(r"https?://[^\s\"')]+", text)) - {"http://www.w3.org/2000/svg"}
        assert urls == set(), (name, urls)
        assert "innerHTML" not in text and "insertAdjacentHTML" not in text
    pyproject = (REPO / "pyproject.toml").read_text()
    assert '"guidance.tools.web" = ["static/*.html", "static/*.js", "static/*.css"]' in pyproject


def test_a_foreign_host_header_is_refused_on_loopback(
    car_and_web: tuple[Telemetry, WebMonitor],
) -> None:
    _tel, web = car_and_web
    port = web.httpd.server_address[1]
    assert get(port, "/api/fleet", host=f"localhost:{port}")[0] == 200
    assert get(port, "/api/fleet", host=f"[::1]:{port}")[0] == 200
    assert get(port, "/api/fleet", host=f"attacker.example:{port}")[0] == 421  # DNS rebinding
    assert get(port, "/", host="")[0] == 421


def test_binding_rules_and_tile_templates() -> None:
    assert parse_bind("127.0.0.1:0") == ("127.0.0.1", 0)
    assert parse_bind("[::1]:8080") == ("::1", 8080)
    assert parse_bind("9000") == ("127.0.0.1", 9000)
    assert check_web_args("localhost:1", allow_remote=False, tiles="") == ("localhost", 1)
    with pytest.raises(UserError, match="--allow-remote"):
        check_web_args("0.0.0.0:8765", allow_remote=False, tiles="")
    assert check_web_args("0.0.0.0:8765", allow_remote=True, tiles="") == ("0.0.0.0", 8765)
    with pytest.raises(UserError, match="HOST:PORT"):
        parse_bind("host:port")
    with pytest.raises(UserError, match=r"\{z\}"):
        check_web_args("127.0.0.1:1", allow_remote=False, tiles="http://tiles.lan/a.png")
    with pytest.raises(UserError, match="http"):
        check_web_args("127.0.0.1:1", allow_remote=False, tiles="file:///{z}/{x}/{y}")
    ok = "http://tiles.lan:8080/{z}/{x}/{y}.png"
    assert check_web_args("127.0.0.1:1", allow_remote=False, tiles=ok)


def test_tile_server_is_the_only_other_image_source() -> None:
    client = MonitorClient([f"tcp/127.0.0.1:{free_port()}"])  # never opened
    web = WebMonitor(client, "127.0.0.1", 0, tiles="http://tiles.lan:8080/{z}/{x}/{y}.png")
    try:
        assert "img-src 'self' data: http://tiles.lan:8080;" in web.csp()
        assert web.page_config()["tiles"].startswith("http://tiles.lan:8080/")
    finally:
        web.httpd.server_close()


def test_cli_refuses_a_public_bind_without_the_flag() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "monitor", "--web", "0.0.0.0:0"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "--allow-remote" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
