"""sd_notify from the app, checked on a real unix datagram socket standing in for systemd."""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from guidance.app.watchdog import SystemdNotifier, watchdog_interval_s


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def notify_socket(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[socket.socket]:
    """A bound AF_UNIX datagram socket, named by NOTIFY_SOCKET, with a 2 s watchdog."""
    path = tmp_path / "notify.sock"
    if len(str(path)) >= 100:  # sun_path is 108 bytes
        pytest.skip(f"tmp path too long for a unix socket: {path}")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(1.0)
    monkeypatch.setenv("NOTIFY_SOCKET", str(path))
    monkeypatch.setenv("WATCHDOG_USEC", "2000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    yield sock
    sock.close()


def received(sock: socket.socket) -> list[str]:
    """Every datagram waiting on the socket."""
    out = []
    sock.setblocking(False)
    try:
        while True:
            out.append(sock.recv(4096).decode())
    except BlockingIOError:
        pass
    finally:
        sock.settimeout(1.0)
    return out


def test_ready_status_and_stopping_reach_the_socket(notify_socket: socket.socket) -> None:
    n = SystemdNotifier()
    assert n.enabled and n.watchdog_enabled and n.interval_s == 2.0
    n.ready("opening devices")
    n.status("driving: 3 prompts")
    n.status("driving:  3 prompts")  # unchanged: not sent again
    n.status("héading 90°")  # ASCII on the wire
    n.stopping()
    assert received(notify_socket) == [
        "READY=1\nSTATUS=opening devices",
        "STATUS=driving: 3 prompts",
        "STATUS=h?ading 90?",
        "STOPPING=1",
    ]


def test_watchdog_pings_at_half_the_period_only_while_the_loop_is_on_time(
    notify_socket: socket.socket, caplog: pytest.LogCaptureFixture
) -> None:
    clock = FakeClock()
    n = SystemdNotifier(max_lag_s=0.5, clock=clock)
    sent = []
    with caplog.at_level(logging.INFO):
        for step in range(60):  # 6 s of a 10 Hz loop; late from 2.0 s to 3.9 s
            clock.now = step * 0.1
            lag = 1.5 if 20 <= step < 40 else 0.002
            if n.tick(lag):
                sent.append(round(clock.now, 1))
    assert sent == [0.0, 1.0, 4.0, 5.0]  # none while late; at once when on time again
    assert received(notify_socket) == ["WATCHDOG=1"] * 4
    messages = [r.getMessage() for r in caplog.records if r.name == "guidance.app.watchdog"]
    assert len(messages) == 2
    assert "withholding watchdog pings" in messages[0]
    assert "resumed" in messages[1]


def test_everything_is_a_no_op_outside_systemd(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    n = SystemdNotifier()
    assert not n.enabled and not n.watchdog_enabled
    n.ready("x")
    n.status("y")
    assert n.tick(0.0) is False


def test_watchdog_for_another_process_or_unset_is_ignored(notify_socket: socket.socket) -> None:
    assert watchdog_interval_s({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": "1"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "nonsense"}) is None
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "5000000"}) == 5.0
    os.environ.pop("WATCHDOG_USEC")
    n = SystemdNotifier()
    assert n.enabled and not n.watchdog_enabled
    assert n.tick(0.0) is False
    n.ready()
    assert received(notify_socket) == ["READY=1"]


def test_lost_socket_is_logged_once_and_never_raised(
    notify_socket: socket.socket, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    clock = FakeClock()
    n = SystemdNotifier(clock=clock)
    notify_socket.close()
    (tmp_path / "notify.sock").unlink()
    with caplog.at_level(logging.INFO):
        for step in range(5):
            clock.now = 2.0 * step
            assert n.tick(0.0) is False
        n.status("still going")
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "sd_notify failed" in warnings[0].getMessage()


def test_unreachable_notify_socket_disables_notifications(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "nobody-listens.sock"))
    n = SystemdNotifier()
    assert not n.enabled
    assert n.tick(0.0) is False
    [warning] = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert "cannot reach systemd" in warning


def test_a_full_notify_queue_never_blocks_the_caller(
    notify_socket: socket.socket, caplog: pytest.LogCaptureFixture
) -> None:
    """A receiver that stops reading fills the datagram queue; sends then fail at once."""
    import time

    clock = FakeClock()
    n = SystemdNotifier(clock=clock)
    took = []
    with caplog.at_level(logging.WARNING, logger="guidance.app.watchdog"):
        for i in range(200):  # far more than a unix datagram queue holds (10 by default)
            clock.now = float(i)
            t0 = time.perf_counter()
            n.tick(0.0)
            n.status(f"driving {i}")
            took.append(time.perf_counter() - t0)
    assert max(took) < 0.5  # a blocking send would wait here forever
    assert n.dropped > 300
    assert sum("sd_notify failed" in r.getMessage() for r in caplog.records) == 1
    assert len(received(notify_socket)) < 100
    clock.now = 1000.0
    assert n.tick(0.0) is True  # the queue was drained above: pings go through again
