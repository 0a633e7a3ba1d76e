"""WheelSpeedDecoder per profile (frames built with cantools from the DBCs) and CanOdometry."""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import threading
import time
import uuid
from collections.abc import Sequence
from typing import Any

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can_decode import MAX_CONSECUTIVE_SPIKES, WheelSpeedDecoder
from drivers.can_odometry import CanOdometry, CanOdometryConfig
from drivers.profiles import PROFILES, get_profile, honda_checksum, load_dbc
from guidance.app.ports import OdometrySource
from guidance.core.messages import WheelOdometry
from guidance.errors import UserError

KPH = 3.6


def frame(
    profile: str,
    t: float,
    rl: float,
    rr: float,
    fl: float | None = None,
    fr: float | None = None,
    **extra: float,
) -> list[can.Message]:
    """The profile's wheel-speed frame(s) for signed speeds in m/s, encoded by cantools."""
    p = get_profile(profile)
    db = load_dbc(p.dbc_file)
    fl = rl if fl is None else fl
    fr = rr if fr is None else fr

    def values(sig: Any, left: float, right: float) -> dict[str, float]:
        out: dict[str, float] = {}
        for name, v in ((sig.left, left), (sig.right, right)):
            unit = v / p.unit_to_mps  # in the DBC's unit (km/h, rad/s, rpm)
            out[name] = unit if p.signed_speeds else abs(unit)
        for name, v in ((sig.left_direction, left), (sig.right_direction, right)):
            if name:
                out[name] = 1 if v > 0 else 2 if v < 0 else 0
        for name in (sig.left_fault, sig.right_fault):
            if name:
                out[name] = 0
        return out

    def encode(frame_id: int, vals: dict[str, float]) -> can.Message:
        spec = db.get_message_by_frame_id(frame_id)
        full: dict[str, float] = {s.name: 0.0 for s in spec.signals}
        full.update(vals)
        full.update({k: v for k, v in extra.items() if k in full})
        data = bytearray(spec.encode(full, strict=False))
        if p.checksum == "honda":
            data[-1] = (data[-1] & 0xF0) | honda_checksum(frame_id, bytes(data))
        return can.Message(timestamp=t, arbitration_id=frame_id, data=data, is_extended_id=False)

    if p.rear.frame_id == p.front.frame_id:
        vals = values(p.rear, rl, rr)
        vals.update(values(p.front, fl, fr))
        return [encode(p.rear.frame_id, vals)]
    # GM: front first, as the fronts must be fresh when the rear frame closes the interval.
    return [
        encode(p.front.frame_id, values(p.front, fl, fr)),
        encode(p.rear.frame_id, values(p.rear, rl, rr)),
    ]


def drive(
    dec: WheelSpeedDecoder, profile: str, speeds: Sequence[tuple[float, ...]], t0: float = 100.0
) -> list[WheelOdometry]:
    """Feed one frame set per entry, spaced by the profile's message period."""
    period = get_profile(profile).message_period_s
    out = []
    for i, s in enumerate(speeds):
        for msg in frame(profile, t0 + i * period, *s):
            inc = dec.feed(msg)
            if inc is not None:
                out.append(inc)
    return out


