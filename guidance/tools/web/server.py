"""``guidance monitor --web``: a live map of the fleet in a browser, from one process.

A thread folds the Zenoh telemetry events into a ``FleetView`` (the terminal monitor's);
a standard-library HTTP server serves the page and its assets (package data: no build step,
no CDN) and ``/api/fleet``, a JSON snapshot of every car the page polls four times a second.

The snapshot carries each car's whole track (thinned to ``TRACK_POINTS_SENT``) only when
asked without ``since``; the page then asks ``/api/fleet?since=G&epoch=E`` with the
``generation`` and ``epoch`` of its last answer, and gets only the track points written since
(``track_start``: the car's index of the first; the one before may be replaced, as the newest
position is until the car has moved ``TRACK_STEP_M``). So a poll of 1,000 cars after an hour is
about a megabyte (their states), not 23 MB of tracks. A stale ``epoch`` (another monitor
process) or a ``since`` from the future gets the whole tracks again, and so does a car with
more than ``TRACK_POINTS_SENT`` new points (``since=0``): no answer carries more than that
per car. Under the lock the folding thread needs, only those bounded copies are taken; the
answer is built after it is released.

Security: it binds to loopback unless ``allow_remote`` is given; on loopback it also answers
only requests whose ``Host`` is a loopback name (a web page elsewhere cannot reach it through
DNS rebinding). Text from the cars is inserted by the page as text, never as HTML, and the
page's Content-Security-Policy allows scripts and styles from itself only, images from itself
and the configured tile server.

Robustness (docs/reliability.md): a request must arrive whole within ``REQUEST_TIMEOUT_S`` (each
read waits at most that long, and a watchdog closes a connection whose request is still not in
after ``REQUEST_DEADLINE_S``, however slowly it trickles); at most ``MAX_CONNECTIONS`` are
served at once, the next ones get a 503 and are closed; a client that disconnects early or
times out is counted, never a traceback; a ``Host`` or path that does not parse is a 400.
``[v6]:PORT`` binds IPv6. The thread that folds the telemetry survives anything one event
does: the error is counted (``fold_errors``) and it goes on with the next. Every counter is in
``/api/fleet`` under ``server``, with the client's ``bad_keys`` (samples under a key no car
publishes, dropped).
"""

from __future__ import annotations

import contextlib
import copy
import ipaddress
import json
import logging
import re
import secrets
import socket
import sys
import threading
import time
from collections.abc import Callable, Mapping
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from guidance.errors import UserError
from guidance.telemetry.client import MonitorClient
from guidance.tools.monitor_view import (
    CarView,
    FleetView,
    bad_summary,
    dropped,
    dropped_text,
    gone_summary,
    health_problems,
)

log = logging.getLogger(__name__)

DEFAULT_BIND = "127.0.0.1:8765"
TRACK_POINTS_SENT = 1500
"""At most this many points of each car's track go to the page (evenly thinned)."""
POLL_MS = 250
"""How often the page asks for the fleet: a car's state on the page is then at most this much
older than in the monitor (with 500 ms, 1,000 cars' p99 was 1.4 s old in the answers and 1.75
s on the page; an answer of 1,000 cars costs the server about 40 ms: 16 % of a core at 4 Hz)."""
REQUEST_TIMEOUT_S = 5.0
"""A connection on which nothing arrives (or nothing can be sent) for this long is closed."""
REQUEST_DEADLINE_S = 10.0
"""A request still not read whole after this long is closed, however slowly it trickles."""
MAX_CONNECTIONS = 32
"""Connections served at once (the page holds one or two); beyond: 503 and closed."""
COUNTERS = ("timeouts", "client_disconnects", "connections_refused", "bad_requests", "errors",
            "fold_errors")  # fmt: skip
_ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/static/app.js": ("app.js", "text/javascript; charset=utf-8"),
    "/static/style.css": ("style.css", "text/css; charset=utf-8"),
}


