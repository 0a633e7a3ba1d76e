"""The operator screen of ``guidance run`` on the simulated devices (``[sim] devices = true``).

The car's own screen (``guidance.app.operator_session.OperatorSession``: the banner, the rows,
the co-driver's keys and their acknowledgements) on a simulated drive: ``SimScreen`` builds it
for a ``SimDrive`` with the drive's clock, adds the configured co-driver input (the terminal
keyboard by default) beside the simulated co-driver, and gives the banner the simulated
devices' real names (the virtual CAN channel, the compass pty, the simulated camera) instead
of the config's placeholders.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from guidance.app.operator_session import OperatorSession
from guidance.app.run import co_driver_problem
from guidance.app.screen import banner_rows

if TYPE_CHECKING:
    from guidance.app.app import App, Source
    from guidance.app.ports import Speaker
    from guidance.core.pipeline import Pipeline
    from hal_sim.drive_options import DriveOptions
    from hal_sim.sim_run import SimDevices


class SimScreen:
    """The operator screen of one simulated drive: ``screen`` is the ``--screen`` mode (not
    "off"), ``cfg`` the car's ``AppConfig``, ``clock`` the simulated clock."""

    def __init__(
        self, cfg: Any, pipeline: Pipeline, screen: str, clock: Callable[[], float]
    ) -> None:
        self.cfg = cfg
        self.session = OperatorSession(cfg, pipeline, screen=screen, clock=clock)
        self.pipeline = pipeline
        self.no_input = co_driver_problem(cfg.scene, sys.stdin)
        self.co_driver: Source | None = None

    def sources(self) -> dict[str, Source]:
        """The co-driver input the config names (its keys answered on the screen), when it can
        work now; the simulated co-driver reports the intersections either way."""
        if not self.no_input:
            self.co_driver = self.session.co_driver_input(
                lambda: self.pipeline.estimate.heading_rad
            )
        self.session.operator.co_driver = _CoDrivers(self.co_driver)  # the INPUT row
        return {"co_driver": self.co_driver} if self.co_driver is not None else {}

    def speaker(self, speaker: Speaker | None) -> Speaker | None:
        """The speaker the app is given (on the loop): the co-driver may mute it."""
        return self.session.attach(speaker)

    def listen(self, app: App) -> None:
        """The operator's rows follow the app's inputs and outputs."""
        app.listeners.append(self.session.operator)

    def start(self, dev: SimDevices, opts: DriveOptions, voice: str) -> None:
        self.session.start(self.banner(dev, opts, voice))

    def stop(self) -> None:
        self.session.stop()

    def banner(self, dev: SimDevices, opts: DriveOptions, voice: str) -> list[tuple[str, str]]:
        """The car's banner with the simulated devices as they really are."""
        scene = self.cfg.scene
        typed = {"evdev": f"keypad {scene.device}", "keyboard": "keyboard (stdin)",
                 "speech": f"microphone {scene.microphone}"}.get(scene.input, "none")  # fmt: skip
        if self.no_input:
            typed = f"no keys ({self.no_input.split(';')[0]})"
        co_driver = f"simulated co-driver (reports each intersection) + {typed}"
        devices = {
            "odometry": f"simulated CAN frames, python-can virtual bus {dev.wheels.channel}",
            "compass": (
                f"simulated NMEA on {dev.pty.port}" if dev.pty is not None else "off (simulated)"
            ),
            "camera": (
                f"simulated camera, {opts.camera_hz:g} frames per simulated second"
                if opts.camera_hz is not None
                else "off: the world's landmark sightings"
            ),
        }
        if not opts.telemetry:  # the drive's [sim] table turns the outputs off
            devices["telemetry"] = "off ([sim] telemetry = false)"
        if not opts.record:
            devices["recording"] = "off"
        voice = f"{self.cfg.voice.backend} ({voice})"
        rows = [
            (label, devices.get(label, value))
            for label, value in banner_rows(self.cfg, voice=voice, co_driver=co_driver)
        ]
        pace = "as fast as it goes" if opts.speed is None else f"{opts.speed:g} x real time"
        rows.insert(2, ("drive", f"simulated city, seed {opts.seed}, {pace}; Ctrl-C ends it"))
        return rows


class _CoDrivers:
    """What the screen's INPUT row says of the co-driver: the simulated one, and the keys."""

    def __init__(self, typed: Source | None) -> None:
        self.typed = typed

    def describe(self) -> str:
        if self.typed is None:
            return "simulated (reports each intersection); no keys"
        describe = getattr(self.typed, "describe", None)
        keys = describe() if callable(describe) else str(getattr(self.typed, "name", "keys"))
        return f"simulated (reports each intersection) + {keys}"

    @property
    def connected(self) -> bool:
        return bool(getattr(self.typed, "connected", True))
