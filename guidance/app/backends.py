"""Device backends by name (python-can's interface table pattern, HOUSE_STYLE).

``BACKENDS`` maps ``[odometry] backend = "can"`` to the driver class and its config dataclass,
imported on first use, so the app imports no driver module: it names them here.
"""

from __future__ import annotations

import importlib
from typing import Any

BACKENDS: dict[str, dict[str, tuple[str, str]]] = {
    "odometry": {
        "can": ("drivers.can_odometry:CanOdometry", "drivers.can_odometry:CanOdometryConfig"),
    },
    "compass": {
        "nmea_serial": ("drivers.compass:SerialCompass", "drivers.compass:SerialCompassConfig"),
    },
    "camera": {
        "opencv": ("drivers.camera:OpenCvCamera", "drivers.camera:CameraConfig"),
    },
}
SCENE_BACKENDS: dict[str, str] = {
    "keyboard": "drivers.keyboard:KeyboardScene",
    "evdev": "drivers.evdev_keys:EvdevKeys",
    "speech": "drivers.speech:SpeechInput",
}
"""Co-driver input backends (``[scene] input``, ``module:Class``), imported on first use."""
SCENE_CONFIGS: dict[str, str] = {
    "evdev": "drivers.evdev_keys:EvdevKeysConfig",
    "speech": "drivers.speech:SpeechInputConfig",
}
"""The driver config dataclass of a co-driver input that takes one (``[scene] device``...)."""


def import_backend(path: str) -> Any:
    """The class named by a ``module:Class`` backend string."""
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)
