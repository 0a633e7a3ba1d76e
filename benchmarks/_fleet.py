"""What the fleet benchmarks share: a router, a fleet of cars, a reference subscriber (each a
child process running one of the scripts below), the monitor as a child, and reading it.

The cars (``FLEET``), by kind: ``raw``, a client session, a publisher (``CongestionControl.DROP``,
express) and a liveliness token per car publishing the output table's state message;
``telemetry``, the car's own ``Telemetry``; ``plain``, another program's car as the stall's
repro (/work/shared/repro/monitor_stall.py) makes it: zenoh's default config and publisher, a
dict dumped with ``json``'s defaults at each put. Every car stamps ``t_s`` with
CLOCK_MONOTONIC, the clock the benchmarks read the monitor's output with.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

ROUTER = r"""
import sys, time, zenoh
from guidance.telemetry.session import open_session, session_config
mesh = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else []  # linked routers
conf = session_config(mode="router", listen=[sys.argv[1]], connect=mesh)
conf.insert_json5("transport/unicast/max_sessions", "10000")
conf.insert_json5("transport/unicast/accept_pending", "2000")
s = open_session(conf)
print("up", flush=True)
sys.stdin.readline()
s.close()
"""

FLEET = r"""
import json, sys, threading, time, zenoh
from guidance.core.messages import Ellipse, EstimateState, Target
from guidance.outputs.messages import encode, state_message
from guidance.telemetry.keys import key_for, liveliness_key
from guidance.telemetry.session import open_session, session_config
from guidance.outputs.kinds import STATE, OutputContext
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
router, rate, first, n = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
real, plain, per_session = sys.argv[5] == "telemetry", sys.argv[5] == "plain", int(sys.argv[6])
EXPRESS = (sys.argv[7] if len(sys.argv) > 7 else "express") == "express"
ids = [f"car{i:04d}" for i in range(first, first + n)]
cars = []
for vid in ids:
    if real:  # the car's own publisher: thread, slots, queryable, every kind's publisher
        tel = Telemetry(TelemetryConfig(vehicle_id=vid, mode="client",
                                        connect=tuple(router.split(","))))
        tel.start()
        cars.append((vid, tel, None, None))
        continue
    if plain:  # another program's car (the stall's repro): zenoh's defaults, its own session
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([router]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        s = zenoh.open(conf)
        cars.append((vid, s, s.declare_publisher(key_for(vid, "state")),
                     s.liveliness().declare_token(liveliness_key(vid))))
        continue
    for attempt in range(20 if len(cars) % per_session == 0 else 0):
        try:  # a busy router may refuse while it accepts hundreds
            s = open_session(session_config(mode="client", connect=router.split(",")))
            break
        except Exception:
            time.sleep(0.2 + 0.1 * attempt)
    else:
        if len(cars) % per_session == 0:
            raise SystemExit(f"{vid}: cannot reach the router")
    pub = s.declare_publisher(key_for(vid, "state"),
                              congestion_control=zenoh.CongestionControl.DROP, express=EXPRESS)
    tok = s.liveliness().declare_token(liveliness_key(vid))
    cars.append((vid, s, pub, tok))
while real and not all(c[1].health().valid for c in cars):
    time.sleep(0.05)
print("up", flush=True)
sys.stdin.readline()  # go
cov = ((4.0, 0.1, 0.0), (0.1, 2.0, 0.0), (0.0, 0.0, 0.01))
ell = Ellipse(4.1, 2.8, 0.3, 8.2)
period = 1.0 / rate
stop = threading.Event()
threading.Thread(target=lambda: (sys.stdin.readline(), stop.set()), daemon=True).start()
seq, late, starts, templates = 0, 0, [], []
next_t = time.monotonic()
while not stop.is_set():
    next_t += period
    pause = next_t - time.monotonic()
    if pause > 0:
        time.sleep(pause)
    else:
        late += 1
    seq += 1
    starts.append(time.monotonic())
    for i, (vid, s, pub, tok) in enumerate(cars):
        t = time.monotonic()
        st = EstimateState(t, 10.0 * i + 0.1 * seq, 5.0, 0.5, cov, ell, False, True)
        if real:
            s.send(STATE, st, OutputContext(speed_mps=8.0,
                                            target=Target(300.0, 100.0, "goal", None)))
            continue
        if plain:  # a dict dumped with json's defaults each time, as the repro does
            pub.put(json.dumps({
                "schema": "guidance.state/1", "vehicle_id": vid, "seq": seq, "t_s": t,
                "wall_time_unix_s": time.time(), "x_m": 10.0 * i + 0.1 * seq, "y_m": 5.0,
                "lat_deg": 42.45, "lon_deg": -76.5,
                "origin": {"lat_deg": 42.444, "lon_deg": -76.5019}, "heading_rad": 0.1,
                "heading_deg": 84.3, "heading_deg_true": 5.7,
                "covariance": [[1, 0, 0], [0, 1, 0], [0, 0, 0.01]],
                "ellipse": {"semi_major_m": 2.0, "semi_minor_m": 2.0, "orientation_rad": 0.0,
                            "major_axis_m": 4.0},
                "speed_mps": 10.0, "target": None}))
            continue
        if i >= len(templates):  # the real message once, then only t_s, seq and x_m change
            msg = encode(state_message(EstimateState(-7.5e9, -8.5e9, 5.0, 0.5, cov, ell, False,
                                                     True), vehicle_id=vid, seq=999999937,
                                       speed_mps=8.0, target=Target(300.0, 100.0, "goal", None)))
            templates.append(msg.replace(b"%", b"%%").replace(b'"seq":999999937', b'"seq":%d')
                             .replace(b'"t_s":-7500000000.0', b'"t_s":%r')
                             .replace(b'"x_m":-8500000000.0', b'"x_m":%r'))
        pub.put(templates[i] % (seq, t, 10.0 * i + 0.1 * seq))
print(json.dumps({"rounds": seq, "late_rounds": late, "first": first, "n": n,
                  "starts": starts}), flush=True)
for session in {id(c[1]): c[1] for c in cars}.values():
    session.close()
"""


REFERENCE = r"""
import json, sys, zenoh
from guidance.telemetry.session import open_session, session_config
s = open_session(session_config(mode="peer", connect=[sys.argv[1]]))
sub = s.declare_subscriber("guidance/*/state", zenoh.handlers.FifoChannel(1 << 21))
print("up", flush=True)
t0, t1 = map(float, sys.stdin.readline().split())  # the window, when it is over
n = 0
while (x := sub.handler.try_recv()) is not None:
    b = x.payload.to_bytes()
    cut = b.find(b',"wall_time_unix_s"')  # the car's compact JSON: only its envelope parsed
    m = json.loads(b[:cut] + b"}" if cut > 0 else b)
    n += t0 <= m["t_s"] <= t1
print(n, flush=True)
s.close()
"""
"""What the router delivered: a subscriber with a big FIFO and no Python on its receiving path,
read only once the window is over (the monitor's losses are those beyond this one's)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spawn(code: str, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )


@dataclass
class Seen:
    """What one monitor printed: per car, (arrival, t_s, seq) of each state line."""

    chunks: list[tuple[float, bytes]] = field(default_factory=list)
    states: dict[str, list[tuple[float, float, int]]] = field(default_factory=dict)
    responses: int = 0
    """Web feed: the /api/fleet responses read."""
    feed_ages: list[tuple[float, float]] = field(default_factory=list)
    """Web feed: (arrival, age of a car's state in that response), every car of every one."""

    def showed_a_state(self) -> bool:
        return bool(self.states) or any(b'"schema":"guidance.state/' in c for _, c in self.chunks)

    def parse(self) -> None:
        """Each state line's envelope (the first fields, not the whole line), stamped with
        the arrival of the chunk that completed it."""
        rest = b""
        for now, chunk in self.chunks:
            lines = (rest + chunk).split(b"\n")
            rest = lines.pop()
            for line in lines:
                if not line.startswith(b'{"schema":"guidance.state/'):
                    continue
                msg = json.loads(line[: line.index(b',"wall_time_unix_s"')] + b"}")
                self.states.setdefault(msg["vehicle_id"], []).append((now, msg["t_s"], msg["seq"]))


def read_output(proc: subprocess.Popen[bytes], seen: Seen) -> None:
    """Takes the monitor's output as fast as it comes (big reads, parsed afterwards), so
    this script is never what the monitor waits for."""
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    while chunk := os.read(fd, 1 << 20):
        seen.chunks.append((time.monotonic(), chunk))


def monitor_proc(
    router: str, duration: float, pythonpath: str | None, web_port: int | None = None
) -> subprocess.Popen[bytes]:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    main = ["-c", "import sys; from guidance.tools.cli import main; sys.exit(main())"]
    if "MONITOR_PROFILE" in env:  # a cProfile of the monitor, for finding where it spends
        main = ["-m", "cProfile", "-o", env["MONITOR_PROFILE"], str(ROOT / "benchmarks/_cli.py")]
    return subprocess.Popen(
        [
            sys.executable,
            *main,
            "monitor",
            "--connect",
            router,
            *(["--json"] if web_port is None else ["--web", f"127.0.0.1:{web_port}"]),
            "--timeout",
            f"{duration:g}",
        ],
        cwd=pythonpath or ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env=env,
    )


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a running process so far (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
