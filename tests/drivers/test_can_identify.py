"""Vehicle profiles from opendbc, and ``--profile auto`` (issue 41).

Every profile against its own DBC: a drive encoded with the DBC (every message of it, the
wheel speeds real) is recognised as that profile, or one that reads the wheel speeds the same
way, and decodes back to the distance driven. The real logs (tests/data, and every log in
../shared/data when it is there) are recognised as their make; buses of makes no profile
covers (other opendbc DBCs) are an unknown car; two makes' wheel speeds on one bus are not
guessed between. And ``guidance profiles --json``, ``guidance odometry --profile auto``."""

from __future__ import annotations

import itertools
import json
import random
import subprocess
import sys
from pathlib import Path

import can
import pytest

from drivers.can_identify import decoding_key, identify
from drivers.can_odometry import CanOdometry, CanOdometryConfig, replay_log
from drivers.opendbc_dbc import load_dbc, opendbc_platforms
from drivers.profiles import PROFILES, VehicleProfile, honda_checksum
from guidance.errors import UserError

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared" / "data"
SPEEDS_MPS = [0.0] * 10 + [0.25 * i for i in range(40)] + [10.0] * 200
"""A drive: stopped, a 2.5 m/s^2 start, then 10 m/s (every profile's rate)."""


def _frames(profile: VehicleProfile, speeds: list[float], seed: int = 1) -> list[can.Message]:
    """A bus of the profile's DBC: every standard-id message at 10 Hz (all signals 0) and
    the wheel-speed messages at the profile's rate with ``speeds`` on all four wheels."""
    db = load_dbc(profile.dbc_file)
    rng = random.Random(seed)
    wheel_ids = {profile.rear.frame_id, profile.front.frame_id}
    out: list[can.Message] = []
    period = profile.message_period_s
    others = [m for m in db.messages if not m.is_extended_frame and m.frame_id not in wheel_ids]
    for i, v in enumerate(speeds):
        t = 100.0 + i * period
        for fid in sorted(wheel_ids, reverse=True):  # the front first where they differ
            spec = db.get_message_by_frame_id(fid)
            values: dict[str, float] = {s.name: 0.0 for s in spec.signals}
            for axle in (profile.rear, profile.front):
                if axle.frame_id == fid:
                    values[axle.left] = values[axle.right] = v / profile.unit_to_mps
                    for d in (axle.left_direction, axle.right_direction):
                        if d:
                            values[d] = 1 if v > 0 else 0
            data = bytearray(spec.encode(values, strict=False))
            if profile.checksum == "honda":
                data[-1] = (data[-1] & 0xF0) | honda_checksum(fid, bytes(data))
            out.append(can.Message(timestamp=t, arbitration_id=fid, data=data, channel="can0",
                                   is_extended_id=False, is_fd=spec.length > 8))  # fmt: skip
        if i % max(1, round(0.1 / period)) == 0:
            for m in rng.sample(others, len(others)):
                out.append(can.Message(timestamp=t + 1e-4, arbitration_id=m.frame_id,
                                       data=bytes(m.length), channel="can0",
                                       is_fd=m.length > 8))  # fmt: skip
    return out


def _write_candump(frames: list[can.Message], path: Path) -> Path:
    with can.CanutilsLogWriter(str(path), channel="can0") as w:
        for m in frames:
            w.on_message_received(m)
    return path


def test_at_least_ten_makes_each_profile_on_an_opendbc_platform() -> None:
    brands = {p.brand for p in PROFILES.values()}
    assert len(brands) >= 10, brands
    platforms = opendbc_platforms()
    for name, p in PROFILES.items():
        served = platforms.get(p.dbc_file, ())
        assert served, f"{name}: no opendbc platform uses {p.dbc_file}"
        assert {b for b, _ in served} == {p.brand}, (name, served)
        if p.yaw_rate is not None:  # recorded for the gyro work: it is where it says
            msg = load_dbc(p.dbc_file).get_message_by_frame_id(p.yaw_rate.frame_id)
            assert msg.name == p.yaw_rate.message
            msg.get_signal_by_name(p.yaw_rate.signal)


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_a_drive_encoded_with_its_own_dbc_is_recognised_and_decodes_back(
    name: str, tmp_path: Path
) -> None:
    p = PROFILES[name]
    log = _write_candump(_frames(p, SPEEDS_MPS), tmp_path / f"{name}.log")
    summary = replay_log(log, "auto")
    chosen = PROFILES[summary.profile]
    assert decoding_key(chosen) == decoding_key(p), (name, summary.profile_reason)
    dt = p.message_period_s
    driven = sum(0.5 * (a + b) * dt for a, b in itertools.pairwise(SPEEDS_MPS))
    half_count = 0.5 * p.speed_resolution_mps * dt * (len(SPEEDS_MPS) - 1)  # quantisation
    assert abs(summary.distance_m - driven) <= half_count + 1e-9, summary
    assert summary.rejected == 0


REAL_LOGS = {
    "can/rav4_2020-02-03_bus0_wheelspeeds.log": "toyota",
    "realdrives/comma2k19_ex1_wheelspeeds.log": "toyota",
}
SHARED_LOGS = {
    "canlogs/toyota_rav4_2019/rav4_2020-02-03_bus0.log": "toyota",
    "canlogs/honda_civic_type_r_2019/turnonanddrive.log": "honda",
    "canlogs/honda_civic_8th_front_wheels_only/vsslog.log": "honda",
    "canlogs/gm_camaro_stationary/candump-2021-04-18_191854.log": "gm",
    "canlogs/gm_camaro_stationary/turnwheel.log": "gm",
    "realdrives/comma2k19_ex1.log": "toyota",
    "realdrives/smartloc_berlin_potsdamer_platz.log": "toyota",
}


