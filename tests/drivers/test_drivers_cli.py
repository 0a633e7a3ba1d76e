"""``guidance odometry`` and ``guidance compass`` through guidance.tools.cli.main."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from guidance.tools.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"
RAV4 = DATA / "can" / "rav4_2020-02-03_bus0_wheelspeeds.log"


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_odometry_json(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(["odometry", str(RAV4), "--profile", "toyota", "--json"], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert {"frames", "decoded", "rejected", "duration_s", "distance_m"} <= set(data)
    assert isinstance(data["rejected"], int) and isinstance(data["rejected_by_reason"], dict)
    assert data["rejected"] == sum(data["rejected_by_reason"].values())
    assert data["frames"] == 3753 and data["decoded"] == 3573
    assert data["distance_m"] == pytest.approx(803.30, abs=0.01)
    assert data["duration_s"] == pytest.approx(115.27, abs=0.01)


def test_odometry_text(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(["odometry", str(RAV4), "--profile", "toyota"], capsys)
    assert code == 0
    assert "3753 read" in out and "803.30 m" in out and "rejected:    0" in out


def test_odometry_max_gap_option(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["odometry", str(RAV4), "--profile", "toyota", "--max-gap", "0.5", "--json"]
    code, out, _ = run(argv, capsys)
    data = json.loads(out)
    assert code == 0 and data["rejected_by_reason"]["gap"] == 10


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["odometry", "GARBAGE", "--profile", "toyota"], "no CAN frames could be read"),
        (["odometry", "MISSING", "--profile", "toyota"], "no such file"),
        (["odometry", "RAV4", "--profile", "tesla"], "unknown vehicle profile 'tesla'"),
        (["odometry", "RAV4", "--profile", "toyota", "--max-gap", "-1"], "--max-gap"),
        (["compass", "MISSING"], "not found"),
    ],
)
def test_user_errors_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    garbage = tmp_path / "garbage.log"
    garbage.write_bytes(bytes(range(256)) * 50)
    paths = {"GARBAGE": str(garbage), "MISSING": str(tmp_path / "none.log"), "RAV4": str(RAV4)}
    code, out, err = run([paths.get(a, a) for a in argv], capsys)
    assert code == 2
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert out == ""


def test_compass_json(capsys: pytest.CaptureFixture[str]) -> None:
    path = DATA / "nmea" / "bundg_zeus_9_head.log"
    code, out, err = run(["compass", str(path), "--json"], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert {"lines", "headings", "rejected", "rejected_by_reason", "stats"} <= set(data)
    assert (data["lines"], data["headings"], data["rejected"]) == (392, 115, 277)
    assert data["stats"]["mean_deg"] == pytest.approx(231.737, abs=0.001)


def test_compass_text(capsys: pytest.CaptureFixture[str]) -> None:
    path = DATA / "nmea" / "saab-r4.log"
    code, out, _ = run(["compass", str(path)], capsys)
    assert code == 0
    assert "12 accepted (0 magnetic, 12 true)" in out and "unknown_type 110" in out


def test_compass_garbage_ends_with_a_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "noise.bin"
    path.write_bytes(bytes(range(256)) * 64)
    code, out, err = run(["compass", str(path), "--json"], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert data["headings"] == 0 and data["lines"] == data["rejected"] > 0
    assert data["stats"] is None