def quantised(profile: str, v_mps: float) -> float:
    """The speed the bus can carry: the signal's resolution, rounded to nearest."""
    res = get_profile(profile).speed_resolution_kph
    return round(v_mps * KPH / res) * res / KPH


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_constant_speed_integrates_to_distance(profile: str) -> None:
    dec = WheelSpeedDecoder(profile)
    n = 200
    out = drive(dec, profile, [(10.0, 10.4)] * (n + 1))
    period = get_profile(profile).message_period_s
    assert len(out) == n
    assert sum(o.d_left_m for o in out) == pytest.approx(
        quantised(profile, 10.0) * n * period, rel=1e-9
    )
    assert sum(o.d_right_m for o in out) == pytest.approx(
        quantised(profile, 10.4) * n * period, rel=1e-9
    )
    # Quantisation bound against the true speed: half a count of speed over the whole time.
    half_count = 0.5 * get_profile(profile).speed_resolution_kph / KPH
    assert abs(sum(o.d_left_m for o in out) - 10.0 * n * period) <= half_count * n * period + 1e-9
    assert out[0].t_s == pytest.approx(100.0 + period)
    assert all(b.t_s > a.t_s for a, b in itertools.pairwise(out))
    s = dec.stats()
    assert s["rejected"] == 0 and s["emitted"] == n and s["ignored"] == 0


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_trapezoid_on_a_ramp_is_exact(profile: str) -> None:
    period = get_profile(profile).message_period_s
    steps = 100
    res = get_profile(profile).speed_resolution_kph / KPH
    speeds = [(round(i * 0.05 / res) * res,) * 2 for i in range(steps + 1)]  # exact counts
    out = drive(WheelSpeedDecoder(profile), profile, speeds)
    v = [s[0] for s in speeds]  # the trapezoid of the counts the bus carries
    expected = sum(0.5 * (a + b) * period for a, b in itertools.pairwise(v))
    assert sum(o.d_left_m for o in out) == pytest.approx(expected, rel=1e-6)
    assert expected == pytest.approx(0.5 * v[-1] * steps * period, rel=5e-3)


@pytest.mark.parametrize("profile", ["gm_global_a", "toyota"])
def test_reverse_is_negative(profile: str) -> None:
    out = drive(WheelSpeedDecoder(profile), profile, [(-2.0, -2.0)] * 11)
    assert all(o.d_left_m < 0 and o.d_right_m < 0 for o in out)
    assert sum(o.d_left_m for o in out) == pytest.approx(
        -quantised(profile, 2.0) * 10 * get_profile(profile).message_period_s
    )


def test_honda_speeds_are_unsigned() -> None:
    """The Civic DBC has no direction: reverse reads as forward (documented limitation)."""
    out = drive(WheelSpeedDecoder("honda_civic"), "honda_civic", [(-2.0, -2.0)] * 3)
    assert all(o.d_left_m > 0 for o in out)


def test_turning_gives_differential_distances() -> None:
    out = drive(WheelSpeedDecoder("gm_global_a"), "gm_global_a", [(9.0, 11.0)] * 21)
    dl = sum(o.d_left_m for o in out)
    dr = sum(o.d_right_m for o in out)
    assert dr > dl
    assert (dr - dl) / get_profile("gm_global_a").track_width_m == pytest.approx(
        (quantised("gm_global_a", 11.0) - quantised("gm_global_a", 9.0)) * 1.0 / 1.72, rel=1e-6
    )


def test_other_ids_remote_error_and_extended_frames_are_ignored() -> None:
    dec = WheelSpeedDecoder("toyota")
    good = frame("toyota", 1.0, 5.0, 5.0)[0]
    other = can.Message(timestamp=1.0, arbitration_id=0x123, data=b"\0" * 8, is_extended_id=False)
    assert dec.feed(other) is None
    assert (
        dec.feed(
            can.Message(timestamp=1.0, arbitration_id=0xAA, data=good.data, is_extended_id=True)
        )
        is None
    )
    remote = can.Message(
        timestamp=1.0, arbitration_id=0xAA, is_remote_frame=True, is_extended_id=False
    )
    assert dec.feed(remote) is None
    assert dec.feed(can.Message(timestamp=1.0, is_error_frame=True)) is None
    s = dec.stats()
    assert s["frames"] == 4 and s["ignored"] == 4 and s["rejected"] == 0 and s["decoded"] == 0


def test_wrong_dlc_is_rejected() -> None:
    dec = WheelSpeedDecoder("toyota")
    good = frame("toyota", 1.0, 5.0, 5.0)[0]
    short = can.Message(
        timestamp=1.0, arbitration_id=0xAA, data=good.data[:5], is_extended_id=False
    )
    assert dec.feed(short) is None
    assert dec.rejected_by_reason["dlc"] == 1 and dec.decoded == 0