@pytest.mark.parametrize("rel", sorted(REAL_LOGS))
def test_the_shipped_real_logs_are_their_make(rel: str) -> None:
    summary = replay_log(REPO / "tests" / "data" / rel, "auto")
    assert PROFILES[summary.profile].brand == REAL_LOGS[rel], summary.profile_reason


@pytest.mark.shared_data
def test_every_real_log_in_shared_data_is_its_make() -> None:
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} is absent (a fresh clone): the shipped logs are checked above")
    logs = sorted(p for d in ("canlogs", "realdrives") for p in (SHARED / d).rglob("*.log"))
    assert {str(p.relative_to(SHARED)) for p in logs} == set(SHARED_LOGS), "a new log: add it"
    for path in logs:
        summary = replay_log(path, "auto")
        want = SHARED_LOGS[str(path.relative_to(SHARED))]
        assert PROFILES[summary.profile].brand == want, (path, summary.profile_reason)


UNSUPPORTED = ["bmw_e9x_e8x", "mercedes_benz_e350_2010", "volvo_v60_2015_pt",
               "volvo_v40_2017_pt", "psa_aee2010_r3", "luxgen_s5_2015", "opel_omega_2001",
               "hongqi_hs5", "gwm_haval_h6_phev_2024", "rivian_primary_actuator"]  # fmt: skip
"""opendbc DBCs of makes no profile covers (some with wheel speeds of their own)."""


@pytest.mark.parametrize("dbc", UNSUPPORTED)
def test_a_car_no_profile_covers_is_an_unknown_car(dbc: str) -> None:
    db = load_dbc(dbc)
    rng = random.Random(dbc)
    frames = []
    for i in range(50):  # every message, 10 Hz, random bytes: whatever its wheels say
        for m in db.messages:
            if not m.is_extended_frame:
                data = bytes(rng.randrange(256) for _ in range(m.length))
                frames.append(can.Message(
                    timestamp=i * 0.1, arbitration_id=m.frame_id, data=data, channel="can0",
                    is_fd=m.length > 8,
                ))  # fmt: skip
    found = identify(frames)
    assert found.profile is None and found.reason.startswith("unknown car"), found.to_json()


def test_two_makes_wheel_speeds_on_one_bus_are_not_guessed_between() -> None:
    toyota, honda = PROFILES["toyota"], PROFILES["honda_civic"]
    frames = sorted(
        [m for m in _frames(toyota, SPEEDS_MPS) if m.arbitration_id == 0xAA]
        + [m for m in _frames(honda, SPEEDS_MPS) if m.arbitration_id == 0x1D0],
        key=lambda m: m.timestamp,
    )
    found = identify(frames)
    assert found.profile is None and found.reason.startswith("ambiguous"), found.to_json()


def test_cli_profiles_and_auto(tmp_path: Path) -> None:
    cli = [sys.executable, "-m", "guidance.tools.cli"]
    listed = json.loads(subprocess.run(
        [*cli, "profiles", "--json"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout)  # fmt: skip
    assert len({e["brand"] for e in listed}) >= 10
    assert all({"name", "brand", "platforms"} <= set(e) for e in listed)
    log = REPO / "tests" / "data" / "can" / "rav4_2020-02-03_bus0_wheelspeeds.log"
    out = subprocess.run([*cli, "odometry", str(log), "--profile", "auto", "--json"], cwd=REPO,
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    summary = json.loads(out)
    assert summary["profile"] == "toyota" and "defines" in summary["profile_reason"]
    unknown = _write_candump(
        [can.Message(timestamp=i * 0.01, arbitration_id=0x123 + i % 7, data=bytes(8),
                     channel="can0") for i in range(500)],
        tmp_path / "unknown.log",
    )  # fmt: skip
    run = subprocess.run([*cli, "odometry", str(unknown), "--profile", "auto"], cwd=REPO,
                         capture_output=True, text=True)  # fmt: skip
    assert run.returncode == 2 and run.stdout == ""
    assert len(run.stderr.strip().splitlines()) == 1 and "unknown car" in run.stderr


def test_the_car_recognises_its_bus_at_start() -> None:
    """``[odometry] profile = "auto"`` on a live (virtual) bus: a Subaru's frames."""
    p = PROFILES["subaru_global_2017"]
    frames = _frames(p, [10.0] * 120)
    cfg = CanOdometryConfig(interface="virtual", channel="identify_test", profile="auto",
                            bitrate=None, bus_options={"receive_own_messages": False})  # fmt: skip
    import threading

    sender = can.Bus(interface="virtual", channel="identify_test")
    stop = threading.Event()

    def send() -> None:
        while not stop.is_set():
            for m in frames:
                if stop.is_set():
                    break
                sender.send(m)
                stop.wait(0.001)

    thread = threading.Thread(target=send)
    thread.start()
    try:
        odo = CanOdometry(cfg)
        assert odo.config.profile in {n for n, q in PROFILES.items()
                                      if decoding_key(q) == decoding_key(p)}  # fmt: skip
    finally:
        stop.set()
        thread.join()
        sender.shutdown()
    with pytest.raises(UserError, match="must be up at start"):
        CanOdometry(CanOdometryConfig(interface="socketcan", channel="no_such_can9",
                                      profile="auto"))  # fmt: skip
