"""MCAP recording: round trip, mcap's own readers, crash recovery, rotation, disk full, drops."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
import tomllib
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from guidance.core.codec import to_record
from guidance.core.messages import (
    CameraFrame,
    Ellipse,
    EstimateState,
    Health,
    IntersectionScene,
    Prompt,
    Target,
    TurnCompleted,
)
from guidance.errors import UserError
from guidance.outputs.kinds import (
    DECISION,
    EXIT,
    HEALTH,
    LANDMARK,
    PROMPT,
    STATE,
    TURN,
    HealthReport,
    LandmarkReport,
    OutputContext,
)
from guidance.outputs.messages import LandmarkRejection
from guidance.recording.config import RecordingConfig
from guidance.recording.reader import Reader
from guidance.recording.topics import INPUT_TOPICS, OUTPUT_TOPICS, TOPICS
from guidance.recording.writer import Recorder

REPO = Path(__file__).resolve().parents[3]


def make_state(t_s: float, x_m: float = 0.0) -> EstimateState:
    cov = ((4.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.01))
    return EstimateState(t_s, x_m, 2.0 * x_m, 0.3, cov, Ellipse(4.0, 2.0, 0.0, 8.0), False, True)


def record_drive(rec: Recorder, n: int = 200) -> None:
    """A small drive: CAN at 100 Hz, NMEA at 10 Hz, camera at 5 Hz, state at 20 Hz."""
    rng = np.random.default_rng(1)
    for i in range(n):
        t = 10.0 + i * 0.01
        assert rec.record_can(t, 0x3E9, bytes([i % 256, 1, 2, 3, 4, 5, 6, 7]))
        if i % 10 == 0:
            rec.record_nmea(t + 0.001, b"$HCHDG,98.3,,,0.6,E*1B\r\n")
        if i % 20 == 0:
            image = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
            rec.record_camera(CameraFrame(t + 0.002, image, "front"), file_ref=f"frames/{i}.png")
        if i % 5 == 0:
            rec.send(
                STATE,
                make_state(t + 0.003, float(i)),
                OutputContext(
                    speed_mps=7.0,
                    target=Target(100.0, 50.0, "goal", None),
                    method="straight_to_goal",
                ),
            )
    for event in (
        IntersectionScene(10.5, (0.0, math.pi / 2), 15.0, ("straight", "left")),
        TurnCompleted(11.0, math.pi / 2),
    ):
        topic, body = to_record(event)
        rec.record(topic, event.t_s, body)
    rec.send(PROMPT, Prompt(10.6, "In 15 metres, turn left", 1, "turn"))
    rec.send(
        LANDMARK, LandmarkReport(10.7, rejections=[LandmarkRejection("outside_gate", 3)], gated=1)
    )
    rec.send(
        HEALTH,
        HealthReport(10.8, {"odometry": Health("odometry", "ok", True, True, 0.01, rate_hz=100.0)}),
    )


def test_round_trip_in_log_time_order_with_schemas_foxglove_reads(tmp_path: Path) -> None:
    cfg = RecordingConfig(directory=str(tmp_path), chunk_size_bytes=8192)
    with Recorder(cfg) as rec:
        record_drive(rec)
    health = rec.health()
    assert health.counters["errors"] == 0 and health.counters["dropped"] == 0
    assert (health.status, health.alive) == ("stopped", False)
    assert len(rec.files) == 1

    reader = Reader(tmp_path)
    msgs = list(reader)
    counts = Counter(m.topic for m in msgs)
    # thumbnails: at most one per thumbnail_interval_s (1 s) of the 2 s drive
    assert counts == {
        "/can": 200,
        "/nmea": 20,
        "/camera": 10,
        "/camera/thumbnail": 2,
        "/state": 40,
        "/scene": 2,
        "/prompt": 1,
        "/landmark": 1,
        "/health": 1,
        # Foxglove views (no origin configured: no LocationFix)
        "/foxglove/pose": 40,
        "/foxglove/scene": 4,  # the estimate every 0.5 s of the 2 s
        "/foxglove/log": 1,
    }
    times = [m.t_s for m in msgs]
    assert times == sorted(times)
    assert reader.recovered == [] and reader.skipped == 0

    can = next(m for m in msgs if m.topic == "/can")
    assert (
        can.t_s == 10.0 and can.data["id"] == 0x3E9 and can.data["data_hex"] == "0001020304050607"
    )
    nmea = next(m for m in msgs if m.topic == "/nmea")
    assert nmea.data["line"] == "$HCHDG,98.3,,,0.6,E*1B"
    cam = next(m for m in msgs if m.topic == "/camera")
    assert (cam.data["width_px"], cam.data["height_px"], cam.data["file_ref"]) == (
        160,
        120,
        "frames/0.png",
    )
    thumb = next(m for m in msgs if m.topic == "/camera/thumbnail")
    assert thumb.data["format"] == "jpeg" and thumb.data["timestamp"]["sec"] == 10
    assert [m.t_s for m in msgs if m.topic == "/camera/thumbnail"] == [10.002, 11.002]
    assert sum(m.data["thumbnail"] for m in msgs if m.topic == "/camera") == 2
    import base64

    assert base64.b64decode(thumb.data["data"])[:3] == b"\xff\xd8\xff"  # a JPEG
    state = next(m for m in msgs if m.topic == "/state")
    assert state.data["schema"] == "guidance.state/1" and state.data["speed_mps"] == 7.0
    assert state.t_s == 10.003  # exact float survives
    scenes = [m.data for m in msgs if m.topic == "/scene"]
    assert scenes[0]["labels"] == ["straight", "left"] and scenes[1]["kind"] == "turn"

    # mcap's own reader lists every channel with a JSON schema Foxglove can use.
    with rec.files[0].open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    channels = {ch.topic: ch for ch in summary.channels.values()}
    assert set(channels) == set(TOPICS)
    for ch in channels.values():
        schema = summary.schemas[ch.schema_id]
        assert ch.message_encoding == "json" and schema.encoding == "jsonschema"
        assert json.loads(schema.data)["title"] == schema.name
    assert summary.schemas[channels["/camera/thumbnail"].schema_id].name == (
        "foxglove.CompressedImage"
    )
    assert summary.statistics.message_count == len(msgs)
    assert reader.channels()["/state"] == "guidance.state"
    assert set(INPUT_TOPICS) | set(OUTPUT_TOPICS) <= set(reader.channels())


def test_write_order_and_topic_filter(tmp_path: Path) -> None:
    with Recorder(RecordingConfig(directory=str(tmp_path))) as rec:
        for t in (3.0, 1.0, 2.0):
            rec.record_nmea(t, f"line {t}")
        rec.record_can(0.5, 1, b"\x00")
    in_order = [m.t_s for m in Reader(tmp_path, topics=["/nmea"], log_time_order=False)]
    assert in_order == [3.0, 1.0, 2.0]
    assert [m.t_s for m in Reader(tmp_path)] == [0.5, 1.0, 2.0, 3.0]


CHILD = r"""
import sys, time
from guidance.recording.config import RecordingConfig
from guidance.recording.writer import Recorder
directory, n, flush_s = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
cfg = RecordingConfig(directory=directory, chunk_size_bytes=4096, flush_interval_s=flush_s)
rec = Recorder(cfg)
rec.start()
for i in range(n):
    rec.record_can(i * 0.001, 0x100 + i % 7, bytes(8))