def test_honda_checksum_is_verified() -> None:
    dec = WheelSpeedDecoder("honda_civic")
    msg = frame("honda_civic", 1.0, 5.0, 5.0)[0]
    bad = bytearray(msg.data)
    bad[-1] ^= 0x01
    corrupt = can.Message(timestamp=1.0, arbitration_id=0x1D0, data=bad, is_extended_id=False)
    assert dec.feed(corrupt) is None
    assert dec.rejected_by_reason["checksum"] == 1
    assert dec.feed(msg) is None  # good frame: the anchor
    assert dec.decoded == 1


def test_real_honda_frames_pass_the_checksum() -> None:
    """Two frames copied from the Civic 8th-generation log (checksum nibbles 0xA and 0xD)."""
    for data in ("000000000000000A", "09B812A40000000D"):
        assert (bytes.fromhex(data)[-1] & 0xF) == honda_checksum(0x1D0, bytes.fromhex(data))


def test_non_monotonic_timestamp_is_rejected_without_integrating() -> None:
    dec = WheelSpeedDecoder("toyota")
    p = 0.0125
    msgs = [frame("toyota", t, 10.0, 10.0)[0] for t in (1.0, 1.0 + p, 1.0 + p / 2, 1.0 + 2 * p)]
    out = [dec.feed(m) for m in msgs]
    assert out[0] is None and out[1] is not None and out[2] is None and out[3] is not None
    assert dec.rejected_by_reason["non_monotonic"] == 1
    assert dec.left_m == pytest.approx(quantised("toyota", 10.0) * 2 * p)


def test_duplicate_timestamp_is_rejected() -> None:
    dec = WheelSpeedDecoder("toyota")
    m = frame("toyota", 1.0, 10.0, 10.0)[0]
    dec.feed(m)
    assert dec.feed(m) is None
    assert dec.rejected_by_reason["non_monotonic"] == 1


def test_clock_stepping_back_far_reanchors() -> None:
    dec = WheelSpeedDecoder("toyota")
    dec.feed(frame("toyota", 100.0, 10.0, 10.0)[0])
    assert dec.feed(frame("toyota", 50.0, 10.0, 10.0)[0]) is None  # stepped back 50 s
    out = dec.feed(frame("toyota", 50.0125, 10.0, 10.0)[0])
    assert out is not None and out.d_left_m == pytest.approx(quantised("toyota", 10.0) * 0.0125)


def test_gap_is_not_integrated_and_reanchors() -> None:
    dec = WheelSpeedDecoder("gm_global_a", max_gap_s=0.5)
    drive(dec, "gm_global_a", [(10.0, 10.0)] * 3, t0=0.0)
    before = dec.left_m
    for m in frame("gm_global_a", 0.1 + 0.6, 10.0, 10.0):  # 0.6 s of silence
        assert dec.feed(m) is None
    assert dec.rejected_by_reason["gap"] == 1
    assert dec.left_m == before
    assert dec.gap_s == pytest.approx(0.6)
    out = [dec.feed(m) for m in frame("gm_global_a", 0.75, 10.0, 10.0)]
    assert out[-1] is not None and out[-1].d_left_m == pytest.approx(
        quantised("gm_global_a", 10.0) * 0.05
    )


def test_implausible_speed_is_rejected() -> None:
    dec = WheelSpeedDecoder("gm_global_a")
    drive(dec, "gm_global_a", [(10.0, 10.0)] * 2, t0=0.0)
    spec = load_dbc("gm_global_a_powertrain_generated.dbc").get_message_by_frame_id(0x34A)
    raw = spec.encode({"RLWheelSpd": 0, "RRWheelSpd": 0, "RLWheelDir": 1, "RRWheelDir": 1})
    garbage = bytes([0xFF, 0xFF, 0xFF, 0xFF]) + raw[4:]  # 0xFFFF = 2038 km/h
    msg = can.Message(timestamp=0.1, arbitration_id=0x34A, data=garbage, is_extended_id=False)
    assert dec.feed(msg) is None
    assert dec.rejected_by_reason["implausible"] == 1


