"""NMEA heading parser, line framing and heading statistics; recorded captures through them."""

from __future__ import annotations

import math
from functools import reduce
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.compass import (
    LineAssembler,
    NmeaCompassParser,
    SerialCompass,
    SerialCompassConfig,
    heading_stats,
    parse_capture,
)
from guidance.app.ports import CompassSource
from guidance.core.messages import CompassHeading
from guidance.errors import UserError

NMEA_DATA = Path(__file__).resolve().parents[1] / "data" / "nmea"


def sentence(body: str, checksum: str | None = "auto") -> bytes:
    """``$body*hh`` with the NMEA XOR checksum (or a given / no checksum field)."""
    if checksum is None:
        return f"${body}".encode()
    if checksum == "auto":
        checksum = f"{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"
    return f"${body}*{checksum}".encode()


def parse(line: bytes, **kw: bool) -> tuple[NmeaCompassParser, CompassHeading | None]:
    p = NmeaCompassParser(**kw)
    return p, p.feed_line(line, t_s=12.5)


def reason(p: NmeaCompassParser) -> str:
    (only,) = [k for k, v in p.rejected_by_reason.items() if v]
    return only


def test_hdg_hdm_hdt() -> None:
    p, h = parse(sentence("HCHDG,101.1,,,7.1,W"))
    assert h is not None and h.heading_deg == pytest.approx(101.1) and not h.is_true
    assert h.t_s == 12.5
    p, h = parse(sentence("HCHDM,238.5,M"))
    assert h is not None and h.heading_deg == pytest.approx(238.5) and not h.is_true
    p, h = parse(sentence("GPHDT,274.07,T"))
    assert h is not None and h.heading_deg == pytest.approx(274.07) and h.is_true
    assert p.stats()["true_headings"] == 1


def test_real_sentences_from_the_gpsd_captures() -> None:
    """Copied from bundg_zeus_9.log and saab-r4.log (checksums as the devices sent them)."""
    p, h = parse(b"$SDHDG,229.8,,,1.3,E*36\r\n")
    assert h is not None and h.heading_deg == pytest.approx(229.8)  # variation ignored
    p, h = parse(b"$HEHDT,4.0,T*2B")
    assert h is not None and h.is_true and h.heading_deg == pytest.approx(4.0)
    p, h = parse(b"$GPHDT,,T*1B")
    assert h is None and reason(p) == "empty_heading"


def test_hdg_deviation_is_applied_and_variation_is_not() -> None:
    _, h = parse(sentence("HCHDG,100.0,2.5,E,10.0,W"))
    assert h is not None and h.heading_deg == pytest.approx(102.5)
    _, h = parse(sentence("HCHDG,1.0,2.5,W,10.0,E"))
    assert h is not None and h.heading_deg == pytest.approx(358.5)
    _, h = parse(sentence("HCHDG,100.0,2.5,E,10.0,W"), apply_hdg_deviation=False)
    assert h is not None and h.heading_deg == pytest.approx(100.0)
    p, h = parse(sentence("HCHDG,100.0,2.5,X,,"))
    assert h is None and reason(p) == "parse"


@pytest.mark.parametrize(
    ("line", "why"),
    [
        (sentence("HCHDG,101.1,,,,", checksum="00"), "checksum"),
        (sentence("HCHDG,101.1,,,,", checksum="0"), "checksum"),
        (sentence("HCHDG,101.1,,,,", checksum="G1"), "checksum"),
        (sentence("HCHDG,101.1,,,,") + b"junk", "checksum"),
        (sentence("HCHDG,101.1,,,,", checksum=None), "no_checksum"),
        (
            sentence("GPGGA,184353.07,1929.045,S,02410.506,E,1,04,2.6,100.00,M,-33.9,M,,0000"),
            "unknown_type",
        ),
        (
            sentence("PASHR,204132.000,010.51,T,+00.39,-00.79,-00.84,0.151,0.075,0.555,1,0"),
            "unknown_type",
        ),
        (sentence("GPABC,1,2,3"), "unknown_type"),
        (b"!AIVDM,1,1,,B,13aGhtw0R<OJf=6LgQ?Ad1FF05`L,0*24", "unknown_type"),
        (sentence("HCHDG"), "parse"),
        (sentence("HCHDG,abc,,,,"), "parse"),
        (sentence("HCHDG,,,,,"), "empty_heading"),
        (sentence("HCHDM,,M"), "empty_heading"),
        (sentence("HCHDG,360.5,,,,"), "out_of_range"),
        (sentence("HCHDG,-0.5,,,,"), "out_of_range"),
        (sentence("HCHDG,nan,,,,"), "out_of_range"),
        (sentence("HCHDG,inf,,,,"), "out_of_range"),
        (b"\x00\xff\xfe\x80garbage", "not_nmea"),
        (b"hello world", "not_nmea"),
        (b"$HCHDG,1\x07.0,,,,*00", "not_nmea"),
        (b"$" + b"A" * 300, "too_long"),
    ],
)
def test_rejections_by_reason(line: bytes, why: str) -> None:
    p, h = parse(line)
    assert h is None
    assert reason(p) == why
    assert p.lines == 1 and p.headings == 0 and p.rejected == 1