while rec.health().counters["written"] < n:
    time.sleep(0.005)
time.sleep(float(sys.argv[4]))
print("ready", flush=True)
time.sleep(600)
"""


def run_and_kill(directory: Path, n: int, flush_s: float, settle_s: float) -> Path:
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(directory), str(n), str(flush_s), str(settle_s)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(10) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
    (path,) = sorted(directory.glob("*.mcap"))
    return path


def stream_messages(path: Path) -> list[Message]:
    """Messages as mcap's own stream reader sees them, up to the cut."""
    out: list[Message] = []
    with path.open("rb") as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Message):
                    out.append(record)
        except McapError:  # EndOfFile at the cut
            pass
    return out


def test_sigkill_loses_at_most_the_last_chunk(tmp_path: Path) -> None:
    n = 3000
    path = run_and_kill(tmp_path, n, flush_s=600.0, settle_s=0.0)

    with path.open("rb") as f, pytest.raises(McapError):
        make_reader(f).get_summary()  # no footer: the writer never finished

    reader = Reader(path)
    got = [m.data for m in reader]
    assert reader.recovered == [path]
    assert reader.channels()["/can"] == "guidance.can_frame"
    assert [d["t_s"] for d in got] == [i * 0.001 for i in range(len(got))]  # a clean prefix
    assert len(stream_messages(path)) == len(got)
    lost = n - len(got)
    record_bytes = len(json.dumps(got[0], separators=(",", ":"))) + 30  # payload + record header
    assert lost * record_bytes <= 4096, f"lost {lost} messages, more than one 4 KiB chunk"
    assert len(got) > n // 2


def test_sigkill_after_a_quiet_second_loses_nothing(tmp_path: Path) -> None:
    path = run_and_kill(tmp_path, 25, flush_s=0.2, settle_s=0.6)
    got = list(Reader(path))
    assert len(got) == 25 and len(stream_messages(path)) == 25


