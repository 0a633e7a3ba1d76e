"""``[scene]``: which co-driver input ``guidance run`` reads (docs/app.md, "Configuration")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from guidance.app.config import SceneSettings, parse_config
from guidance.errors import UserError


def _doc(scene: dict[str, Any] | None) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "start": {"x_m": 0.0, "y_m": 0.0, "heading_deg": 0.0},
        "goal": {"x_m": 1500, "y_m": -200},
        "compass": {"declination_deg": 0.0, "port": "/dev/ttyACM0"},
        "telemetry": {"enabled": False},
        "recording": {"enabled": False},
    }
    if scene is not None:
        doc["scene"] = scene
    return doc


@pytest.mark.parametrize(
    ("scene", "expected"),
    [
        (None, SceneSettings("keyboard", "", True)),
        ({"keyboard": True}, SceneSettings("keyboard")),
        ({"keyboard": False}, SceneSettings("none")),  # the old spelling
        ({"input": "none"}, SceneSettings("none")),
        (
            {"input": "evdev", "device": "/dev/input/by-id/usb-kp-event-kbd", "grab": False},
            SceneSettings("evdev", "/dev/input/by-id/usb-kp-event-kbd", False),
        ),
    ],
)
def test_scene_inputs(scene: dict[str, Any] | None, expected: SceneSettings) -> None:
    assert parse_config(_doc(scene)).scene == expected


def test_a_relative_device_is_relative_to_the_config_file(tmp_path: Path) -> None:
    cfg = parse_config(_doc({"input": "evdev", "device": "keypad.fifo"}), base_dir=tmp_path)
    assert cfg.scene.device == str(tmp_path / "keypad.fifo")


@pytest.mark.parametrize(
    ("scene", "message"),
    [
        ({"input": "evdev"}, r"\[scene\] device is required with input = 'evdev'"),
        ({"device": "/dev/input/event3"}, r"\[scene\] device is only read with input = 'evdev'"),
        ({"input": "keypad"}, r"\[scene\] input must be one of keyboard, evdev, speech, none"),
        ({"input": "none", "keyboard": False}, r"\[scene\] give input or keyboard"),
        ({"input": "evdev", "device": "/x", "grap": True}, r"\[scene\] unknown key\(s\): grap"),
    ],
)
def test_bad_scene_tables_name_the_key(scene: dict[str, Any], message: str) -> None:
    with pytest.raises(UserError, match=message):
        parse_config(_doc(scene))