def test_single_spike_is_rejected_and_the_next_frame_bridges_it() -> None:
    dec = WheelSpeedDecoder("toyota")
    speeds = [(10.0, 10.0)] * 5 + [(60.0, 60.0)] + [(10.0, 10.0)] * 5
    out = drive(dec, "toyota", speeds)
    assert dec.rejected_by_reason["spike"] == 1
    assert len(out) == 9
    assert dec.left_m == pytest.approx(quantised("toyota", 10.0) * 10 * 0.0125)


def test_a_persistent_level_change_is_believed_after_a_few_spikes() -> None:
    dec = WheelSpeedDecoder("toyota")
    speeds = [(10.0, 10.0)] * 3 + [(40.0, 40.0)] * 10
    out = drive(dec, "toyota", speeds)
    assert dec.rejected_by_reason["spike"] == MAX_CONSECUTIVE_SPIKES + 1
    assert out[-1].d_left_m == pytest.approx(quantised("toyota", 40.0) * 0.0125)


def test_fault_bits_reject_the_frame() -> None:
    # Toyota: opendbc 0.3.1 reads the bit the older DBC called WHEEL_SPEED_RL_FAULT as the
    # speed's top bit (+327.68 km/h): a set "fault" bit is an implausible speed, rejected.
    dec = WheelSpeedDecoder("toyota")
    for m in frame("toyota", 1.0, 5.0, 5.0):
        m.data[6] |= 0x80  # bit 55, the top bit of WHEEL_SPEED_RL
        assert dec.feed(m) is None
    assert dec.rejected_by_reason["implausible"] == 1
    gm = WheelSpeedDecoder("gm_global_a")
    for m in frame("gm_global_a", 1.0, 5.0, 5.0, RLWheelDir=4):
        gm.feed(m)
    assert gm.rejected_by_reason["fault"] == 1


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_front_wheel_fallback_when_rears_read_zero(
    profile: str, caplog: pytest.LogCaptureFixture
) -> None:
    dec = WheelSpeedDecoder(profile)
    period = get_profile(profile).message_period_s
    with caplog.at_level(logging.WARNING, logger="drivers.can_decode"):
        out = drive(dec, profile, [(0.0, 0.0, 8.0, 8.2)] * 21 + [(8.0, 8.0, 8.0, 8.0)] * 5)
    assert dec.front_fallback == 20
    assert sum(o.d_left_m for o in out[:20]) == pytest.approx(quantised(profile, 8.0) * 20 * period)
    assert sum(o.d_right_m for o in out[:20]) == pytest.approx(
        quantised(profile, 8.2) * 20 * period
    )
    flips = [r for r in caplog.records if "front" in r.getMessage()]
    assert len(flips) == 2  # once on, once off: not once per frame


def test_front_fallback_can_be_disabled() -> None:
    prof = dataclasses.replace(get_profile("honda_civic"), allow_front_fallback=False)
    dec = WheelSpeedDecoder(prof)
    drive(dec, "honda_civic", [(0.0, 0.0, 8.0, 8.0)] * 10)
    assert dec.front_fallback == 0 and dec.left_m == 0.0


def test_gm_fallback_needs_fresh_front_frames() -> None:
    dec = WheelSpeedDecoder("gm_global_a")
    fronts = frame("gm_global_a", 0.0, 0.0, 0.0, 8.0, 8.0)[0]
    dec.feed(fronts)
    for i in range(1, 30):  # rears only, 1.45 s: the last front frame goes stale after 1 s
        dec.feed(frame("gm_global_a", i * 0.05, 0.0, 0.0)[1])
    assert 0 < dec.front_fallback < 29


def test_unknown_profile_is_a_user_error() -> None:
    with pytest.raises(UserError, match=r"known profiles: acura_ilx_2016_can, .*, vw_pq"):
        WheelSpeedDecoder("tesla")