def test_rotation_by_size_with_a_total_cap(tmp_path: Path) -> None:
    # A file starts with every topic's schema (about 25 KB): the size cap is above that, so
    # each file holds messages (with 16 KiB every message opened a new file).
    cfg = RecordingConfig(
        directory=str(tmp_path),
        chunk_size_bytes=2048,
        max_file_size_bytes=48 * 1024,
        max_total_size_bytes=144 * 1024,
        compression="none",
    )
    n = 4000
    with Recorder(cfg) as rec:
        for i in range(n):
            rec.record_can(i * 0.01, i, bytes(8))
            if i % 200 == 0:
                time.sleep(0.01)  # let the queue drain
    h = rec.health().counters
    assert h["errors"] == 0 and h["dropped"] == 0
    assert len(rec.files) >= 8
    assert h["files_deleted"] == len(rec.files) - len(list(tmp_path.iterdir()))
    kept = sorted(tmp_path.glob("*.mcap"))
    assert sum(p.stat().st_size for p in kept) <= cfg.max_total_size_bytes + cfg.max_file_size_bytes
    assert kept == rec.files[-len(kept) :]  # the newest survive
    ids = [m.data["id"] for m in Reader(tmp_path)]
    assert ids == list(range(ids[0], n))  # a contiguous tail, in order across files


def test_rotation_by_time(tmp_path: Path) -> None:
    cfg = RecordingConfig(directory=str(tmp_path), max_file_duration_s=0.15)
    with Recorder(cfg) as rec:
        for i in range(8):
            rec.record_nmea(float(i), f"line {i}")
            time.sleep(0.06)
    assert len(rec.files) >= 3
    assert [m.data["line"] for m in Reader(rec.files)] == [f"line {i}" for i in range(8)]


def test_full_queue_drops_and_counts_without_blocking(tmp_path: Path) -> None:
    rec = Recorder(RecordingConfig(directory=str(tmp_path), queue_size=8))
    slow_write = rec._write

    def slow(item: object) -> None:
        time.sleep(0.01)
        slow_write(item)  # type: ignore[arg-type]

    rec._write = slow  # type: ignore[method-assign]
    rec.start()
    try:
        took = []
        accepted = 0
        for i in range(200):
            t0 = time.perf_counter()
            accepted += rec.record_can(float(i), 1, b"")
            took.append(time.perf_counter() - t0)
    finally:
        rec.close()
    h = rec.health().counters
    assert h["dropped"] == 200 - accepted and h["dropped"] > 150
    assert h["written"] == accepted
    took.sort()  # the writer takes 10 ms per message: a blocking call would wait that long
    assert took[int(0.99 * (len(took) - 1))] < 0.001 and took[-1] < 0.5


def fill_until_full(rec: Recorder, limit: int = 200_000) -> int:
    for i in range(limit):
        rec.record_can(i * 0.001, i, os.urandom(8))
        if i % 100 == 0:
            time.sleep(0.002)
        if rec.health().status == "disk_full":
            return i
    raise AssertionError("the disk never filled")


@pytest.fixture
def tiny_tmpfs(tmp_path: Path) -> Iterator[Path]:
    """A 64 KiB tmpfs (needs root and mount rights; skipped otherwise)."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root; the RLIMIT_FSIZE test covers disk full")
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_disk_full_on_a_tiny_tmpfs_stops_recording_and_flags_it(tiny_tmpfs: Path) -> None:
    cfg = RecordingConfig(directory=str(tiny_tmpfs), chunk_size_bytes=4096, compression="none")
    rec = Recorder(cfg)
    rec.start()
    try:
        fill_until_full(rec)
        assert rec.record_can(1e6, 1, b"") is False  # stopped, and says so
    finally:
        rec.close()
    h = rec.health()
    assert h.status == "disk_full" and not h.alive and not h.valid
    assert h.counters["errors"] >= 1 and h.counters["dropped"] >= 1
    assert "No space left on device" in h.detail
    got = list(Reader(tiny_tmpfs))
    assert len(got) > 100  # what reached the disk before it filled is readable


RLIMIT_CHILD = r"""
import json, resource, signal, sys, time
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # get EFBIG instead of being killed
resource.setrlimit(resource.RLIMIT_FSIZE, (50_000, 50_000))
from guidance.recording.config import RecordingConfig
from guidance.recording.writer import Recorder
rec = Recorder(RecordingConfig(directory=sys.argv[1], chunk_size_bytes=4096, compression="none"))
rec.start()
i = 0
while rec.health().status != "disk_full" and i < 100_000:
    rec.record_can(i * 0.001, i, bytes(8)); i += 1
    if i % 100 == 0:
        time.sleep(0.002)
