"""The shipped unit can read the co-driver's keypad: stdin is /dev/null under systemd, so the
keys come from an input device the service may open (group and device access)."""

from __future__ import annotations

from pathlib import Path

from test_systemd_units import UNITS_DIR, parse_unit

README = UNITS_DIR / "README.md"


def test_unit_gives_the_service_the_input_devices() -> None:
    u = parse_unit(UNITS_DIR / "guidance.service")
    assert u[("Service", "StandardInput")] == ["null"]  # what the app warns about
    assert "input" in u[("Service", "SupplementaryGroups")][0].split()
    assert "char-input r" in u[("Service", "DeviceAllow")]
    assert u[("Service", "DevicePolicy")] == ["closed"]  # so the line above is needed


def test_readme_configures_the_keypad_and_the_user_group() -> None:
    text = Path(README).read_text()
    assert 'input = "evdev"' in text and "/dev/input/by-id/" in text
    assert "--groups audio,dialout,video,input guidance" in text
