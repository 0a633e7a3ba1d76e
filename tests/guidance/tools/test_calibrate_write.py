"""``guidance calibrate --write`` on hostile TOML layouts (issue 23, item 2): the result always
parses, loads through the car's loader and holds the new card, every comment survives; what
cannot be written safely is refused with one line and the file is left as it was."""

from __future__ import annotations

import io
import os
import re
import stat
import tomllib
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest
from test_calibrate import _circles_drive

from guidance.app.config import load_config
from guidance.tools.calibrate import write_card
from guidance.tools.cli import main

CARD = [12.5, -3.25, 0.5, 1.0, -0.75]

HEAD = """# keep-head: the car's own file
[vehicle]  # keep-vehicle
id = "cal"
track_m = 1.62

[start]
x_m = 0.0
y_m = 0.0
heading_deg = 30.0

[odometry]
backend = "can"  # keep-odometry
interface = "virtual"
channel = "replay"
profile = "toyota"
"""

BODY = """backend = "nmea_serial"  # keep-backend
port = "/dev/null"
declination_deg = 5.0
"""

CARD_LAST = HEAD + "\n[compass]\n" + BODY

LAYOUTS: dict[str, str] = {
    "plain, card last": HEAD + "\n[compass]\n" + BODY,
    "card over several lines with comments": HEAD
    + "\n[compass]\n"
    + BODY
    + "deviation_deg = [  # keep-open\n  1.0,  # keep-a\n  2.0,\n  3.0, 4.0,\n  5.0,  # keep-e\n]"
    + "  # keep-close\n",
    "card over several lines, compass first": "[compass]  # keep-c\n"
    + BODY
    + "deviation_deg = [\n    0.0,\n    0.0,\n    0.0,\n    0.0,\n    0.0\n]\n# keep-after\n"
    + HEAD,
    "empty list over several lines": HEAD + "[compass]\n" + BODY + "deviation_deg = [\n]\n",
    "spaced header": HEAD + "\n[ compass ]  # keep-spaced\n" + BODY,
    "tabbed header": HEAD + "\n[\tcompass\t]\n" + BODY,
    "quoted header": HEAD + '\n["compass"]  # keep-quoted\n' + BODY,
    "literal-quoted header": HEAD + "\n['compass']\n" + BODY + "deviation_deg = [1, 2, 3, 4, 5]\n",
    "indented table": HEAD + "\n  [compass]\n" + "".join(f"    {ln}\n" for ln in BODY.splitlines()),
    "inline table": 'compass = { backend = "nmea_serial", port = "/dev/null", declination_deg'
    " = 5.0 }  # keep-inline\n" + HEAD,
    "inline table with a card": 'compass = { backend = "nmea_serial", port = "/dev/null",'
    " declination_deg = 5.0, deviation_deg = [0, 0, 0, 0, 0] }  # keep-inline\n" + HEAD,
    "dotted keys": 'compass.backend = "nmea_serial"  # keep-dotted\ncompass.port = "/dev/null"\n'
    "compass.declination_deg = 5.0\n" + HEAD,
    "dotted keys with a card": 'compass.backend = "nmea_serial"\ncompass.port = "/dev/null"\n'
    "compass.declination_deg = 5.0\ncompass.deviation_deg = [1, 2, 3, 4, 5]  # keep-old-card\n"
    + HEAD,
    "quoted dotted card": 'compass.backend = "nmea_serial"\ncompass.port = "/dev/null"\n'
    'compass.declination_deg = 5.0\n"compass"."deviation_deg" = [1, 2, 3, 4, 5]\n' + HEAD,
    "quoted key": HEAD + "[compass]\n" + BODY + '"deviation_deg" = [9, 9, 9, 9, 9]  # keep-q\n',
    "no spaces, trailing comment": CARD_LAST + "deviation_deg=[1,2,3,4,5]#keep-t\n",
    "a wrong-length card": HEAD + "[compass]\n" + BODY + "deviation_deg = [1, 2, 3]\n",
    "a card of text": HEAD + "[compass]\n" + BODY + 'deviation_deg = "none yet"  # keep-text\n',
    "compass in the middle": HEAD.split("[odometry]")[0]
    + "[compass]\n"
    + BODY
    + "\n[odometry]"
    + HEAD.split("[odometry]")[1],
    "a commented-out header before": HEAD + "# [compass]  keep-ghost\n# deviation_deg = [0]\n"
    "\n[compass]\n" + BODY,
    "CRLF line ends": (HEAD + "\n[compass]\n" + BODY).replace("\n", "\r\n"),
    "CRLF, card over lines": (
        HEAD + "[compass]\n" + BODY + "deviation_deg = [\n 1,\n 2,\n 3,\n 4,\n 5,\n]  # keep-crlf\n"
    ).replace("\n", "\r\n"),
    "no newline at the end": HEAD + "\n[compass]\n" + BODY.rstrip("\n"),
    "card without newline at the end": CARD_LAST + "deviation_deg = [0,0,0,0,0]",
    "unicode comments": HEAD + "\n[compass]  # keep-ünïcödé ✓\n" + BODY,
    "multi-line string with a fake header": HEAD.replace(
        'profile = "toyota"', 'profile = """toyota"""'
    )
    + "\n[compass]\n"
    + BODY,
}


