"""SimCompassPty -> pseudo-terminal -> the real pyserial SerialCompass driver."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager

import pytest

from drivers.compass import NmeaCompassParser, SerialCompass, SerialCompassConfig
from guidance.core.messages import CompassHeading
from hal_sim.sim_compass import SimCompassPty, hdg_body, nmea_sentence


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    """Fail a test that leaves a thread running or a pty open."""
    with leak_check(grace_s=2.0, virtual_can=False):
        yield


def wait_until(cond: Callable[[], bool], timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def fast_config(port: str) -> SerialCompassConfig:
    return SerialCompassConfig(
        port=port, baudrate=4800, read_timeout_s=0.05, reconnect_initial_s=0.02, reconnect_max_s=0.1
    )


@pytest.fixture
def sim() -> Iterator[SimCompassPty]:
    with SimCompassPty() as s:
        yield s


def test_sentences_are_valid_nmea() -> None:
    # Byte for byte what a B&G chartplotter sent (gpsd test log bundg_zeus_9.log).
    line = nmea_sentence(hdg_body(229.8, deviation_deg=None, variation_deg=1.3, talker="SD"))
    assert line == b"$SDHDG,229.8,,,1.3,E*36\r\n"
    p = NmeaCompassParser()
    h = p.feed_line(nmea_sentence(hdg_body(101.1, variation_deg=-7.1)), 0.0)
    assert h is not None and h.heading_deg == pytest.approx(101.1)
    assert p.feed_line(nmea_sentence("HCHDG,1.0,,,,", corrupt_checksum=True), 0.0) is None


def test_pty_round_trip(sim: SimCompassPty) -> None:
    got: list[CompassHeading] = []
    compass = SerialCompass(fast_config(sim.port))
    compass.start(got.append)
    try:
        wait_until(lambda: compass.connected)
        t_before = time.monotonic()
        for h in (0.0, 45.5, 359.9, 181.0):
            sim.write_heading(h)
        sim.write_heading(100.0, deviation_deg=-2.5, variation_deg=12.0)
        wait_until(lambda: len(got) == 5)
        t_after = time.monotonic()
    finally:
        compass.stop()
    assert [g.heading_deg for g in got] == pytest.approx([0.0, 45.5, 359.9, 181.0, 97.5])
    assert all(not g.is_true for g in got)
    assert all(t_before <= g.t_s <= t_after for g in got)  # monotonic arrival time
    assert compass.stats()["rejected"] == 0


def test_writer_thread_runs_at_its_rate(sim: SimCompassPty) -> None:
    got: list[CompassHeading] = []
    compass = SerialCompass(fast_config(sim.port))
    compass.start(got.append)
    try:
        wait_until(lambda: compass.connected)
        sim.set_heading(270.0)
        sim.start()
        time.sleep(0.55)
        sim.stop()
        wait_until(lambda: compass.stats()["lines"] >= sim.sentences_written)
    finally:
        compass.stop()
    assert 4 <= len(got) <= 7  # 10 Hz for 0.55 s
    assert {g.heading_deg for g in got} == {270.0}


def test_garbage_bad_checksums_and_long_lines_are_counted(sim: SimCompassPty) -> None:
    got: list[CompassHeading] = []
    compass = SerialCompass(fast_config(sim.port))
    compass.start(got.append)
    try:
        wait_until(lambda: compass.connected)
        garbage = bytes(b for b in range(256) if b not in b"\r\n")
        sim.write_raw(garbage + b"\r\n")  # binary garbage, one line
        sim.write_heading(10.0, corrupt_checksum=True)
        sim.write_sentence("HCHDG,11.0,,,,", checksum=False)
        sim.write_raw(b"X" * 5000)  # a very long run with no line end...
        sim.write_raw(b"\r\n")
        half = nmea_sentence(hdg_body(12.0))
        sim.write_raw(half[:9])  # ...and a sentence split across two writes
        time.sleep(0.1)
        sim.write_raw(half[9:])
        sim.write_sentence("GPGGA,184353.07,1929.045,S,02410.506,E,1,04,2.6,100.00,M,-33.9,M,,0000")
        wait_until(lambda: compass.stats()["lines"] >= 6)
    finally:
        compass.stop()
    s = compass.stats()
    assert [g.heading_deg for g in got] == [12.0]
    assert s["rejected_not_nmea"] == 1
    assert s["rejected_checksum"] == 1
    assert s["rejected_no_checksum"] == 1
    assert s["rejected_too_long"] == 1
    assert s["rejected_unknown_type"] == 1
    assert s["lines"] == s["headings"] + s["rejected"] == 6
    assert s["read"] == 6  # the reader's one name for the units it read (app health)


def test_unplug_and_replug_reconnects_and_logs_once_each_way(
    sim: SimCompassPty, caplog: pytest.LogCaptureFixture
) -> None:
    got: list[CompassHeading] = []
    compass = SerialCompass(fast_config(sim.port))
    with caplog.at_level(logging.INFO, logger="drivers.compass"):
        compass.start(got.append)
        try:
            wait_until(lambda: compass.connected)
            sim.write_heading(1.0)
            wait_until(lambda: len(got) == 1)
            sim.unplug()
            wait_until(lambda: not compass.connected)
            time.sleep(0.4)  # several reopen attempts while the device is gone
            sim.plug()
            wait_until(lambda: compass.connected)
            sim.write_heading(2.0)
            wait_until(lambda: len(got) == 2)
        finally:
            compass.stop()
    assert [g.heading_deg for g in got] == [1.0, 2.0]
    s = compass.stats()
    assert s["disconnects"] == 1 and s["reconnects"] == 1
    messages = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert sum("unavailable" in m for m in messages) == 1
    assert sum("is back" in m for m in messages) == 1


def test_compass_started_before_the_device_appears(sim: SimCompassPty) -> None:
    sim.unplug()
    got: list[CompassHeading] = []
    compass = SerialCompass(fast_config(sim.port))
    compass.start(got.append)
    try:
        time.sleep(0.2)
        assert not compass.connected
        sim.plug()
        wait_until(lambda: compass.connected)
        sim.write_heading(33.0)
        wait_until(lambda: len(got) == 1)
    finally:
        compass.stop()
    assert got[0].heading_deg == 33.0


def test_stop_is_prompt_while_unplugged(sim: SimCompassPty) -> None:
    sim.unplug()
    cfg = SerialCompassConfig(port=sim.port, reconnect_initial_s=60.0, reconnect_max_s=60.0)
    compass = SerialCompass(cfg)
    compass.start(lambda h: None)
    time.sleep(0.1)
    t0 = time.monotonic()
    compass.stop()
    # The reader sleeps out a 60 s backoff unless stop() wakes it; the bound leaves a loaded
    # machine its scheduling delays and still tells the two apart.
    assert time.monotonic() - t0 < 10.0


def test_a_failing_sink_does_not_stop_reading(sim: SimCompassPty) -> None:
    seen: list[float] = []

    def sink(h: CompassHeading) -> None:
        seen.append(h.heading_deg)
        raise RuntimeError("consumer bug")

    compass = SerialCompass(fast_config(sim.port))
    compass.start(sink)
    try:
        wait_until(lambda: compass.connected)
        for h in (1.0, 2.0, 3.0):
            sim.write_heading(h)
        wait_until(lambda: len(seen) == 3)
    finally:
        compass.stop()
    assert compass.stats()["sink_errors"] == 3


def test_arrival_clock_can_be_the_simulation_clock(sim: SimCompassPty) -> None:
    """An accelerated simulation stamps compass lines with its own clock, like its CAN frames."""
    world_t = [500.0]
    got: list[CompassHeading] = []
    compass = SerialCompass(fast_config(sim.port), clock=lambda: world_t[0])
    compass.start(got.append)
    try:
        wait_until(lambda: compass.connected)
        sim.write_heading(90.0)
        wait_until(lambda: len(got) == 1)
    finally:
        compass.stop()
    assert got[0].t_s == 500.0
