"""``guidance monitor --json`` with cars published by another program and a late reader of its
stdout (issue 41, the stall; ``/work/shared/repro/monitor_stall.py`` does the same).

Several cars, each its own zenoh client session of a router (not the project's Telemetry),
publishing ``guidance.state/1`` at 10 Hz, each in a way another program might: zenoh's
defaults, an attachment and an encoding, express with real-time priority and blocking
congestion control, no liveliness token, a clock of its own (unix time, sequence numbers from
1,000), puts on the session without a declared publisher. The test reads the monitor's stdout
only when the cars have stopped, as ``subprocess.communicate`` does: the monitor's output is
then far more than a pipe holds. Every state of every car must come out, in order.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import zenoh

REPO = Path(__file__).resolve().parents[3]
RATE_HZ = 10.0
SECONDS = 5.0
KINDS = ("defaults", "attachment", "express", "no-token", "own-clock", "session-put")
"""One car of each kind; 6 cars x 50 states x ~0.5 kB = 150 kB, over twice a 64 KiB pipe."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _conf(mode: str, endpoint: str) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("transport/shared_memory/enabled", "false")
    where = "listen/endpoints" if mode == "router" else "connect/endpoints"
    c.insert_json5(where, json.dumps([endpoint]))
    return c


def _state(vid: str, seq: int, t_s: float, i: int) -> dict[str, Any]:
    """A real state's fields, as the repro writes them."""
    return {
        "schema": "guidance.state/1", "vehicle_id": vid, "seq": seq, "t_s": t_s,
        "wall_time_unix_s": time.time(), "x_m": 10.0 * i + seq, "y_m": 5.0,
        "lat_deg": 42.45, "lon_deg": -76.5, "origin": {"lat_deg": 42.444, "lon_deg": -76.5019},
        "heading_rad": 0.1, "heading_deg": 84.3, "heading_deg_true": 5.7,
        "covariance": [[1, 0, 0], [0, 1, 0], [0, 0, 0.01]],
        "ellipse": {"semi_major_m": 2.0, "semi_minor_m": 2.0, "orientation_rad": 0.0,
                    "major_axis_m": 4.0},
        "speed_mps": 10.0, "target": None,
    }  # fmt: skip


class _Car:
    def __init__(self, i: int, kind: str, endpoint: str) -> None:
        self.vid, self.kind, self.i = f"car{i:03d}", kind, i
        self.session = zenoh.open(_conf("client", endpoint))
        key = f"guidance/{self.vid}/state"
        self.token = (
            None if kind == "no-token" else self.session.liveliness().declare_token(
                f"guidance/{self.vid}"
            )
        )  # fmt: skip
        if kind == "express":
            self.pub = self.session.declare_publisher(
                key, express=True, priority=zenoh.Priority.REAL_TIME,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.BEST_EFFORT,
            )  # fmt: skip
        elif kind == "attachment":
            self.pub = self.session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON)
        else:
            self.pub = self.session.declare_publisher(key)  # also tells when the monitor listens
        self.sent: list[int] = []
        self.sent_bytes = 0

    def publish(self, n: int) -> None:
        seq, t_s = n, n / RATE_HZ
        if self.kind == "own-clock":
            seq, t_s = 1000 + n, 1.7e9 + n / RATE_HZ
        payload = json.dumps(_state(self.vid, seq, t_s, self.i))
        if self.kind == "attachment":
            self.pub.put(payload, attachment=bytes(33))
        elif self.kind == "session-put":
            self.session.put(f"guidance/{self.vid}/state", payload)
        else:
            self.pub.put(payload)
        self.sent.append(seq)
        self.sent_bytes += len(payload) + 1

    def close(self) -> None:
        self.session.close()


def test_external_cars_and_a_late_reader_lose_no_state() -> None:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = zenoh.open(_conf("router", endpoint))
    cars: list[_Car] = []
    mon: subprocess.Popen[str] | None = None
    try:
        cars = [_Car(i, kind, endpoint) for i, kind in enumerate(KINDS)]
        rounds = int(SECONDS * RATE_HZ)
        mon = subprocess.Popen(
            [sys.executable, "-m", "guidance.tools.cli", "monitor", "--connect", endpoint,
             "--json", "--count", str(rounds * len(cars)), "--timeout", "30"],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        deadline = time.monotonic() + 30.0
        while not all(c.pub.matching_status.matching for c in cars):
            assert time.monotonic() < deadline and mon.poll() is None, "monitor did not start"
            time.sleep(0.05)
        time.sleep(0.5)  # its other subscribers are declared with the states'
        t0 = time.monotonic()
        for n in range(rounds):
            time.sleep(max(0.0, t0 + n / RATE_HZ - time.monotonic()))
            for car in cars:
                car.publish(n)
        out, err = mon.communicate(timeout=60)  # the first read of its stdout
    finally:
        if mon is not None and mon.poll() is None:
            mon.kill()
            mon.wait()
        for car in cars:
            car.close()
        router.close()
    assert sum(c.sent_bytes for c in cars) > 2 * 65536, "more than twice what a pipe holds"
    printed: dict[str, list[int]] = {}
    for line in out.splitlines():
        msg = json.loads(line)
        if msg.get("schema") == "guidance.state/1":
            printed.setdefault(msg["vehicle_id"], []).append(msg["seq"])
    for car in cars:
        assert printed.get(car.vid) == car.sent, (
            f"{car.vid} ({car.kind}): {len(printed.get(car.vid, []))} of {len(car.sent)} "
            f"states printed; stderr: {err[-500:]}"
        )
    assert mon.returncode == 0, err