def test_missing_checksum_only_when_allowed() -> None:
    _, h = parse(sentence("HCHDG,10.0,,,,", checksum=None), allow_missing_checksum=True)
    assert h is not None and h.heading_deg == pytest.approx(10.0)
    p, h = parse(sentence("HCHDG,10.0,,,,", checksum="00"), allow_missing_checksum=True)
    assert h is None and reason(p) == "checksum"  # present and wrong is still wrong


def test_lowercase_checksum_and_360_fold() -> None:
    body = "HCHDG,360.0,,,,"
    cs = f"{reduce(lambda a, c: a ^ ord(c), body, 0):02x}"
    _, h = parse(sentence(body, checksum=cs))
    assert h is not None and h.heading_deg == 0.0


def test_collision_resyncs_on_the_last_dollar() -> None:
    """isync.log style: a packet injected into another; the complete inner one is kept."""
    line = b"$GPGGA,131519.00,4153.8" + sentence("HCHDG,45.0,,,,")
    p, h = parse(line)
    assert h is not None and h.heading_deg == pytest.approx(45.0)
    assert p.resynced == 1


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=400))
def test_arbitrary_bytes_never_raise_and_counts_add_up(data: bytes) -> None:
    p = NmeaCompassParser()
    out = p.feed_line(data, t_s=0.0)
    assert p.lines == 1 and p.headings + p.rejected == 1
    if out is not None:
        assert 0.0 <= out.heading_deg < 360.0


@settings(max_examples=200, deadline=None)
@given(
    headings=st.lists(st.floats(min_value=0, max_value=359.9), min_size=1, max_size=20),
    cuts=st.lists(st.integers(min_value=0, max_value=2000), max_size=10),
)
def test_lines_survive_any_chunking(headings: list[float], cuts: list[int]) -> None:
    stream = b"".join(sentence(f"HCHDG,{h:.1f},,,,") + b"\r\n" for h in headings)
    chunks, last = [], 0
    for c in sorted(set(min(c, len(stream)) for c in cuts)):
        chunks.append(stream[last:c])
        last = c
    chunks.append(stream[last:])
    asm, p = LineAssembler(), NmeaCompassParser()
    got = [p.feed_line(line, 0.0) for chunk in chunks for line in asm.feed(chunk)]
    assert [g.heading_deg if g else None for g in got] == pytest.approx(
        [round(h, 1) % 360.0 for h in headings], abs=1e-9
    )


def test_line_assembler_line_ends_and_overlong_runs() -> None:
    too_long = []
    asm = LineAssembler(max_bytes=20, on_too_long=lambda: too_long.append(1))
    assert asm.feed(b"a\r\nb\rc\n\n\r\nd") == [b"a", b"b", b"c"]
    assert asm.feed(b"e" * 50) == []  # "de..." overflows: dropped up to the next line end
    assert asm.feed(b"e" * 50 + b"\nok\n") == [b"ok"]
    assert too_long == [1]  # one overlong run, reported once
    assert asm.feed(b"tail") == [] and asm.flush() == [b"tail"]


