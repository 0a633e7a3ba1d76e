"""Text from outside read defensively (issue 14, item 13): ``guidance odometry`` on a truncated
``.log.gz`` and on a 100 MB line, a candump line missing one hex digit, and numbers such as
``1_0_0`` that ``float()`` accepts. Real files, the real commands and parsers.
"""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest
from reliability_helpers import REPO

from drivers.can_odometry import LogReadResult, read_can_log
from drivers.compass import NmeaCompassParser
from guidance.tools.cli import main
from hal_sim.sim_compass import nmea_sentence

RAV4 = REPO / "tests" / "data" / "can" / "rav4_2020-02-03_bus0_wheelspeeds.log"


def _odometry(capsys: pytest.CaptureFixture[str], path: Path) -> tuple[int, dict[str, Any], str]:
    rc = main(["odometry", str(path), "--profile", "toyota", "--json"])
    cap = capsys.readouterr()
    assert "internal error" not in cap.err and "Traceback" not in cap.err, cap.err
    return rc, (json.loads(cap.out) if rc == 0 else {}), cap.err


def test_a_truncated_log_gz_reports_the_damage_and_keeps_the_frames_before_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    full = tmp_path / "full.log.gz"
    full.write_bytes(gzip.compress(RAV4.read_bytes()))
    rc, whole, _ = _odometry(capsys, full)
    assert rc == 0 and whole["unreadable"] == 0
    cut = tmp_path / "cut.log.gz"
    data = full.read_bytes()
    cut.write_bytes(data[: len(data) * 6 // 10])
    rc, part, err = _odometry(capsys, cut)
    assert rc == 0, err
    assert 0.3 * whole["frames"] < part["frames"] < whole["frames"]  # the frames before it
    assert part["read_error"] and "damaged after line" in part["read_error"]
    assert 0 < part["distance_m"] < whole["distance_m"]


def test_a_huge_line_is_skipped_in_bounded_memory(tmp_path: Path) -> None:
    """A 100 MB line between good lines: counted unreadable, the good lines decoded, and the
    reading takes a few MB, not the line's size (before: the whole line in memory, times
    the copies of decoding it)."""
    lines = RAV4.read_bytes().splitlines(keepends=True)
    path = tmp_path / "huge.log"
    with path.open("wb") as f:
        f.writelines(lines[:100])
        f.write(b"(1580765471.7) can0 0AA#" + b"1" * 100_000_000 + b"\n")
        f.writelines(lines[100:])
    script = textwrap.dedent(
        f"""
        import resource
        from pathlib import Path
        from drivers.can_odometry import replay_log
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        s = replay_log(Path({str(path)!r}), "toyota")
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(s.frames, s.unreadable, (after - before) // 1024)
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    frames, unreadable, grew_mb = (int(v) for v in out.stdout.split())
    assert frames == len(lines) and unreadable == 1
    assert grew_mb < 30, f"reading grew the process by {grew_mb} MB"


@pytest.mark.parametrize(
    "bad",
    [
        b"(1580765471.676344) can0 0AA#29772970296C296",  # one hex digit missing
        b"(1580765471.676344) can0 0AA#2977297G296C296C",  # not hex
        b"(1_5_8_0765471.676344) can0 0AA#29772970296C296C",  # float() takes 1_0_0
        b"(1580765471.676344) can0 0A#29772970296C296C",  # a 2-digit id
        b"(\xd9\xa1.5) can0 0AA#29772970296C296C",  # unicode digits
    ],
)
def test_a_damaged_candump_line_is_rejected_not_decoded_shifted(tmp_path: Path, bad: bytes) -> None:
    good = b"(1580765471.676344) can0 0AA#29772970296C296C\n"
    path = tmp_path / "one.log"
    path.write_bytes(good + bad + b"\n" + good.replace(b".676344", b".686344"))
    result = LogReadResult()
    frames = list(read_can_log(path, result))
    assert len(frames) == 2 and result.unreadable == 1
    assert all(bytes(f.data) == bytes.fromhex("29772970296C296C") for f in frames)


@pytest.mark.parametrize("number", ["1_0_0", "1_0.5", "١٢٣", "1e2", "nan", "infinity", "0x10"])
def test_nmea_numbers_are_plain_decimals(number: str) -> None:
    body = f"HCHDG,{number},,,,".encode()
    checksum = 0
    for b in body:
        checksum ^= b
    parser = NmeaCompassParser()
    assert parser.feed_line(b"$" + body + f"*{checksum:02X}".encode(), 0.0) is None
    assert parser.last_outcome != "ok"
    assert parser.feed_line(nmea_sentence("HCHDG,100.5,,,,").rstrip(), 0.0) is not None
