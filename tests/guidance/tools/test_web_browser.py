"""The web map in a real headless Chromium (issue 16, item 3).

Two ``guidance sim`` processes (cars ``alpha`` and ``bravo``, Zenoh on loopback, multicast
scouting off) and ``guidance monitor --web 127.0.0.1:0`` run as real processes; the system's
Chromium (Debian ``chromium`` + ``chromium-driver``, driven by selenium; nothing downloaded)
opens the page. From the DOM: both cars appear, their positions move, each has an ellipse;
``alpha`` killed with SIGKILL is shown as gone within a few seconds while ``bravo`` goes on.
A screenshot is saved to ``out/test-artifacts/web_monitor.png`` (or ``$GUIDANCE_TEST_ARTIFACTS``).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[3]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        CHROMIUM is None or CHROMEDRIVER is None,
        reason="needs the Debian packages chromium and chromium-driver (.ci/run installs them)",
    ),
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def sim_config(tmp: Path, vehicle: str, port: int, seed: int) -> Path:
    """config/sim.toml with this car's id, seed and its own loopback endpoint."""
    text = (REPO / "config" / "sim.toml").read_text()
    text = text.replace("[vehicle]\n", f'[vehicle]\nid = "{vehicle}"\n')
    text = re.sub(r"(?m)^seed = \d+", f"seed = {seed}", text)
    text = text.replace('listen = ["tcp/127.0.0.1:7447"]', f'listen = ["tcp/127.0.0.1:{port}"]')
    assert f"127.0.0.1:{port}" in text and f'"{vehicle}"' in text
    path = tmp / f"{vehicle}.toml"
    path.write_text(text)
    return path


@pytest.fixture
def processes() -> Iterator[Callable[..., subprocess.Popen[str]]]:
    procs: list[subprocess.Popen[str]] = []

    def start(*args: str, stdout: int | None = subprocess.DEVNULL) -> subprocess.Popen[str]:
        p = subprocess.Popen(
            [sys.executable, "-m", "guidance.tools.cli", *args],
            cwd=REPO,
            stdout=stdout,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        procs.append(p)
        return p

    yield start
    for p in procs:
        if p.poll() is None:
            p.kill()
        p.wait(10)


def browser(tmp: Path) -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    os.environ["SE_OFFLINE"] = "true"  # selenium must never fetch a browser or driver
    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--window-size=1280,800",
        f"--user-data-dir={tmp / 'chromium-profile'}",
    ):
        opts.add_argument(flag)
    return webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)), options=opts)


def cars(driver: Any) -> dict[str, dict[str, Any]]:
    """What the page shows for each car, read from its SVG and cards."""
    return dict(
        driver.execute_script(
            """
            const out = {};
            for (const g of document.querySelectorAll('#cars g.car')) {
              const e = g.querySelector('ellipse.ellipse');
              const card = document.querySelector(`li.card[data-vehicle="${g.dataset.vehicle}"]`);
              out[g.dataset.vehicle] = {
                alive: g.dataset.alive === 'true',
                x: g.dataset.x === undefined ? null : parseFloat(g.dataset.x),
                y: g.dataset.y === undefined ? null : parseFloat(g.dataset.y),
                rx: e ? parseFloat(e.getAttribute('rx')) : 0,
                track: !!g.querySelector('polyline.track'),
                goal: !!g.querySelector('polygon.goal'),
                card_gone: card ? card.classList.contains('gone') : null,
                card_text: card ? card.textContent : '',
              };
            }
            return out;
            """
        )
    )