def parse_bind(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT`` too) or ``PORT``; port 0 picks a free one."""
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        raise UserError(f"--web {text!r}: expected HOST:PORT, e.g. {DEFAULT_BIND}") from None
    if not 0 <= port <= 65535:
        raise UserError(f"--web {text!r}: port must be 0-65535")
    return host, port


_HOST_HEADER = re.compile(
    r"(?:\[(?P<v6>[0-9A-Fa-f:.]{2,45})\]|(?P<name>[A-Za-z0-9_.-]{1,253}))(?::[0-9]{1,5})?"
)


def host_name(header: str) -> str:
    """The host of a ``Host`` header (``name``, ``a.b.c.d``, ``[v6]``, each with an optional
    ``:port``), lower-cased; ``ValueError`` for anything else (``[::1``, ``[::1]x``)."""
    m = _HOST_HEADER.fullmatch(header.strip())
    if m is None:
        raise ValueError("malformed Host header")
    if m["v6"] is not None:
        return str(ipaddress.IPv6Address(m["v6"]))  # ValueError when not an address
    return m["name"].lower()


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_tiles(url: str) -> str:
    """A tile URL template: http(s), with ``{z}``, ``{x}`` and ``{y}``."""
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise UserError(f"--tiles {url!r}: expected an http(s) URL template")
    if not all(k in url for k in ("{z}", "{x}", "{y}")):
        raise UserError(f"--tiles {url!r}: the template needs {{z}}, {{x}} and {{y}}")
    return url


def check_web_args(bind: str, *, allow_remote: bool, tiles: str) -> tuple[str, int]:
    """Validate ``--web``, ``--allow-remote`` and ``--tiles`` before anything opens."""
    host, port = parse_bind(bind)
    if not is_loopback(host) and not allow_remote:
        raise UserError(
            f"--web {bind}: serving the fleet's positions beyond this machine needs "
            "--allow-remote (and zenoh access control: config/zenoh/, docs/telemetry.md)"
        )
    if tiles:
        check_tiles(tiles)
    return host, port


def fleet_query(path: str) -> tuple[int | None, str]:
    """``since`` and ``epoch`` of ``/api/fleet?since=G&epoch=E``; anything else in the query is
    ignored, and a ``since`` that is not a small whole number is no ``since``."""
    try:
        query = parse_qs(urlsplit(path).query, max_num_fields=8)
    except ValueError:  # more fields than that: not the page's
        return None, ""
    since_text = (query.get("since") or [""])[0]
    epoch = (query.get("epoch") or [""])[0][:32]
    digits = since_text.isascii() and since_text.isdigit() and len(since_text) <= 15
    return (int(since_text) if digits else None), epoch


def track_part(car: CarView, since: int | None) -> tuple[int | None, list[tuple[float, float]]]:
    """``track_start`` and the points the page gets for one car: its whole track thinned to
    ``TRACK_POINTS_SENT`` when ``since`` is None, else the points written after the fleet's
    generation ``since`` from index ``track_start``; when those are more than
    ``TRACK_POINTS_SENT`` (``since=0``, a page back after an hour), the whole track thinned
    instead (``track_start`` None: the page replaces its copy). So an answer is bounded, and
    so is what the fold lock is held for (``WebMonitor.fleet``)."""
    if since is not None:
        part = car.track_since(since, TRACK_POINTS_SENT)
        if part is not None:
            return part
    track = list(car.track)
    if len(track) > TRACK_POINTS_SENT:
        step = len(track) / TRACK_POINTS_SENT
        track = [track[int(i * step)] for i in range(TRACK_POINTS_SENT - 1)] + [track[-1]]
    return None, track


def car_json(
    car: CarView,
    now_s: float,
    since: int | None = None,
    part: tuple[int | None, list[tuple[float, float]]] | None = None,
) -> dict[str, Any]:
    """What the page gets for one car, with its ``track_part`` (``part``, when taken
    already)."""
    start, track = track_part(car, since) if part is None else part
    age = None if car.last_received_s is None else max(0.0, now_s - car.last_received_s)
    health = car.health
    total, reasons = dropped(health)
    return {
        "vehicle_id": car.vehicle_id,
        "alive": car.alive,
        "gone_s_ago": None if car.gone_s is None else max(0.0, now_s - car.gone_s),
        "gone": "" if car.alive else gone_summary(car, now_s),
        "age_s": age,
        "state": car.state,
        "track": [[round(x, 2), round(y, 2)] for x, y in track],
        "track_start": start,
        "track_total": car.track_total,
        "prompt": car.prompt,
        "health": {
            "ok": None if health is None else bool(health.get("ok")),
            "summary": health_problems(health),
            "dropped": total,
            "dropped_by_reason": reasons,
            "dropped_text": dropped_text(health),
        },
        "messages": car.messages,
        "bad_messages": car.bad_messages,
        "bad": bad_summary(car),
        "gaps": car.gaps,
        "alarm": car.alarm,
    }


class WebMonitor:
    """The fleet view fed by a ``MonitorClient`` and served over HTTP."""

    def __init__(
        self,
        client: MonitorClient,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        allow_remote: bool = False,
        tiles: str = "",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        check_web_args(f"[{host}]:{port}", allow_remote=allow_remote, tiles=tiles)
        self.client = client
        self.tiles = check_tiles(tiles) if tiles else ""
        self.view = FleetView()
        self.epoch = secrets.token_hex(8)
        """This process's name for its generations (a page's ``since`` is of one process)."""
        self.lock = threading.Lock()
        self._clock = clock
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.loopback_only = is_loopback(host)
        self.counters = dict.fromkeys(COUNTERS, 0)
        self._counters_lock = threading.Lock()
        self.httpd = _Server((host, port), self)

    @property
    def url(self) -> str:
        addr = self.httpd.server_address
        host = addr[0].decode() if isinstance(addr[0], bytes) else str(addr[0])
        port = addr[1]
        shown = f"[{host}]" if ":" in host else host
        return f"http://{shown}:{port}/"

    def start(self) -> WebMonitor:
        self.client.query_latest()
        for name, target in (
            ("web-events", self._events),
            ("web-http", self.httpd.serve_forever),
            ("web-watchdog", self._watchdog),
        ):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def close(self) -> None:
        self._stop.set()
        self.httpd.shutdown()
        self.httpd.server_close()
        for t in self._threads:
            t.join(5.0)

    def __enter__(self) -> WebMonitor:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def count(self, name: str) -> int:
        with self._counters_lock:
            self.counters[name] += 1
            return self.counters[name]

    def _events(self) -> None:
        """Fold events until closed; whatever one event does, the next is folded (counted)."""
        while not self._stop.is_set():
            try:
                self._fold_next()
            except Exception as exc:
                n = self.count("fold_errors")
                if n <= 10 or n % 100 == 0:
                    log.error("web: an event could not be folded (%s); %d so far",
                              type(exc).__name__, n)  # fmt: skip
                self._stop.wait(0.05)

    def _fold_next(self) -> None:
        event = self.client.get(0.25)
        if event is None:
            return
        with self.lock:
            new_car = event.kind == "alive" and event.vehicle_id not in self.view.cars
            self.view.apply(event)
        if new_car:
            self.client.query_latest(event.vehicle_id)

    def _watchdog(self) -> None:
        """Close the connections whose request is not in after ``REQUEST_DEADLINE_S``."""
        while not self._stop.wait(0.5):
            for sock in self.httpd.overdue(time.monotonic()):
                self.count("timeouts")
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)  # the handler's read ends at once

    def fleet(self, since: int | None = None, epoch: str = "") -> dict[str, Any]:
        """The page's snapshot; with the ``since`` and ``epoch`` of an earlier one, only the
        track points written after it (the module says why)."""
        now = self._clock()
        with self.lock:  # only copies, bounded per car: the answer is built after
            generation = self.view.generation
            if since is not None and (epoch != self.epoch or not 0 <= since <= generation):
                since = None  # another process's, or from the future: the whole tracks
            cars = {**self.view.gone, **self.view.cars}
            taken = [(copy.copy(cars[vid]), track_part(cars[vid], since)) for vid in sorted(cars)]
            messages, bad = self.view.messages, self.view.bad_messages
        out = [car_json(car, now, part=part) for car, part in taken]
        with self._counters_lock:
            server = dict(self.counters)
        return {
            "schema": "guidance.fleet/1",
            "epoch": self.epoch,
            "generation": generation,
            "cars": out,
            "messages": messages,
            "bad_messages": bad,
            "bad_keys": self.client.bad_keys,
            "server": server,
        }

    def page_config(self) -> dict[str, Any]:
        from guidance.version import version

        return {"tiles": self.tiles, "version": version(), "poll_ms": POLL_MS}

    def host_allowed(self, host_header: str | None) -> bool:
        """Whether a request with this ``Host`` is answered; ``ValueError`` when it does not
        parse (``[::1``): a 400."""
        host = host_name(host_header) if host_header else ""
        if not self.loopback_only:
            return True
        return is_loopback(host)

    def csp(self) -> str:
        img = "'self' data:"
        if self.tiles:
            parts = urlsplit(self.tiles.replace("{", "").replace("}", ""))
            img += f" {parts.scheme}://{parts.netloc}"
        return (
            f"default-src 'none'; script-src 'self'; style-src 'self'; img-src {img}; "
            "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
        )


class _Server(ThreadingHTTPServer):
    """A ``ThreadingHTTPServer`` with a bound on connections, a deadline per request, IPv6,
    and a count instead of a traceback for each client that goes away."""

    daemon_threads = True
    request_queue_size = 64

    def __init__(self, address: tuple[str, int], monitor: WebMonitor) -> None:
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.monitor = monitor
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self._reading: dict[socket.socket, float] = {}
        self._reading_lock = threading.Lock()
        super().__init__(address, _Handler)

    def process_request(self, request: Any, client_address: Any) -> None:
        if not self._slots.acquire(blocking=False):
            self.monitor.count("connections_refused")
            with contextlib.suppress(OSError):
                request.settimeout(0.5)
                request.sendall(
                    b"HTTP/1.0 503 Service Unavailable\r\nContent-Type: text/plain\r\n"
                    b"Content-Length: 5\r\nConnection: close\r\n\r\nbusy\n"
                )
            self.shutdown_request(request)
            return
        self.reading(request, True)
        try:
            super().process_request(request, client_address)
        except BaseException:
            self.reading(request, False)
            self._slots.release()
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.reading(request, False)
            self._slots.release()

    def reading(self, request: socket.socket, waiting: bool) -> None:
        """Mark a connection as waiting for its request (or no longer)."""
        with self._reading_lock:
            if waiting:
                self._reading[request] = time.monotonic() + REQUEST_DEADLINE_S
            else:
                self._reading.pop(request, None)

    def overdue(self, now: float) -> list[socket.socket]:
        with self._reading_lock:
            late = [s for s, deadline in self._reading.items() if deadline <= now]
            for s in late:
                del self._reading[s]
        return late

    def handle_error(self, request: Any, client_address: Any) -> None:
        exc = sys.exc_info()[1]
        if isinstance(exc, ConnectionError | TimeoutError):  # gone early, reset, timed out
            self.monitor.count("client_disconnects")
            log.debug("web: client %s went away: %s", client_address, exc)
            return
        n = self.monitor.count("errors")
        if n <= 10 or n % 100 == 0:
            log.error("web: a request failed (%s: %s); %d so far", type(exc).__name__, exc, n)


class _Handler(BaseHTTPRequestHandler):
    server_version = "guidance-monitor"
    sys_version = ""

    def setup(self) -> None:
        self.timeout = REQUEST_TIMEOUT_S  # type: ignore[misc]  # each read and write
        super().setup()

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("web: " + format, *args)

    def log_error(self, format: str, *args: Any) -> None:
        if any(isinstance(a, TimeoutError) for a in args):
            self.server.monitor.count("timeouts")  # type: ignore[attr-defined]
        self.log_message(format, *args)

    def _send(self, status: int, body: bytes, ctype: str, extra: Mapping[str, str] = {}) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        for k, v in extra.items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, value: Any) -> None:
        body = json.dumps(value, separators=(",", ":"), allow_nan=False).encode()
        self._send(HTTPStatus.OK, body, "application/json")

    def do_HEAD(self) -> None:
        self.do_GET()

    def do_GET(self) -> None:
        mon: WebMonitor = self.server.monitor  # type: ignore[attr-defined]
        self.server.reading(self.connection, False)  # type: ignore[attr-defined]
        try:
            allowed = mon.host_allowed(self.headers.get("Host"))
            path = urlsplit(self.path).path
        except ValueError:  # e.g. "Host: [::1" or a path "//[x"
            mon.count("bad_requests")
            self._send(HTTPStatus.BAD_REQUEST, b"bad request\n", "text/plain")
            return
        if not allowed:
            self._send(HTTPStatus.MISDIRECTED_REQUEST, b"wrong host\n", "text/plain")
            return
        if path == "/api/fleet":
            self._json(mon.fleet(*fleet_query(self.path)))
        elif path == "/api/config":
            self._json(mon.page_config())
        elif path in _ASSETS:
            name, ctype = _ASSETS[path]
            body = resources.files("guidance.tools.web").joinpath("static", name).read_bytes()
            self._send(HTTPStatus.OK, body, ctype, {"Content-Security-Policy": mon.csp()})
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain")


def serve(
    client: MonitorClient,
    bind: str,
    *,
    allow_remote: bool = False,
    tiles: str = "",
    timeout_s: float | None = None,
    announce: Callable[[str], None] = print,
) -> int:
    """Run the web monitor until Ctrl-C or ``timeout_s``; exit code 0."""
    host, port = check_web_args(bind, allow_remote=allow_remote, tiles=tiles)
    try:
        web = WebMonitor(client, host, port, allow_remote=allow_remote, tiles=tiles)
    except OSError as exc:
        raise UserError(f"--web {bind}: cannot listen: {exc.strerror or exc}") from None
    with web:
        announce(f"guidance monitor: web map at {web.url} (Ctrl-C to stop)")
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            while deadline is None or time.monotonic() < deadline:
                time.sleep(0.2 if deadline is None else min(0.2, deadline - time.monotonic()))
        except KeyboardInterrupt:
            pass
    return 0
