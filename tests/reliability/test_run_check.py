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