def _comments(text: str) -> list[str]:
    return re.findall(r"keep-[^\s\],#]+", text)


def _check(car: Path, before: str) -> None:
    text = car.read_text(encoding="utf-8")
    assert tomllib.loads(text)["compass"]["deviation_deg"] == CARD
    cfg = load_config(car, require_goal=False)  # the car's own loader
    assert cfg.pipeline.compass_deviation_deg == tuple(CARD)
    assert sorted(_comments(text)) == sorted(_comments(before))
    old, new = tomllib.loads(before), tomllib.loads(text)
    old.get("compass", {}).pop("deviation_deg", None)
    new["compass"].pop("deviation_deg")
    assert old == new  # nothing else changed


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_every_layout_gets_the_card_and_keeps_its_comments(tmp_path: Path, name: str) -> None:
    car = tmp_path / "car.toml"
    before = LAYOUTS[name]
    car.write_bytes(before.encode("utf-8"))
    assert write_card(car, CARD) == car.resolve()
    _check(car, before)
    if "CRLF" in name:
        assert b"\r\n" in car.read_bytes() and b"\n" not in car.read_bytes().replace(b"\r\n", b"")
    write_card(car, CARD)  # again: the same file, one card
    lines = car.read_text().splitlines()
    assert sum("deviation_deg" in ln.split("#")[0] for ln in lines) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["car.toml"]


REFUSED = {
    "an array of tables": HEAD + "[[compass]]\n" + BODY,
    "compass a number": "compass = 5\n" + HEAD,
    "not TOML": HEAD + "[compass\n" + BODY,
    "twice the table": HEAD + "[compass]\n" + BODY + "[compass]\nport = 'x'\n",
    "the loader refuses it": HEAD + "[compass]\n" + BODY + "colour = 'red'\n",
}


@pytest.mark.parametrize("name", list(REFUSED))
def test_what_cannot_be_edited_is_one_line_and_the_file_stays(tmp_path: Path, name: str) -> None:
    car = tmp_path / "car.toml"
    car.write_text(REFUSED[name])
    with pytest.raises(Exception) as info:
        write_card(car, CARD)
    assert type(info.value).__name__ == "UserError"
    msg = str(info.value)
    assert "\n" not in msg and "unchanged" in msg and str(car) in msg
    assert car.read_text() == REFUSED[name]
    assert [p.name for p in tmp_path.iterdir()] == ["car.toml"]


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return _circles_drive(tmp_path_factory.mktemp("drive"))


def _run(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(list(args))
    return code, out.getvalue(), err.getvalue()


def _calibrate(drive: tuple[Path, Path], car: Path) -> tuple[int, str, str]:
    log, nmea = drive
    return _run("calibrate", str(log), "--nmea", str(nmea), "--config", str(car), "--write")


@pytest.mark.parametrize(
    "name", ["card over several lines with comments", "inline table", "dotted keys",
             "spaced header", "quoted header"],
)  # fmt: skip
def test_the_cli_writes_hostile_layouts_the_car_then_loads(
    drive: tuple[Path, Path], tmp_path: Path, name: str
) -> None:
    car = tmp_path / "car.toml"
    car.write_text(LAYOUTS[name])
    code, out, err = _calibrate(drive, car)
    assert code == 0, err
    assert "written to" in out
    card = tomllib.loads(car.read_text())["compass"]["deviation_deg"]
    assert abs(card[0] - 20.0) < 1.5  # the drive's true card (tests/.../test_calibrate.py)
    assert load_config(car, require_goal=False).pipeline.compass_deviation_deg == tuple(card)
    assert set(_comments(LAYOUTS[name])) <= set(_comments(car.read_text()))


def test_a_symlinked_config_is_written_through_the_link(
    drive: tuple[Path, Path], tmp_path: Path
) -> None:
    real = tmp_path / "etc" / "car.toml"
    real.parent.mkdir()
    real.write_text(LAYOUTS["plain, card last"])
    real.chmod(0o640)
    link = tmp_path / "car.toml"
    link.symlink_to(real)
    code, out, err = _calibrate(drive, link)
    assert code == 0, err
    assert link.is_symlink() and os.readlink(link) == str(real)  # the link stays a link
    assert "deviation_deg" in tomllib.loads(real.read_text())["compass"]  # the target has it
    assert stat.S_IMODE(real.stat().st_mode) == 0o640
    assert str(real) in out
    assert sorted(p.name for p in real.parent.iterdir()) == ["car.toml"]


def test_a_read_only_config_is_refused_with_one_line(
    drive: tuple[Path, Path], tmp_path: Path
) -> None:
    car = tmp_path / "car.toml"
    car.write_text(LAYOUTS["plain, card last"])
    car.chmod(0o444)
    code, out, err = _calibrate(drive, car)
    assert code == 2 and "written to" not in out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "read-only (mode 0444)" in lines[0] and "Traceback" not in err
    assert car.read_text() == LAYOUTS["plain, card last"]
    assert stat.S_IMODE(car.stat().st_mode) == 0o444


def test_a_symlink_loop_is_refused_with_one_line(tmp_path: Path) -> None:
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(Exception, match="cannot write the card") as info:
        write_card(a, CARD)
    assert type(info.value).__name__ == "UserError" and "\n" not in str(info.value)