after = rec.record_can(1e6, 1, b"")
rec.close()
print(json.dumps({**rec.health().as_dict(), "accepted_after": after, "still_running": True}))
"""


def test_file_size_limit_stops_recording_and_the_process_keeps_running(tmp_path: Path) -> None:
    r = subprocess.run(
        [sys.executable, "-c", RLIMIT_CHILD, str(tmp_path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    h = json.loads(r.stdout)
    assert h["status"] == "disk_full" and h["still_running"] and not h["accepted_after"]
    assert h["counters"]["errors"] >= 1 and "File too large" in h["detail"]
    assert "recording stopped (disk full)" in r.stderr  # logged once
    assert r.stderr.count("recording stopped") == 1
    assert len(list(Reader(tmp_path))) > 100


def test_a_malformed_message_is_an_error_and_recording_goes_on(tmp_path: Path) -> None:
    with Recorder(RecordingConfig(directory=str(tmp_path))) as rec:
        rec.send(DECISION, object())  # type: ignore[arg-type]
        rec.record("/custom", 1.0, {"bad": {1, 2}})  # a set is not JSON
        rec.record("/custom", 2.0, {"ok": True})
    h = rec.health()
    assert h.counters["errors"] == 2 and h.counters["written"] == 1
    (msg,) = list(Reader(tmp_path))
    assert msg.topic == "/custom" and msg.data == {"ok": True, "t_s": 2.0}


def test_a_restart_in_the_same_second_does_not_overwrite(tmp_path: Path) -> None:
    cfg = RecordingConfig(directory=str(tmp_path))
    for run in range(2):
        with Recorder(cfg, clock=lambda: 1_767_225_600.0) as rec:
            rec.record_nmea(float(run), f"run {run}")
    files = sorted(tmp_path.glob("*.mcap"))
    assert [p.name for p in files] == [
        "drive-20260101-000000-0001.mcap",
        "drive-20260101-000000-0002.mcap",
    ]
    assert [m.data["line"] for m in Reader(tmp_path)] == ["run 0", "run 1"]


def test_unwritable_directory_is_a_flag_not_an_exception(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    rec = Recorder(RecordingConfig(directory=str(blocker / "sub")))
    rec.start()
    assert rec.record_nmea(0.0, "x") is False
    rec.close()
    h = rec.health()
    assert h.counters["errors"] == 1 and not h.alive and h.status == "failed"


def test_recording_config_table() -> None:
    doc = tomllib.loads((REPO / "config" / "zenoh" / "telemetry.example.toml").read_text())
    cfg = RecordingConfig.from_mapping(doc["recording"], base_dir=Path("/data"))
    assert cfg.directory == "/data/recordings"
    assert cfg == RecordingConfig(directory="/data/recordings")
    with pytest.raises(UserError, match="unknown key"):
        RecordingConfig.from_mapping({"dir": "x"})
    with pytest.raises(
        UserError, match=r"\[recording\] chunk_size_bytes must be an integer, not '64k'"
    ):
        RecordingConfig.from_mapping({"chunk_size_bytes": "64k"})
    with pytest.raises(UserError, match="compression"):
        RecordingConfig(compression="gzip")


def test_reader_errors_are_user_errors(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="not found"):
        Reader(tmp_path / "nope.mcap")
    with pytest.raises(UserError, match=r"no \.mcap files"):
        Reader(tmp_path)


def test_turns_and_exits_taken_leave_the_process(tmp_path: Path) -> None:
    """Outputs the pipeline computes (turns, exits taken) are recorded on their own topics."""
    from guidance.core.messages import ExitTaken
    from guidance.core.plan.navigator import Decision
    from guidance.outputs.schemas import SCHEMAS

    decision = Decision(
        20.0, 1, math.pi / 2, math.pi / 2, (), 100.0, 0.0, "goal", None, 7, False, "goal", "cost"
    )
    with Recorder(RecordingConfig(directory=str(tmp_path))) as rec:
        assert rec.send(TURN, TurnCompleted(21.0, -math.pi / 2, "co-driver"))
        assert rec.send(EXIT, ExitTaken(21.5, decision, 2, False, "co-driver"))
    msgs = {m.topic: m.data for m in Reader(tmp_path)}
    turn, taken = msgs["/turn"], msgs["/exit"]
    assert turn["schema"] == "guidance.turn/1" and turn["heading_change_deg"] == -90.0
    assert turn["source"] == "co-driver" and turn["vehicle_id"] == "car1"
    assert (taken["advised_exit"], taken["taken_exit"], taken["followed"]) == (1, 2, False)
    assert taken["intersection_id"] == 7 and taken["decision_t_s"] == 20.0
    for kind, body in (("turn", turn), ("exit", taken)):
        props = SCHEMAS[kind]["properties"]
        assert set(body) <= set(props), set(body) - set(props)
