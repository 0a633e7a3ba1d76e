"""The example zenoh passwords of config/zenoh/, used unchanged, are warned about at start
(issue 40, a low): by the car and the monitor when they build their session config, and by
``guidance run --check``. The login itself on loopback is tests/guidance/telemetry/
test_telemetry.py::test_usrpwd_access_control_only_the_operator_sets_a_goal."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import pytest

from guidance.telemetry import example_passwords
from guidance.telemetry.example_passwords import (
    EXAMPLE_PASSWORDS,
    example_password_problem,
    warn_example_passwords,
)
from guidance.telemetry.session import session_config
from guidance.tools.cli import main

REPO = Path(__file__).resolve().parents[3]
ZENOH = REPO / "config" / "zenoh"
TAHOE = REPO / "config" / "tahoe.toml"


def _copy(name: str, folder: Path, swap: dict[str, str] | None = None) -> Path:
    """An example file with its /etc placeholder pointing into ``folder`` (and any swaps)."""
    text = (ZENOH / name).read_text().replace("/etc/guidance/zenoh/", f"{folder}/")
    for old, new in (swap or {}).items():
        text = text.replace(old, new)
    out = folder / name
    out.write_text(text)
    return out


def test_the_constant_is_the_passwords_config_zenoh_ships() -> None:
    """The warning knows every password the examples hold, and only those."""
    shipped = {
        line.partition(":")[2] for line in (ZENOH / "passwords.example.txt").read_text().split()
    }
    for path in ZENOH.glob("*.json5"):
        shipped |= set(re.findall(r'password:\s*"([^"]*)"', path.read_text()))
    assert shipped == EXAMPLE_PASSWORDS


def test_the_example_passwords_are_named_by_user_and_changed_ones_are_not(
    tmp_path: Path,
) -> None:
    _copy("passwords.example.txt", tmp_path).rename(tmp_path / "passwords.txt")
    car = _copy("car-usrpwd-acl.json5", tmp_path)
    monitor = _copy("monitor-usrpwd.json5", tmp_path)
    line = example_password_problem(str(car))
    assert line is not None and "'operator', 'viewer' still have the example password" in line
    line = example_password_problem(str(monitor))
    assert line is not None and "'viewer' still has the example password" in line
    for text in (line, example_password_problem(str(car)) or ""):  # never the password itself
        assert not any(p in text for p in EXAMPLE_PASSWORDS)

    (tmp_path / "passwords.txt").write_text("operator:k4#9-own\nviewer:change-me-viewer\n")
    assert "'viewer' still has" in (example_password_problem(str(car)) or "")
    (tmp_path / "passwords.txt").write_text("operator:k4#9-own\nviewer:also-own\n")
    own = _copy("monitor-usrpwd.json5", tmp_path, {"change-me-viewer": "also-own"})
    for path in (car, own, ZENOH / "car-tls.json5", ZENOH / "car-mtls-acl.json5"):
        assert example_password_problem(str(path)) is None, path
    assert example_password_problem("") is None
    (tmp_path / "passwords.txt").unlink()  # zenoh says it is missing when it opens the session
    assert example_password_problem(str(car)) is None


def test_the_car_and_the_monitor_warn_once_when_they_build_the_session(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(example_passwords, "_warned", set())
    monitor = str(_copy("monitor-usrpwd.json5", tmp_path))
    with caplog.at_level(logging.WARNING, logger=example_passwords.__name__):
        for _ in range(3):  # a session reopened after a network loss: warned once
            session_config(mode="client", connect=("tcp/127.0.0.1:9",), zenoh_config=monitor)
        warn_example_passwords(monitor)
    lines = [r.getMessage() for r in caplog.records if r.name == example_passwords.__name__]
    assert len(lines) == 1 and "'viewer' still has the example password" in lines[0]


def test_guidance_run_check_warns_of_the_example_passwords(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _copy("passwords.example.txt", tmp_path).rename(tmp_path / "passwords.txt")
    car = _copy("car-usrpwd-acl.json5", tmp_path)
    config = tmp_path / "car.toml"
    text = TAHOE.read_text().replace("[telemetry]", f'[telemetry]\nzenoh_config = "{car}"', 1)
    config.write_text(text)
    assert main(["run", "--config", str(config), "--check"]) == 0
    err = capsys.readouterr().err
    assert "warning: zenoh config" in err and "'operator', 'viewer' still have" in err