def wait_for(cond: Callable[[], Any], timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")


def artifact_dir() -> Path:
    d = Path(os.environ.get("GUIDANCE_TEST_ARTIFACTS", REPO / "out" / "test-artifacts"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def test_two_simulated_cars_on_the_web_map_and_one_killed(
    tmp_path: Path, processes: Callable[..., subprocess.Popen[str]]
) -> None:
    ports = {"alpha": free_port(), "bravo": free_port()}
    sims = {
        vid: processes(
            "sim",
            "--config",
            str(sim_config(tmp_path, vid, port, seed)),
            "--speed",
            "4",
            "--duration",
            "3000",
            "--no-voice",
            "--no-record",
            "--no-png",
            "--out",
            str(tmp_path / vid),
        )
        for (vid, port), seed in zip(ports.items(), (7, 11), strict=True)
    }
    connect = [a for p in ports.values() for a in ("--connect", f"tcp/127.0.0.1:{p}")]
    web = processes("monitor", "--web", "127.0.0.1:0", *connect, stdout=subprocess.PIPE)
    assert web.stdout is not None
    line = web.stdout.readline()
    m = re.search(r"http://127\.0\.0\.1:\d+/", line)
    assert m, f"monitor said {line!r}"

    driver = browser(tmp_path)
    try:
        driver.get(m.group(0))
        assert driver.title == "guidance monitor: fleet map"

        def both_drawn() -> dict[str, dict[str, Any]] | None:
            seen = cars(driver)
            ready = all(v in seen and seen[v]["x"] is not None for v in ports)
            return seen if ready else None

        first = wait_for(both_drawn, 90.0, "both cars on the page")
        t0 = time.monotonic()

        def both_moved() -> dict[str, dict[str, Any]] | None:
            now = cars(driver)
            moved = all((now[v]["x"], now[v]["y"]) != (first[v]["x"], first[v]["y"]) for v in ports)
            return now if moved else None

        now = wait_for(both_moved, 20.0, "both cars to move")
        for vid in ports:
            car = now[vid]
            assert car["alive"] and not car["card_gone"] and "live" in car["card_text"]
            assert car["rx"] > 0 and car["track"] and car["goal"], car
            assert "hdg" in car["card_text"] and "health:" in car["card_text"]

        # the page's track, built from the new points of each poll, is the server's whole one
        # (its last point, the newest position, may since have been replaced)
        def merged_tracks() -> dict[str, Any] | None:
            tracks: dict[str, Any] = driver.execute_async_script(
                """const done = arguments[arguments.length - 1];
                fetch('/api/fleet', {cache: 'no-store'}).then((r) => r.json()).then((f) => {
                  const out = {};
                  for (const c of f.cars) {
                    const kept = state.tracks.get(c.vehicle_id);
                    out[c.vehicle_id] = [kept ? kept.points.slice(0, -1) : [], c.track];
                  }
                  done(out);
                });"""
            )
            grown = all(len(tracks[v][0]) >= 5 for v in ports)  # several polls' points
            return tracks if grown else None

        tracks = wait_for(merged_tracks, 60.0, "the page's tracks to grow over several polls")
        for vid in ports:
            mine, whole = tracks[vid]
            assert mine == whole[: len(mine)], (vid, mine, whole)
        print(f"both cars moving on the page {time.monotonic() - t0:.1f} s after both appeared")
        driver.save_screenshot(str(tmp_path / "live.png"))

        sims["alpha"].send_signal(signal.SIGKILL)
        sims["alpha"].wait(10)
        killed = time.monotonic()
        after = wait_for(
            lambda: (c := cars(driver)) and not c["alpha"]["alive"] and c["alpha"]["card_gone"]
            and c,
            10.0,
            "alpha shown as gone",
        )  # fmt: skip
        gone_s = time.monotonic() - killed
        print(f"alpha shown as gone {gone_s:.2f} s after SIGKILL")
        assert gone_s < 5.0
        assert "gone" in after["alpha"]["card_text"]
        bravo = after["bravo"]
        assert bravo["alive"] and not bravo["card_gone"]
        wait_for(
            lambda: (cars(driver)["bravo"]["x"], cars(driver)["bravo"]["y"])
            != (bravo["x"], bravo["y"]),
            20.0,
            "bravo to keep moving",
        )  # fmt: skip
        shot = artifact_dir() / "web_monitor.png"
        assert driver.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
    finally:
        driver.quit()


def test_tiles_come_only_from_the_configured_server_and_cover_the_car(tmp_path: Path) -> None:
    """A local tile server: the page asks it for the tile under the car (the tile maths), and
    the browser loads nothing from anywhere but the monitor and that server."""
    import http.server
    import io
    import math
    import threading

    from PIL import Image

    from guidance.core.messages import Ellipse, EstimateState
    from guidance.outputs.kinds import STATE, OutputContext
    from guidance.telemetry.client import MonitorClient
    from guidance.telemetry.config import TelemetryConfig
    from guidance.telemetry.publisher import Telemetry
    from guidance.tools.web.server import WebMonitor

    buf = io.BytesIO()
    Image.new("RGB", (256, 256), (235, 240, 225)).save(buf, "PNG")
    png, requested = buf.getvalue(), []

    class Tiles(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            requested.append(self.path)
            self.send_response(200)
            self.send_header("Content-Type", "image/png")
            self.send_header("Content-Length", str(len(png)))
            self.end_headers()
            self.wfile.write(png)

        def log_message(self, *_args: Any) -> None:
            pass

    tiles = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Tiles)
    threading.Thread(target=tiles.serve_forever, daemon=True).start()
    tile_url = f"http://127.0.0.1:{tiles.server_address[1]}/{{z}}/{{x}}/{{y}}.png"
    origin, port = (42.444, -76.5019), free_port()
    cfg = TelemetryConfig(
        vehicle_id="tiled", listen=(f"tcp/127.0.0.1:{port}",), origin_lat_lon_deg=origin
    )
    cov = ((25.0, 0.0, 0.0), (0.0, 25.0, 0.0), (0.0, 0.0, 0.01))
    with Telemetry(cfg) as tel, MonitorClient([f"tcp/127.0.0.1:{port}"]) as client:
        web = WebMonitor(client, "127.0.0.1", 0, tiles=tile_url).start()
        driver = browser(tmp_path)
        try:
            for i in range(20):  # a short drive north-east of the origin
                st = EstimateState(float(i), 300.0 + 5 * i, 200.0 + 5 * i, 0.8, cov,
                                   Ellipse(10.0, 10.0, 0.0, 20.0), False, True)  # fmt: skip
                tel.send(STATE, st, OutputContext(goal=(600.0, 500.0)))
                time.sleep(0.05)
            driver.get(web.url)
            wait_for(lambda: cars(driver).get("tiled", {}).get("x") == 395.0, 20.0, "the car")
            wait_for(lambda: requested, 10.0, "tile requests")
            srcs = driver.execute_script(
                "return [...document.querySelectorAll('#tiles image')]"
                ".map(i => i.getAttribute('href'))"
            )
            assert srcs and all(s.startswith(tile_url.split("{")[0]) for s in srcs)
            z = {int(p.split("/")[1]) for p in requested}
            assert len(z) == 1 and 12 <= min(z) <= 19, requested
            lat, lon = driver.execute_script(
                "const s = document.querySelector('li.card[data-vehicle=tiled] .geo');"
                "return s.textContent.split(', ').map(Number);"
            )
            n = 2 ** min(z)
            tx = math.floor((lon + 180) / 360 * n)
            r = math.radians(lat)
            ty = math.floor((1 - math.log(math.tan(r) + 1 / math.cos(r)) / math.pi) / 2 * n)
            # the tile under the car: the browser asks for the tiles one by one, and on a
            # loaded machine the first ones are in while the rest are still to come
            under = f"/{min(z)}/{tx}/{ty}.png"
            wait_for(lambda: under in requested, 20.0, f"the tile under the car {under}")
            loaded = driver.execute_script(
                "return performance.getEntriesByType('resource').map(e => e.name)"
            )
            page, tile_host = web.url.rstrip("/"), tile_url.split("/{")[0]
            assert all(u.startswith((page, tile_host)) for u in loaded), loaded
        finally:
            driver.quit()
            web.close()
            tiles.shutdown()
            tiles.server_close()


CAR = r"""
import sys, time, zenoh
from guidance.core.messages import Ellipse, EstimateState, Health, Target
from guidance.outputs.messages import encode, health_message, state_message
from guidance.telemetry.keys import key_for, liveliness_key
from guidance.telemetry.session import open_session, session_config
vid, port, x0, drops = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
s = open_session(session_config(mode="peer", listen=[f"tcp/127.0.0.1:{port}"]))
pubs = {k: s.declare_publisher(key_for(vid, k)) for k in ("state", "health")}
token = s.liveliness().declare_token(liveliness_key(vid))
cov = ((25.0, 0.0, 0.0), (0.0, 9.0, 0.0), (0.0, 0.0, 0.01))
tel = Health("telemetry", "up", True, True,
             counters={"dropped": drops, "dropped_superseded": drops - 1 if drops else 0,
                       "dropped_session_down": 1 if drops else 0})
print("up", flush=True)
seq = 0
while True:
    seq += 1
    st = EstimateState(seq * 0.1, x0 + seq, 50.0 * (x0 > 0), 0.3, cov,
                       Ellipse(10.0, 6.0, 0.4, 20.0), False, True)
    pubs["state"].put(encode(state_message(st, vehicle_id=vid, seq=seq, goal=(x0 + 400, 600.0),
                      target=Target(x0 + 400, 600.0, "goal", None),
                      origin_lat_lon_deg=(48.85, 2.35), chance=0.42 if x0 == 0 else 0.9)))
    if seq % 5 == 1:
        inputs = {"compass": Health("compass", "ok", True, True)}
        pubs["health"].put(encode(health_message(seq * 0.1, inputs, vehicle_id=vid,
                           seq=seq // 5 + 1, components={"telemetry": tel})))
    time.sleep(0.1)
"""


def page_cars(driver: Any) -> dict[str, dict[str, Any]]:
    """Per car: colour, label text and its contrast on the map's white, ellipse sizes, card."""
    return dict(
        driver.execute_script(
            """
            const lum = (rgb) => {
              const c = rgb.map((v) => { v /= 255; return v <= 0.03928 ? v / 12.92
                                                     : Math.pow((v + 0.055) / 1.055, 2.4); });
              return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
            };
            const out = {};
            for (const g of document.querySelectorAll('#cars g.car')) {
              const label = g.querySelector('text.label');
              const e = g.querySelector('ellipse.ellipse');
              const dot = g.querySelector('circle.position');
              const card = document.querySelector(`li.card[data-vehicle="${g.dataset.vehicle}"]`);
              let alpha = 1;
              for (let n = label; n && n.id !== 'map'; n = n.parentElement) {
                alpha *= parseFloat(getComputedStyle(n).opacity);
              }
              const fill = getComputedStyle(label).fill.match(/\\d+/g).slice(0, 3).map(Number)
                .map((v) => v * alpha + 255 * (1 - alpha));  // on the map's white
              const dropped = card && card.querySelector('.dropped');
              out[g.dataset.vehicle] = {
                alive: g.dataset.alive === 'true',
                colour: dot.getAttribute('fill'),
                label: label.textContent,
                contrast: 1.05 / (lum(fill) + 0.05),
                rx_px: e ? parseFloat(e.getAttribute('rx')) : 0,
                ry_px: e ? parseFloat(e.getAttribute('ry')) : 0,
                to_scale: e ? e.dataset.toScale === 'true' : null,
                true_rx_px: e ? parseFloat(e.dataset.trueRxPx) : null,
                card_text: card ? card.textContent : '',
                dropped_text: dropped ? dropped.textContent : '',
                dropped_title: dropped ? dropped.title : '',
                chance_low: !!(card && card.querySelector('.chance.low')),
              };
            }
            return out;
            """
        )
    )


def test_three_cars_one_killed_stable_colours_readable_gone_card_and_visible_ellipses(
    tmp_path: Path, processes: Callable[..., subprocess.Popen[str]]
) -> None:
    """Issue 24, item 2: three cars 3 km apart (the automatic grid makes their 10 m ellipses
    sub-pixel), one with 31 dropped messages; bravo killed with SIGKILL."""
    ports = {"alpha": free_port(), "bravo": free_port(), "charlie": free_port()}
    cars_p = {}
    for (vid, port), x0, drops in zip(ports.items(), (0.0, 1500.0, 3000.0), (31, 0, 0),
                                      strict=True):  # fmt: skip
        p = subprocess.Popen(
            [sys.executable, "-c", CAR, vid, str(port), str(x0), str(drops)],
            cwd=REPO, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        cars_p[vid] = p
        assert p.stdout is not None and p.stdout.readline().strip() == "up"
    try:
        connect = [a for p in ports.values() for a in ("--connect", f"tcp/127.0.0.1:{p}")]
        web = processes("monitor", "--web", "127.0.0.1:0", *connect, stdout=subprocess.PIPE)
        assert web.stdout is not None
        m = re.search(r"http://127\.0\.0\.1:\d+/", web.stdout.readline())
        assert m
        driver = browser(tmp_path)
        try:
            driver.get(m.group(0))
            first = wait_for(
                lambda: (c := page_cars(driver)) and len(c) == 3 and c, 30.0, "three cars"
            )
            legend = driver.find_element("id", "legend").text
            for word in ("estimate", "track", "goal", "landmark", "2σ ellipse", "gone"):
                assert word in legend, legend
            for car in first.values():  # the ellipse: never sub-pixel, true size said
                assert car["alive"] and car["rx_px"] >= 6 and car["ry_px"] >= 2, car
                assert car["true_rx_px"] < 6 and car["to_scale"] is False, car
                assert "2σ 20 m (not to scale)" in car["label"], car
                assert "health: ok" in car["card_text"], car
            assert len({c["colour"] for c in first.values()}) == 3
            # the chance of reaching the goal, as each car published it; a low one flagged
            assert "chance of reaching the goal 40 %" in first["alpha"]["card_text"]
            assert first["alpha"]["chance_low"] and not first["charlie"]["chance_low"]
            assert "chance of reaching the goal 90 %" in first["charlie"]["card_text"]
            alpha = first["alpha"]  # "(31 dropped)" explained where it is shown
            assert alpha["dropped_text"].startswith("31 telemetry messages not sent by the car")
            assert "replaced by a newer one" in alpha["dropped_text"]
            assert "did not send" in alpha["dropped_title"], alpha

            cars_p["bravo"].send_signal(signal.SIGKILL)
            cars_p["bravo"].wait(10)
            after = wait_for(
                lambda: (c := page_cars(driver)) and not c["bravo"]["alive"] and c,
                15.0, "bravo shown as gone",
            )  # fmt: skip
            bravo = after["bravo"]
            assert bravo["label"].startswith("bravo (gone)"), bravo
            assert bravo["contrast"] >= 4.5, bravo  # WCAG AA for text, on the map's white
            assert "GONE" in bravo["card_text"] and "liveliness token dropped" in bravo["card_text"]
            assert "health: ok" not in bravo["card_text"], bravo
            for vid in ("alpha", "charlie"):  # the survivors keep their colours
                assert after[vid]["colour"] == first[vid]["colour"] and after[vid]["alive"]
            driver.refresh()  # and so does a fresh page: the colour comes from the id
            again = wait_for(
                lambda: (c := page_cars(driver)) and len(c) == 3 and c, 20.0, "after reload"
            )
            assert {v: c["colour"] for v, c in again.items()} == {
                v: c["colour"] for v, c in first.items()
            }
            time.sleep(1.0)
            shot = artifact_dir() / "web_monitor_gone.png"
            assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
        finally:
            driver.quit()
    finally:
        for p in cars_p.values():
            if p.poll() is None:
                p.kill()
            p.wait(10)