def test_heading_stats_are_circular() -> None:
    st_ = heading_stats([350.0, 10.0])
    assert st_ is not None
    assert min(st_["mean_deg"], 360.0 - st_["mean_deg"]) == pytest.approx(0.0, abs=1e-9)
    assert st_["std_deg"] == pytest.approx(10.0, rel=0.01)
    assert st_["min_deg"] == 10.0 and st_["max_deg"] == 350.0
    assert heading_stats([]) is None
    spread = heading_stats([0.0, 90.0, 180.0, 270.0])
    assert spread is not None and math.isinf(spread["std_deg"])


# -- recorded captures (shipped under tests/data, see SOURCES.md) -------------------------------

CAPTURES = {
    # file: (lines, headings, comments, {reason: count})
    "bundg_zeus_9_head.log": (392, 115, 8, {"unknown_type": 277}),
    "hemi_head.log": (78, 0, 2, {"unknown_type": 55, "empty_heading": 23}),
    "saab-r4.log": (122, 12, 4, {"unknown_type": 110}),
    "rst39.log": (152, 4, 6, {"unknown_type": 148}),
    "pynmea2_examples_data.log": (5, 0, 0, {"not_nmea": 1, "unknown_type": 4}),
    "pynmea2_sentences.log": (
        10,
        0,
        0,
        {"not_nmea": 1, "no_checksum": 3, "checksum": 1, "unknown_type": 5},
    ),
    "malformed_real/gp-320fw-2019-04-07-coldboot.log": (
        134,
        0,
        15,
        {"not_nmea": 3, "no_checksum": 4, "checksum": 20, "parse": 16, "unknown_type": 91},
    ),
    "malformed_real/isync.log": (135, 0, 14, {"not_nmea": 1, "unknown_type": 134}),
}


@pytest.mark.parametrize("name", sorted(CAPTURES))
def test_shipped_captures(name: str) -> None:
    lines, headings, comments, reasons = CAPTURES[name]
    s = parse_capture(NMEA_DATA / name)
    assert (s.lines, s.headings, s.comments) == (lines, headings, comments)
    assert {k: v for k, v in s.rejected_by_reason.items() if v} == reasons
    assert s.lines == s.headings + s.rejected


def test_bundg_headings_are_a_steady_course() -> None:
    s = parse_capture(NMEA_DATA / "bundg_zeus_9_head.log")
    assert s.stats is not None
    # Arithmetic over the 115 $SDHDG fields (awk): mean 231.737, min 229.8, max 233.0.
    assert s.stats["mean_deg"] == pytest.approx(231.737, abs=0.001)
    assert (s.stats["min_deg"], s.stats["max_deg"]) == (229.8, 233.0)
    assert s.stats["std_deg"] < 1.0


def test_capture_of_arbitrary_bytes_ends_with_a_summary(tmp_path: Path) -> None:
    path = tmp_path / "noise.nmea"
    path.write_bytes(bytes(range(256)) * 64 + b"\n" + b"\xff" * 5000)
    s = parse_capture(path)
    assert s.headings == 0 and s.lines == s.rejected > 0 and s.stats is None


def test_capture_missing_file_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="not found"):
        parse_capture(tmp_path / "none.nmea")


@pytest.mark.shared_data
def test_every_shared_capture_parses(shared_data: Path) -> None:
    files = [p for p in sorted((shared_data / "nmea").rglob("*")) if p.is_file()]
    assert len(files) >= 10
    for path in files:
        s = parse_capture(path)
        assert s.lines == s.headings + s.rejected, path
    full = parse_capture(shared_data / "nmea/gpsd_testlogs/bundg_zeus_9.log")
    assert full.headings == 1457  # every $SDHDG in the capture


def test_serial_compass_is_a_compass_source() -> None:
    assert isinstance(SerialCompass(SerialCompassConfig(port="/dev/null")), CompassSource)


def test_serial_config_values_are_checked() -> None:
    with pytest.raises(UserError, match="port"):
        SerialCompassConfig(port="")
    with pytest.raises(UserError, match="baudrate"):
        SerialCompassConfig(baudrate=0)
    with pytest.raises(UserError, match="read_timeout_s"):
        SerialCompassConfig(read_timeout_s=-1)