@settings(max_examples=300, deadline=None)
@given(
    profile=st.sampled_from(sorted(PROFILES)),
    frames=st.lists(
        st.tuples(
            st.sampled_from([0xAA, 0x1D0, 0x348, 0x34A, 0x123]),
            st.binary(max_size=8),
            st.one_of(
                st.floats(min_value=0, max_value=1e4), st.just(float("nan")), st.just(math.inf)
            ),
        ),
        max_size=60,
    ),
)
def test_decoder_never_raises_and_counts_add_up(
    profile: str, frames: list[tuple[int, bytes, float]]
) -> None:
    dec = WheelSpeedDecoder(profile)
    for fid, data, t in frames:
        out = dec.feed(
            can.Message(timestamp=t, arbitration_id=fid, data=data, is_extended_id=False)
        )
        if out is not None:
            assert math.isfinite(out.d_left_m) and math.isfinite(out.d_right_m)
            assert abs(out.d_left_m) <= 90.0 * dec.max_gap_s
    s = dec.stats()
    assert s["frames"] == len(frames)
    wheel = s["frames"] - s["ignored"]
    undecoded = s["rejected_dlc"] + s["rejected_checksum"] + s["rejected_decode"]
    assert s["decoded"] + undecoded == wheel
    assert s["emitted"] <= s["decoded"]


# -- CanOdometry: the live source on a python-can bus ------------------------------------------


def test_can_odometry_is_an_odometry_source() -> None:
    assert isinstance(CanOdometry(CanOdometryConfig(interface="virtual")), OdometrySource)


def test_can_odometry_reads_a_virtual_bus_and_maps_time_to_monotonic() -> None:
    channel = f"test_{uuid.uuid4().hex}"
    got: list[WheelOdometry] = []
    odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=channel, profile="toyota"))
    odo.start(got.append)
    try:
        with can.Bus(interface="virtual", channel=channel) as tx:
            for _ in range(11):
                for m in frame("toyota", 0.0, 10.0, 10.0):
                    tx.send(m)  # the virtual bus stamps time.time(), like socketcan
                time.sleep(0.0125)
            deadline = time.monotonic() + 5.0
            while odo.stats()["frames"] < 11 and time.monotonic() < deadline:
                time.sleep(0.01)
    finally:
        odo.stop()
    assert len(got) == 10
    now = time.monotonic()
    assert all(now - 2.0 < g.t_s <= now for g in got)  # monotonic clock, not Unix time
    total_t = got[-1].t_s - got[0].t_s + (got[0].d_left_m / quantised("toyota", 10.0))
    assert sum(g.d_left_m for g in got) == pytest.approx(
        quantised("toyota", 10.0) * total_t, rel=1e-6
    )


def test_can_odometry_unknown_interface_is_a_user_error() -> None:
    """Refused with the configuration (``guidance run --check``), not when the bus opens."""
    with pytest.raises(UserError, match="no_such_interface"):
        CanOdometryConfig(interface="no_such_interface", channel="x")


def test_can_odometry_survives_a_missing_device(caplog: pytest.LogCaptureFixture) -> None:
    """socketcan on a device that does not exist: retried with backoff, logged once, no crash."""
    cfg = CanOdometryConfig(
        interface="socketcan", channel="nocan9", reconnect_initial_s=0.01, reconnect_max_s=0.02
    )
    odo = CanOdometry(cfg)
    with caplog.at_level(logging.WARNING, logger="drivers.can_odometry"):
        try:
            odo.start(lambda _: None)
        except UserError:  # python-can without socketcan support on this platform
            pytest.skip("socketcan not available here")
        time.sleep(0.3)
        t0 = time.monotonic()
        odo.stop()
        # woken, not abandoned at the reader's 5 s join timeout (a loaded machine's delays fit)
        assert time.monotonic() - t0 < 4.0
    assert odo.stats()["bus_errors"] >= 3
    assert sum("unavailable" in r.getMessage() for r in caplog.records) == 1


