"""Property and fuzz tests (hypothesis) of the input edges: NMEA, CAN decoding, the CLI replays.

Properties: nothing raises; every heading is finite in [0, 360); every odometry increment is
finite and no longer than the fastest plausible car covers in the longest bridged gap; counts
add up; and the real ``PoseEstimator``, fed whatever got through, stays finite. Per run
(``N_*`` below, derandomized so CI sees the same inputs): about 14,000 NMEA lines (6,000 of
arbitrary bytes, 5,000 near-valid sentences, 1,000 chunked streams of about 3,000 lines), 6,000
CAN sequences holding about 176,000 frames (about 41,000 of which close an interval and are
integrated), and 300 replay-command runs; about 40 s on two cores.

``guidance odometry`` and ``guidance compass`` given arbitrary bytes end with a summary (exit 0)
or one clear error line (exit 2), never a traceback: in process for many inputs, and as real
subprocesses for a few.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reliability_helpers import REPO

from drivers.can_decode import MAX_SPEED_MPS, REJECT_REASONS, WheelSpeedDecoder
from drivers.compass import LineAssembler, NmeaCompassParser
from drivers.profiles import PROFILES, get_profile, honda_checksum, load_dbc
from guidance.core.localize.compass_cal import compass_heading_to_theta
from guidance.core.localize.estimator import PoseEstimator
from guidance.core.messages import HeadingFix
from guidance.tools.cli import main as guidance_main
from hal_sim.sim_compass import nmea_checksum

N_NMEA_BYTES = 6000
N_NMEA_SENTENCES = 5000
N_NMEA_STREAM = 1000
N_CAN_RANDOM = 3000  # sequences of up to 40 frames: ~60,000 frames
N_CAN_ENCODED = 3000
N_CLI = 150
FUZZ = settings(
    deadline=None,
    suppress_health_check=[
        HealthCheck.too_slow,
        HealthCheck.filter_too_much,
        HealthCheck.function_scoped_fixture,  # capsys: read (and so reset) on every example
    ],
    derandomize=True,  # the same inputs every run: CI is deterministic
)

# -- NMEA -----------------------------------------------------------------------------------------
NUMBERISH = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**400), 10**400).map(str),
    st.sampled_from(
        [
            "",
            "nan",
            "NaN",
            "inf",
            "-inf",
            "1e309",
            "-0",
            "360",
            "360.0001",
            "0x10",
            "1_0",
            " 12",
            "١٢",
            "∞",
            "E",
            "W",
            "",
            ",",
        ]
    ),
    st.text(alphabet="0123456789.-+eE", max_size=12),
)
SENTENCE_TYPES = st.sampled_from(["HDG", "HDM", "HDT", "GGA", "RMC", "VTG", "HDX", "", "HD"])
TALKERS = st.sampled_from(["HC", "GP", "II", "P", "", "HCX", "$"])


def check_heading_parser(parser: NmeaCompassParser, line: bytes) -> None:
    before = parser.lines
    out = parser.feed_line(line, t_s=1.0)
    assert parser.lines == before + 1
    assert parser.lines == parser.headings + parser.rejected
    if out is not None:
        assert math.isfinite(out.heading_deg) and 0.0 <= out.heading_deg < 360.0
        theta = compass_heading_to_theta(out, declination_deg=-12.0)
        est = PoseEstimator()
        est.process(HeadingFix(1.0, theta))
        assert np.all(np.isfinite(est.x)) and np.all(np.isfinite(est.P))


@settings(FUZZ, max_examples=N_NMEA_BYTES)
@given(st.binary(max_size=300))
def test_nmea_parser_on_arbitrary_bytes(line: bytes) -> None:
    check_heading_parser(NmeaCompassParser(), line)


@st.composite
def sentences(draw: st.DrawFn) -> bytes:
    """Sentences that get past the framing: heading types with odd fields, right checksums."""
    fields = draw(st.lists(NUMBERISH, max_size=8))
    body = draw(TALKERS) + draw(SENTENCE_TYPES) + "".join("," + f for f in fields)
    how = draw(st.sampled_from(["good", "good", "good", "none", "wrong", "lower", "junk"]))
    try:
        cs = nmea_checksum(body)
    except UnicodeEncodeError:
        cs = 0
    tail = {
        "good": f"*{cs:02X}",
        "lower": f"*{cs:02x}",
        "none": "",
        "wrong": f"*{cs ^ 0x21:02X}",
        "junk": "*" + draw(st.text(max_size=3)),
    }[how]
    prefix = draw(st.sampled_from(["", "", "", "garbage", "$GPGGA,1*00", "!AIVDM"]))
    return (prefix + "$" + body + tail).encode("utf-8", "surrogatepass")


@settings(FUZZ, max_examples=N_NMEA_SENTENCES)
@given(sentences(), st.booleans())
def test_nmea_parser_on_near_valid_sentences(line: bytes, allow_missing: bool) -> None:
    check_heading_parser(NmeaCompassParser(allow_missing_checksum=allow_missing), line)


@settings(FUZZ, max_examples=N_NMEA_STREAM)
@given(st.lists(st.one_of(sentences(), st.binary(max_size=400)), max_size=12), st.data())
def test_serial_framing_and_parser_on_random_streams(
    parts: list[bytes], data: st.DataObject
) -> None:
    """The live path: chunks of a byte stream -> LineAssembler -> parser, memory bounded."""
    stream = b"".join(p + data.draw(st.sampled_from([b"\r\n", b"\n", b"\r", b""])) for p in parts)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    parser = NmeaCompassParser()
    asm = LineAssembler(on_too_long=lambda: parser.reject("too_long"))
    lines = []
    start = 0
    for cut in [*cuts, len(stream)]:
        lines += asm.feed(stream[start:cut])
        assert len(asm._buf) <= asm.max_bytes  # never holds more than one line's worth
        start = cut
    lines += asm.flush()
    for line in lines:
        check_heading_parser(parser, line)


# -- CAN ------------------------------------------------------------------------------------------
PROFILE_NAMES = sorted(PROFILES)
WHEEL_IDS = sorted({fid for p in PROFILES.values() for fid in p.frame_ids})


WHEEL_LENGTHS = {
    fid: load_dbc(p.dbc_file).get_message_by_frame_id(fid).length
    for p in PROFILES.values()
    for fid in p.frame_ids
}


def frames_from_bytes(blob: bytes) -> list[can.Message]:
    """Decode a byte string into frames: 4 header bytes (flags and time step, id selector,
    length, spare) then the data. Wheel-speed ids mostly get their right length (and a right
    Honda checksum), so random payloads reach the integration. One hypothesis draw per example
    keeps generation cheap, and hypothesis still shrinks and mutates the bytes."""
    out = []
    t = 0.0
    i = 0
    while i + 4 <= len(blob):
        flags, sel, low, dlc = blob[i : i + 4]
        i += 4
        extended = flags & 0x0F == 0x08
        if sel < 224:
            fid = WHEEL_IDS[sel % len(WHEEL_IDS)]
            n = WHEEL_LENGTHS[fid] if dlc < 224 else dlc % 9
        else:
            fid = ((sel << 8) | low) & (0x1FFF_FFFF if extended else 0x7FF)
            n = dlc % 9
        data = bytearray(blob[i : i + n].ljust(n, b"\0"))
        i += n
        if fid == 0x1D0 and data and dlc & 1:
            data[-1] = (data[-1] & 0xF0) | honda_checksum(fid, bytes(data))
        mode = flags >> 4
        if mode < 11:
            t += 0.0125 * (1 + mode % 4)
        elif mode == 11:
            t += low / 100.0  # up to 2.55 s: gaps either side of max_gap_s
        elif mode == 12:
            t -= low / 1000.0  # backwards
        elif mode == 13:
            t = (math.nan, math.inf, -math.inf, 1e12)[low % 4]
        elif mode == 14:
            t = 0.0  # the clock restarts
        # mode 15: the same time again (a duplicate)
        out.append(
            can.Message(
                timestamp=t,
                arbitration_id=fid,
                is_extended_id=extended,
                is_error_frame=flags & 0x0F == 0x03,
                is_remote_frame=flags & 0x0F == 0x05,
                data=data,
            )
        )
    return out


def check_decoder(decoder: WheelSpeedDecoder, frames: list[can.Message]) -> None:
    est = PoseEstimator()
    limit = decoder.max_speed_mps * decoder.max_gap_s + 1e-9
    for msg in frames:
        inc = decoder.feed(msg)
        if inc is None:
            continue
        assert math.isfinite(inc.t_s)
        assert math.isfinite(inc.d_left_m) and math.isfinite(inc.d_right_m)
        assert abs(inc.d_left_m) <= limit and abs(inc.d_right_m) <= limit
        est.process(inc)
    assert np.all(np.isfinite(est.x)) and np.all(np.isfinite(est.P))
    s = decoder.stats()
    assert s["frames"] == len(frames)
    assert s["rejected"] == sum(s[f"rejected_{r}"] for r in REJECT_REASONS)
    # Every frame is ignored, rejected before decoding, or decoded (and then maybe rejected).
    pre = s["rejected_dlc"] + s["rejected_checksum"] + s["rejected_decode"]
    assert s["ignored"] + s["decoded"] + pre >= s["frames"]
    assert s["emitted"] <= s["decoded"]
    assert math.isfinite(decoder.distance_m) and decoder.distance_m <= limit * max(s["emitted"], 1)


@settings(FUZZ, max_examples=N_CAN_RANDOM)
@given(st.sampled_from(PROFILE_NAMES), st.binary(min_size=160, max_size=480))
def test_can_decoder_on_random_frames(profile: str, blob: bytes) -> None:
    check_decoder(WheelSpeedDecoder(profile), frames_from_bytes(blob))


def encoded_frames(name: str, blob: bytes) -> list[can.Message]:
    """Well-formed wheel-speed frames (cantools-encoded, Honda checksums right) driven by the
    bytes: mostly a random walk of plausible wheel speeds at the message period, sometimes raw
    signal values anywhere in their range (directions and fault bits included), irregular
    times, broken checksums."""
    p = get_profile(name)
    db = load_dbc(p.dbc_file)
    specs = [db.get_message_by_frame_id(fid) for fid in p.frame_ids]
    out = []
    t = 0.0
    speed_kph = [30.0] * 4
    for pos in range(0, len(blob) - 3, 4):
        control, a, b, c = blob[pos : pos + 4]
        for k in range(4):
            speed_kph[k] = min(max(speed_kph[k] + (blob[pos + k] - 128) / 32.0, 0.0), 200.0)
        for spec in specs:
            if control >= 230:  # wild raw values
                raw = {}
                for j, sig in enumerate(spec.signals):
                    word = (a << 16 | b << 8 | c) * (j + 1) % (2**sig.length)
                    raw[sig.name] = word - 2 ** (sig.length - 1) if sig.is_signed else word
                data = bytearray(spec.encode(raw, scaling=False, strict=False))
            else:
                phys = {sig.name: 0 for sig in spec.signals}
                wheels = {p.rear.left, p.rear.right, p.front.left, p.front.right}
                for j, sig in enumerate(spec.signals):
                    if "Dir" in sig.name:
                        phys[sig.name] = 1
                    elif sig.name in wheels:  # in the DBC's unit (km/h, rpm, rad/s)
                        phys[sig.name] = speed_kph[j % 4] / 3.6 / p.unit_to_mps
                data = bytearray(spec.encode(phys, strict=False))
            if p.checksum == "honda" and control % 16:
                data[-1] = (data[-1] & 0xF0) | honda_checksum(spec.frame_id, bytes(data))
            out.append(
                can.Message(
                    timestamp=t, arbitration_id=spec.frame_id, data=data, is_extended_id=False
                )
            )
        t += p.message_period_s if control < 200 else (control - 200) / 20.0 - 0.2
    return out


@settings(FUZZ, max_examples=N_CAN_ENCODED)
@given(st.sampled_from(PROFILE_NAMES), st.binary(min_size=40, max_size=240))
def test_can_decoder_on_well_formed_frames_with_wild_values(name: str, blob: bytes) -> None:
    decoder = WheelSpeedDecoder(name)
    check_decoder(decoder, encoded_frames(name, blob))
    assert decoder.max_speed_seen_mps <= MAX_SPEED_MPS


# -- the replay commands on arbitrary bytes -------------------------------------------------------
SUFFIXES = [".log", ".log.gz", ".asc", ".blf", ".trc", ".csv", ".mf4", ".db", ""]


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        rc = guidance_main(argv)
    except SystemExit as exc:  # argparse
        rc = int(exc.code or 0)
    out, err = capsys.readouterr()
    return rc, out, err


@settings(FUZZ, max_examples=N_CLI)
@given(st.binary(max_size=3000), st.sampled_from(SUFFIXES), st.sampled_from(PROFILE_NAMES))
def test_guidance_odometry_on_arbitrary_bytes(
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    blob: bytes,
    suffix: str,
    profile: str,
) -> None:
    path = tmp_path_factory.mktemp("odo") / f"capture{suffix}"
    path.write_bytes(blob)
    rc, out, err = run_cli(["odometry", str(path), "--profile", profile], capsys)
    assert rc in (0, 2), err
    assert "Traceback" not in err and "internal error" not in err
    if rc == 0:
        assert "distance:" in out and "rejected:" in out
    else:
        assert err.startswith("guidance odometry: error:") and err.count("\n") == 1


@settings(FUZZ, max_examples=N_CLI)
@given(st.binary(max_size=5000), st.booleans())
def test_guidance_compass_on_arbitrary_bytes(
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    blob: bytes,
    allow_missing: bool,
) -> None:
    path = tmp_path_factory.mktemp("nmea") / "capture.nmea"
    path.write_bytes(blob)
    argv = ["compass", str(path)] + (["--allow-missing-checksum"] if allow_missing else [])
    rc, out, err = run_cli(argv, capsys)
    assert rc == 0, err
    assert "Traceback" not in err
    assert "lines:" in out and "rejected:" in out and "statistics:" in out


@pytest.mark.parametrize(
    ("command", "suffix"),
    [("odometry", ".log"), ("odometry", ".blf"), ("odometry", ".asc"), ("compass", ".nmea")],
)
def test_replay_commands_in_a_real_process_on_random_bytes(
    tmp_path: Path, command: str, suffix: str
) -> None:
    rng = np.random.default_rng(11)
    path = tmp_path / f"random{suffix}"
    path.write_bytes(rng.integers(0, 256, 200_000, dtype=np.uint8).tobytes())
    argv = [sys.executable, "-m", "guidance.tools.cli", command, str(path)]
    if command == "odometry":
        argv += ["--profile", "gm_global_a"]
    r = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    if command == "compass":
        assert r.returncode == 0 and "rejected:" in r.stdout and "statistics:" in r.stdout
    else:
        assert r.returncode in (0, 2), r.stderr
        summary = r.stdout if r.returncode == 0 else r.stderr
        assert ("distance:" in summary) or ("error:" in summary and summary.count("\n") == 1)
