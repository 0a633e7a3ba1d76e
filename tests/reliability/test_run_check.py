"""``guidance run --check`` refuses what would make the car start wrong (issue 14, item 13): an
unknown CAN interface, a missing zenoh config file, a recording folder that cannot be created,
a ``[[landmarks]]`` entry without a position (before: silently at the start) and an
``[odometry]`` table without ``profile`` (before: silently the GM reference car). Each is one
``error:`` line and exit 2; a good config passes. Real TOML files through the real command.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from guidance.tools.cli import main

CAR = """
[vehicle]
id = "chk1"

[start]
x_m = 0.0
y_m = 0.0
heading_deg = 90.0

[goal]
x_m = 400.0
y_m = 0.0

[odometry]
backend = "can"
interface = "{interface}"
channel = "check"
{profile}

[compass]
enabled = false

[estimator]
compass_two_sigma_deg = false

[telemetry]
enabled = {telemetry}
{zenoh}

[recording]
directory = "{recording}"
{landmarks}
"""


def _config(tmp_path: Path, **kw: str) -> Path:
    values = {
        "interface": "virtual",
        "profile": 'profile = "toyota"',
        "telemetry": "false",
        "zenoh": "",
        "recording": str(tmp_path / "rec"),
        "landmarks": "",
    }
    values.update(kw)
    path = tmp_path / "car.toml"
    path.write_text(CAR.format(**values))
    return path


def _check(capsys: pytest.CaptureFixture[str], path: Path, *extra: str) -> tuple[int, str]:
    rc = main(["run", "--config", str(path), *extra])
    err = capsys.readouterr().err
    assert "internal error" not in err and "Traceback" not in err, err
    return rc, err


def test_a_good_config_passes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _check(capsys, _config(tmp_path), "--check")[0] == 0


def _blocker(tmp_path: Path) -> str:
    (tmp_path / "afile").write_text("not a folder")
    return str(tmp_path / "afile" / "rec")


CASES = {
    "unknown CAN interface": (
        {"interface": "nope"},
        "interface 'nope' is not a python-can interface",
    ),
    "missing zenoh config": (
        {"telemetry": "true", "zenoh": 'zenoh_config = "missing.json5"'},
        "zenoh_config",
    ),
    "uncreatable recording folder": ({"recording": "BLOCKER"}, "is not a folder"),
    "landmark without a position": (
        {"landmarks": '[[landmarks]]\nid = 1\nname = "church"'},
        "[landmarks.0] needs a position",
    ),
    "landmark with x only": (
        {"landmarks": "[[landmarks]]\nid = 1\nx_m = 20.0"},
        "[landmarks.0] needs a position",
    ),
    "missing profile": ({"profile": ""}, "[odometry] profile is missing"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_check_rejects_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    changes, text = CASES[name]
    changes = {k: (_blocker(tmp_path) if v == "BLOCKER" else v) for k, v in changes.items()}
    rc, err = _check(capsys, _config(tmp_path, **changes), "--check")
    assert rc == 2, err
    assert len(err.strip().splitlines()) == 1 and "error:" in err and text in err, err


def test_an_unknown_can_interface_stops_the_start_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without --check too: one line before anything opens (before: "internal error:
    ExceptionGroup" from the reader's task group)."""
    rc, err = _check(capsys, _config(tmp_path, interface="nope"))
    assert rc == 2 and "interface 'nope'" in err


def test_check_warns_for_a_compass_port_and_a_can_interface_that_do_not_exist(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 24: --check said OK for both; now each is a warning with the usual fix (the
    drivers keep retrying, an adapter may be plugged in later), and the check still passes."""
    path = _config(tmp_path, interface="socketcan")
    text = (
        path.read_text()
        .replace(
            "[compass]\nenabled = false",
            '[compass]\nport = "/dev/ttyNOSUCH9"\ndeclination_deg = 0.0',
        )
        .replace('channel = "check"', 'channel = "nosuchcan7"')
    )
    path.write_text(text.replace("compass_two_sigma_deg = false", "compass_two_sigma_deg = 20.0"))
    rc, err = _check(capsys, path, "--check")
    assert rc == 0, err
    assert "warning: [compass] port /dev/ttyNOSUCH9 does not exist" in err, err
    assert "warning: [odometry]" in err and "nosuchcan7" in err, err
    # either no SocketCAN here (a container) or no such interface: each names its fix
    assert "modprobe can can_raw" in err or "sudo ip link set nosuchcan7 up type can" in err


def test_serial_and_socketcan_problems_name_their_fixes(tmp_path: Path) -> None:
    from guidance.app.checks import serial_problem, socketcan_problem

    port = tmp_path / "ttyFAKE"
    port.write_text("")
    port.chmod(0o000)
    import os

    if os.geteuid() != 0:  # root opens anything
        assert "usermod -aG dialout" in serial_problem(str(port))
    port.chmod(0o600)
    assert serial_problem(str(port)) == ""
    net = tmp_path / "net"
    (net / "can0").mkdir(parents=True)
    (net / "can0" / "operstate").write_text("down\n")
    (net / "can0" / "flags").write_text("0x80\n")
    why = socketcan_problem("can0", net)
    no_socketcan = "modprobe can can_raw" in why  # this machine (a container) has none
    assert no_socketcan or why.endswith("is down: sudo ip link set can0 up type can bitrate 500000")
    (net / "can0" / "operstate").write_text("up\n")
    (net / "can0" / "flags").write_text("0x41\n")
    assert socketcan_problem("can0", net) == ("" if not no_socketcan else why)
    assert no_socketcan or "does not exist" in socketcan_problem("can9", net)


def test_the_can_driver_names_the_fix_for_errno_97_19_and_100() -> None:
    from drivers.can_odometry import can_hint

    assert "modprobe can can_raw" in can_hint("socketcan", "can0", OSError(97, "x"))
    assert "no network interface can0" in can_hint("socketcan", "can0", OSError(19, "x"))
    assert "can0 is down: sudo ip link set can0 up" in can_hint(
        "socketcan", "can0", OSError(100, "x")
    )
    assert can_hint("virtual", "can0", OSError(97, "x")) == ""
