"""Real CAN logs through the decoder: the shipped RAV4 excerpt, other formats, damaged files,
and (optional, ``shared_data``) the GPL Civic and Camaro logs kept outside the repository."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import can
import pytest

from drivers.can_odometry import replay_log
from guidance.errors import UserError

RAV4 = Path(__file__).resolve().parents[1] / "data" / "can" / "rav4_2020-02-03_bus0_wheelspeeds.log"
RAV4_DISTANCE_M = 803.30
"""All 3,573 WHEEL_SPEEDS frames of the 115 s drive; the car's own SPEED message (0xB4),
integrated the same way over the full log, gives 801.1 m (docs/drivers.md)."""


def test_rav4_excerpt_decodes_to_the_known_distance() -> None:
    s = replay_log(RAV4, "toyota")
    assert s.frames == 3753
    assert s.decoded == 3573
    assert s.ignored == 180
    assert s.rejected == 0 and s.unreadable == 0
    assert s.increments == 3572
    assert s.duration_s == pytest.approx(115.27, abs=0.01)
    assert s.distance_m == pytest.approx(RAV4_DISTANCE_M, abs=0.01)
    assert s.left_m == pytest.approx(s.right_m, rel=0.005)  # a mostly straight drive
    assert s.max_speed_mps * 3.6 == pytest.approx(47.0, abs=0.1)  # "up to about 47 km/h"


def test_a_stricter_gap_limit_loses_the_logger_dropouts() -> None:
    """The log has ten 0.52-0.69 s dropouts; at 0.5 s they are not bridged (about 50 m)."""
    s = replay_log(RAV4, "toyota", max_gap_s=0.5)
    assert s.rejected_by_reason["gap"] == 10
    assert s.gap_s == pytest.approx(5.72, abs=0.01)
    assert s.distance_m == pytest.approx(753.26, abs=0.01)


def _write(path: Path, writer_cls: type) -> None:
    with writer_cls(str(path)) as writer:
        for msg in can.LogReader(str(RAV4)):
            writer.on_message_received(msg)


@pytest.mark.parametrize(("suffix", "writer"), [(".asc", can.ASCWriter), (".blf", can.BLFWriter)])
def test_other_log_formats_give_the_same_distance(
    tmp_path: Path, suffix: str, writer: type
) -> None:
    path = tmp_path / f"rav4{suffix}"
    _write(path, writer)
    s = replay_log(path, "toyota")
    assert s.decoded == 3573
    assert s.distance_m == pytest.approx(RAV4_DISTANCE_M, abs=0.05)


def test_gzipped_candump(tmp_path: Path) -> None:
    path = tmp_path / "rav4.log.gz"
    with RAV4.open("rb") as src, gzip.open(path, "wb") as dst:
        shutil.copyfileobj(src, dst)
    assert replay_log(path, "toyota").distance_m == pytest.approx(RAV4_DISTANCE_M, abs=0.01)


def test_damaged_candump_lines_cost_only_themselves(tmp_path: Path) -> None:
    lines = RAV4.read_bytes().splitlines(keepends=True)
    junk = [b"\xff\xfe garbage\n", b"(12.5) can0 0AA#ZZ\n", b"(1580765500.12\n"]
    damaged = [*lines[:1000], *junk, *lines[1000:]]
    path = tmp_path / "damaged.log"
    path.write_bytes(b"".join(damaged))
    s = replay_log(path, "toyota")
    assert s.unreadable == 3
    assert s.decoded == 3573
    assert s.distance_m == pytest.approx(RAV4_DISTANCE_M, abs=0.01)


def test_truncated_blf_stops_with_a_reason(tmp_path: Path) -> None:
    full = tmp_path / "full.blf"
    _write(full, can.BLFWriter)
    cut = tmp_path / "cut.blf"
    data = full.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    s = replay_log(cut, "toyota")  # must not raise: python-can reads what is there
    assert 0 < s.frames < 3753
    assert 0.0 < s.distance_m < RAV4_DISTANCE_M
    corrupt = tmp_path / "corrupt.blf"
    corrupt.write_bytes(data[:2000] + b"\0" * 1000 + data[3000:])
    try:
        s = replay_log(corrupt, "toyota")
    except UserError as exc:  # nothing readable: one line naming the zlib error
        assert "decompressing" in str(exc)
    else:
        assert s.read_error is not None


def test_arbitrary_bytes_are_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "noise.log"
    path.write_bytes(bytes(range(256)) * 40)
    with pytest.raises(UserError, match="no CAN frames could be read"):
        replay_log(path, "toyota")


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".trc", ".csv"])
def test_arbitrary_bytes_in_other_formats_never_traceback(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"noise{suffix}"
    path.write_bytes(bytes(range(256)) * 40)
    try:
        s = replay_log(path, "toyota")
    except UserError as exc:
        assert str(path) in str(exc)
    else:
        assert s.decoded == 0


def test_missing_file_unknown_suffix_and_empty_file(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no such file"):
        replay_log(tmp_path / "nope.log", "toyota")
    odd = tmp_path / "capture.pcap"
    odd.write_bytes(b"x")
    with pytest.raises(UserError, match="unknown CAN log format"):
        replay_log(odd, "toyota")
    with pytest.raises(UserError, match="not a file"):
        replay_log(tmp_path, "toyota")
    empty = tmp_path / "empty.log"
    empty.write_bytes(b"")
    s = replay_log(empty, "toyota")
    assert s.frames == 0 and s.distance_m == 0.0


# -- real logs outside the repository (GPL / large): optional -----------------------------------


@pytest.mark.shared_data
def test_full_rav4_log(shared_data: Path) -> None:
    s = replay_log(shared_data / "canlogs/toyota_rav4_2019/rav4_2020-02-03_bus0.log", "toyota")
    assert s.frames == 39331 and s.decoded == 3573 and s.rejected == 0
    assert s.distance_m == pytest.approx(RAV4_DISTANCE_M, abs=0.01)


@pytest.mark.shared_data
def test_civic_type_r_slow_drive(shared_data: Path) -> None:
    s = replay_log(
        shared_data / "canlogs/honda_civic_type_r_2019/turnonanddrive.log", "honda_civic"
    )
    assert s.decoded == 803
    assert s.rejected_by_reason["checksum"] == 0  # real Honda checksums verify
    assert s.rejected == s.rejected_by_reason["gap"] == 11  # the logger lost 41 s in 11 gaps
    assert s.max_speed_mps * 3.6 == pytest.approx(9.0, abs=0.6)  # "0-9.5 km/h"
    assert s.distance_m == pytest.approx(21.69, abs=0.01)
    # The car's odometer counter (ENGINE_DATA, 10 m steps) ticks 3 times: 20 to 40 m driven.
    bridged = replay_log(
        shared_data / "canlogs/honda_civic_type_r_2019/turnonanddrive.log",
        "honda_civic",
        max_gap_s=30.0,
    )
    assert 20.0 <= bridged.distance_m <= 40.0


@pytest.mark.shared_data
def test_civic_8th_front_wheels_only(shared_data: Path) -> None:
    s = replay_log(
        shared_data / "canlogs/honda_civic_8th_front_wheels_only/vsslog.log", "honda_civic"
    )
    assert s.decoded == 1593 and s.rejected == 0
    assert s.front_fallback > 1200  # rears read 0 throughout; the fronts carry the distance
    assert s.distance_m > 100.0


@pytest.mark.shared_data
@pytest.mark.parametrize("name", ["turnwheel.log", "candump-2021-04-18_191854.log"])
def test_camaro_parked_decodes_to_zero(shared_data: Path, name: str) -> None:
    s = replay_log(shared_data / "canlogs/gm_camaro_stationary" / name, "gm_global_a")
    assert s.decoded > 0
    assert s.rejected == s.rejected_by_reason["gap"]  # only the sparse capture's silences
    assert s.distance_m == 0.0
