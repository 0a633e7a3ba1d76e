"""Issue 23, item 5: the ``guidance monitor --web`` server under hostile clients, with real
sockets: a half-sent or trickled request is closed within seconds, connections are bounded
(the extra ones get a 503), a client that disconnects early is counted (no traceback), a
``Host`` that does not parse gets a 400, and ``[::1]:PORT`` binds IPv6.

The fleet comes from an unopened ``MonitorClient`` (no Zenoh needed: the server is the subject);
the timeouts are shortened for speed, the code paths are those of the defaults."""

from __future__ import annotations

import contextlib
import http.client
import socket
import struct
import threading
import time
from collections.abc import Iterator

import pytest

from guidance.telemetry.client import MonitorClient
from guidance.tools.web import server
from guidance.tools.web.server import WebMonitor


@pytest.fixture
def web(monkeypatch: pytest.MonkeyPatch) -> Iterator[WebMonitor]:
    monkeypatch.setattr(server, "REQUEST_TIMEOUT_S", 1.0, raising=False)
    monkeypatch.setattr(server, "REQUEST_DEADLINE_S", 2.5, raising=False)
    monkeypatch.setattr(server, "MAX_CONNECTIONS", 8, raising=False)
    with WebMonitor(MonitorClient(["tcp/127.0.0.1:9"]), "127.0.0.1", 0) as w:
        yield w


def port_of(web: WebMonitor) -> int:
    return int(web.httpd.server_address[1])


def closed_within(sock: socket.socket, seconds: float) -> float | None:
    """Seconds until the server closed ``sock`` (reads until EOF), None if still open."""
    t0 = time.monotonic()
    sock.settimeout(0.2)
    while time.monotonic() - t0 < seconds:
        try:
            if sock.recv(4096) == b"":
                return time.monotonic() - t0
        except TimeoutError:
            continue
        except ConnectionError:
            return time.monotonic() - t0
    return None


def test_a_half_sent_request_is_closed_after_the_timeout(web: WebMonitor) -> None:
    with socket.create_connection(("127.0.0.1", port_of(web))) as s:
        s.sendall(b"GET /api/fleet HTTP/1.1\r\nHost: 127.0.0.1")  # never finished
        took = closed_within(s, 30.0)
    # closed at its 1 s read timeout; the bound leaves a loaded machine its delays
    assert took is not None and took < 15.0, took
    assert web.counters["timeouts"] >= 1


def test_a_trickled_request_is_closed_at_its_deadline(web: WebMonitor) -> None:
    """One byte every 0.5 s never trips the per-read timeout: the deadline closes it."""
    with socket.create_connection(("127.0.0.1", port_of(web))) as s:
        t0 = time.monotonic()
        closed = False
        for byte in b"GET /api/fleet HTTP/1.1\r\nX-Slow: " + b"a" * 100:
            try:
                s.sendall(bytes([byte]))
            except OSError:
                closed = True
                break
            s.settimeout(0.5)
            try:
                if s.recv(1) == b"":
                    closed = True
                    break
            except TimeoutError:
                pass
            except ConnectionError:
                closed = True
                break
            if time.monotonic() - t0 > 30.0:  # the whole trickle would take 60 s
                break
        took = time.monotonic() - t0
    assert closed and took < 20.0, took  # the 2.5 s deadline, with a loaded machine's delays
    assert web.counters["timeouts"] >= 1


def test_connections_are_bounded_and_the_server_recovers(
    web: WebMonitor, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(server, "REQUEST_TIMEOUT_S", 5.0, raising=False)  # held throughout
    monkeypatch.setattr(server, "REQUEST_DEADLINE_S", 10.0, raising=False)
    threads_before = threading.active_count()
    socks = [socket.create_connection(("127.0.0.1", port_of(web))) for _ in range(30)]
    try:
        for s in socks:
            s.sendall(b"GET / HTTP/1.1\r\n")  # half-sent: each holds a connection
        time.sleep(0.5)
        busy = 0
        for s in socks:
            s.settimeout(0.05)
            with contextlib.suppress(TimeoutError, ConnectionError):
                busy += s.recv(64).startswith(b"HTTP/1.0 503")
        assert busy == 30 - 8, busy
        assert web.counters["connections_refused"] == 22
        assert threading.active_count() <= threads_before + 8
    finally:
        for s in socks:
            s.close()
    time.sleep(0.5)  # closed by the client: the held ones end and free their slots
    conn = http.client.HTTPConnection("127.0.0.1", port_of(web), timeout=5)
    conn.request("GET", "/api/fleet")
    assert conn.getresponse().status == 200
    conn.close()


def test_clients_that_disconnect_early_are_counted_without_a_traceback(
    web: WebMonitor, capfd: pytest.CaptureFixture[str]
) -> None:
    for _ in range(40):
        s = socket.create_connection(("127.0.0.1", port_of(web)))
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        s.sendall(b"GET /static/app.js HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        s.close()  # a reset: the server's write (or read) fails
    time.sleep(0.5)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Exception occurred" not in err, err[-2000:]
    assert web.counters["client_disconnects"] >= 1 and web.counters["errors"] == 0


@pytest.mark.parametrize("host", ["[::1", "[zz]:1", "[::1]x", "a b", "localhost:x"])
def test_a_host_that_does_not_parse_is_a_400(web: WebMonitor, host: str) -> None:
    conn = http.client.HTTPConnection("127.0.0.1", port_of(web), timeout=5)
    try:
        conn.putrequest("GET", "/api/fleet", skip_host=True)
        conn.putheader("Host", host)
        conn.endheaders()
        r = conn.getresponse()
        assert r.status == 400
    finally:
        conn.close()
    assert web.counters["bad_requests"] == 1 and web.counters["errors"] == 0


def ipv6_loopback() -> bool:
    try:
        with socket.socket(socket.AF_INET6) as s:
            s.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not ipv6_loopback(), reason="no IPv6 loopback on this machine")
def test_an_ipv6_bind_serves_the_page_on_its_v6_address() -> None:
    from guidance.tools.web.server import parse_bind

    host, port = parse_bind("[::1]:0")
    with WebMonitor(MonitorClient(["tcp/127.0.0.1:9"]), host, port) as web:
        assert web.url.startswith("http://[::1]:")
        v6_port = int(web.httpd.server_address[1])
        conn = http.client.HTTPConnection("::1", v6_port, timeout=5)
        conn.request("GET", "/api/fleet")  # Host: [::1]:PORT, a loopback name
        r = conn.getresponse()
        assert r.status == 200 and b"guidance.fleet/1" in r.read()
        conn.close()
