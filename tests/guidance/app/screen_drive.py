"""A short drive of ``guidance run`` on simulated devices, for the operator-screen tests.

``python tests/guidance/app/screen_drive.py DIR [--screen auto] [--input evdev|keyboard]`` writes
``DIR/car.toml`` (CAN on a python-can virtual bus fed by ``SimCanWheels`` in this process, the
compass on a pty written by ``SimCompassPty``, the co-driver keypad at ``DIR/keypad``: a FIFO
of raw input_event records the test writes; with ``--input keyboard`` the terminal itself;
``--input none``: no co-driver input)
and runs ``run_car`` with stdout as it is (a tmux pane: the live view) until ``DIR/stop``
appears. ``drive_config`` is also used in-process by the tests.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def drive_config(directory: Path, *, channel: str, compass_port: str, scene: str) -> Path:
    """A car config for the simulated devices; ``scene`` is the [scene] table's body."""
    cfg = directory / "car.toml"
    cfg.write_text(
        f"""
[vehicle]
id = "screen1"
[start]
x_m = 0.0
y_m = 0.0
heading_deg = 90.0
[goal]
x_m = 0.0
y_m = 3000.0
[navigation]
method = "straight_to_goal"
[odometry]
interface = "virtual"
channel = "{channel}"
profile = "gm_global_a"
expected_rate_hz = 50.0
[compass]
port = "{compass_port}"
declination_deg = 0.0
expected_rate_hz = 10.0
[scene]
{scene}
[voice]
backend = "text"
[telemetry]
enabled = false
[recording]
enabled = false
"""
    )
    return cfg


async def _drive(directory: Path, screen: str, co_driver: str) -> int:
    from guidance.app.run import run_car
    from hal_sim.sim_can import SimCanWheels
    from hal_sim.sim_compass import SimCompassPty

    channel = f"screen-{os.getpid()}"
    with SimCompassPty(rate_hz=10.0) as pty, SimCanWheels(channel, period_s=0.02) as wheels:
        pty.set_heading(90.0)
        wheels.set_speeds(8.0, 8.0)
        cfg = drive_config(
            directory,
            channel=channel,
            compass_port=pty.port,
            scene={
                "evdev": f'input = "evdev"\ndevice = "{directory / "keypad"}"',
                "keyboard": 'input = "keyboard"',
                "none": 'input = "none"',
            }[co_driver],
        )
        task = asyncio.create_task(run_car(str(cfg), screen=screen))
        await asyncio.sleep(0.3)
        wheels.start()
        pty.start()
        (directory / "running").touch()
        while not (directory / "stop").exists() and not task.done():  # noqa: ASYNC110
            await asyncio.sleep(0.05)  # the test asks to stop by creating a file
        if not task.done():
            os.kill(os.getpid(), signal.SIGTERM)
        code = await asyncio.wait_for(task, 10.0)
        wheels.stop()
        pty.stop()
    return code


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("directory", type=Path)
    parser.add_argument("--screen", default="auto")
    parser.add_argument("--input", default="evdev", choices=("evdev", "keyboard", "none"))
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    return asyncio.run(_drive(args.directory, args.screen, args.input))


if __name__ == "__main__":
    sys.exit(main())
