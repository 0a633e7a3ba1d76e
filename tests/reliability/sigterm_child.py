"""A ``guidance run`` process on simulated devices, for the SIGTERM stop test (issue 23, 8).

``python sigterm_child.py DIR PORT``: wheel-speed frames on a python-can virtual bus (which
lives in one process, so the simulated wheels run in this one) and NMEA headings on a
pseudo-terminal, then the ``guidance`` program itself (``guidance.tools.cli.entry``: the
console script) with a car TOML in DIR using them: compass, CAN odometry, text voice, Zenoh
telemetry on loopback PORT, an MCAP recording and checkpoints. The test sends SIGTERM once
``READY=1`` reached ``NOTIFY_SOCKET`` and checks the exit code.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from hal_sim.sim_can import SimCanWheels
from hal_sim.sim_compass import SimCompassPty

CAR_TOML = """
[vehicle]
id = "stop1"
[start]
x_m = 0.0
y_m = 0.0
heading_deg = 90.0
[goal]
x_m = 5000.0
y_m = 0.0
[odometry]
interface = "virtual"
channel = "{channel}"
expected_rate_hz = 50.0
[compass]
port = "{port}"
declination_deg = 0.0
expected_rate_hz = 10.0
[scene]
keyboard = false
[voice]
backend = "text"
[checkpoint]
path = "{dir}/ck.json"
interval_s = 0.5
[telemetry]
listen = ["tcp/127.0.0.1:{zenoh_port}"]
[recording]
directory = "{dir}/rec"
"""


def main() -> None:
    folder, zenoh_port = sys.argv[1], int(sys.argv[2])
    channel = f"sigterm-{os.getpid()}"
    pty = SimCompassPty(rate_hz=10.0)
    pty.set_heading(90.0)
    wheels = SimCanWheels(channel, period_s=0.02).open()
    wheels.set_speeds(10.0, 10.0)
    cfg = Path(folder) / "car.toml"
    cfg.write_text(CAR_TOML.format(channel=channel, port=pty.port, dir=folder,
                                   zenoh_port=zenoh_port))  # fmt: skip
    wheels.start()
    pty.start()
    from guidance.tools.cli import entry

    sys.argv = ["guidance", "run", "--config", str(cfg), "--screen", "plain"]
    entry()  # the program's own exit: never returns


if __name__ == "__main__":
    main()