def test_a_lost_bus_is_logged_once_back_once_and_each_flip_reaches_the_status_sink(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The bus is missing (two failed opens), then opens but fails at its first read (three
    times: a socketcan interface that is down), then works. One warning for the loss, one for
    the return at the first frame, never one per retry; "disconnected" reaches the status sink
    at once, and once, and the return to ok after it (the reader base's ``_set_connected``)."""
    channel = f"test_{uuid.uuid4().hex}"
    cfg = CanOdometryConfig(
        interface="virtual", channel=channel, profile="toyota", clock="frame",
        reconnect_initial_s=0.01, reconnect_max_s=0.02, receive_timeout_s=0.02,
    )  # fmt: skip
    odo = CanOdometry(cfg)
    real_open = odo._open_bus
    opens = 0

    def flaky_open() -> can.BusABC:
        nonlocal opens
        opens += 1
        if opens <= 2:
            raise OSError(19, "No such device")
        bus = real_open()
        if opens <= 5:

            def down(timeout: float | None = None) -> can.Message | None:
                raise OSError(100, "Network is down")

            monkeypatch.setattr(bus, "recv", down)
        return bus

    monkeypatch.setattr(odo, "_open_bus", flaky_open)
    statuses: list[str] = []
    odo.set_status_sink(lambda h: statuses.append(h.status))
    with caplog.at_level(logging.WARNING, logger="drivers.can_odometry"):
        odo.start(lambda _: None)
        try:
            assert statuses == ["disconnected"]  # at start, not at the next health()
            deadline = time.monotonic() + 5.0
            while odo.stats().get("reconnects", 0) < 4 and time.monotonic() < deadline:
                time.sleep(0.005)
            with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx:
                for i in range(30):
                    for m in frame("toyota", 10.0 + i * 0.0125, 3.0, 3.0):
                        tx.send(m)
                while statuses[-1] != "ok" and time.monotonic() < deadline:
                    time.sleep(0.01)
        finally:
            odo.stop()
    s = odo.stats()
    assert (s["bus_errors"], s["reconnects"], s["disconnects"]) == (5, 4, 1)
    messages = [r.getMessage() for r in caplog.records]
    assert sum("unavailable" in m for m in messages) == 1, messages
    assert sum("is back" in m for m in messages) == 1, messages
    assert "CAN bus virtual/" in messages[0] and "No such device" in messages[0]
    assert statuses.count("disconnected") == 1 and "ok" in statuses, statuses
    assert statuses.index("disconnected") < statuses.index("ok")


def test_sink_errors_are_counted_and_reading_continues() -> None:
    channel = f"test_{uuid.uuid4().hex}"
    calls = []

    def bad_sink(inc: WheelOdometry) -> None:
        calls.append(inc)
        raise RuntimeError("consumer bug")

    odo = CanOdometry(
        CanOdometryConfig(interface="virtual", channel=channel, profile="toyota", clock="frame")
    )
    odo.start(bad_sink)
    try:
        with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx:
            for i in range(5):
                for m in frame("toyota", 10.0 + i * 0.0125, 3.0, 3.0):
                    tx.send(m)
            deadline = time.monotonic() + 5.0
            while odo.stats()["frames"] < 5 and time.monotonic() < deadline:
                time.sleep(0.01)
    finally:
        odo.stop()
    assert len(calls) == 4 and odo.stats()["sink_errors"] == 4
    assert calls[0].t_s == pytest.approx(10.0125)  # clock="frame": frame time as it is
    assert not [t for t in threading.enumerate() if t.name.startswith("can_odometry")]


def test_config_values_are_checked() -> None:
    with pytest.raises(UserError, match="profile"):
        CanOdometryConfig(profile="nope")
    with pytest.raises(UserError, match="clock"):
        CanOdometryConfig(clock="gps")
    with pytest.raises(UserError, match="max_gap_s"):
        CanOdometryConfig(max_gap_s=0)
    with pytest.raises(UserError, match="bitrate"):
        CanOdometryConfig(bitrate=-5)
