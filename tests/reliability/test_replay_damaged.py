"""Recordings cut by SIGKILL and records the parser cannot take (issue 23, items 12 and 17):
``guidance recording repair`` writes a file the standard ``mcap`` reader opens, ``guidance
replay`` names it where it reports a damaged file, and a time of 10^400 or 100,000-deep JSON
in a recording is a counted rejection, never "internal error". Real processes killed with
SIGKILL, real MCAP files, the real CLI (``guidance.tools.cli.main``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from test_replay_hostile import RECORDING, _messages, _result, _run, _write

from guidance.recording.reader import Reader
from guidance.tools.cli import main

REPO = Path(__file__).resolve().parents[2]
DEEP = b"[" * 100_000 + b"]" * 100_000


def _killed_recording(folder: Path) -> Path:
    """A recording whose recorder (the real ``Recorder`` in its own process) got SIGKILL."""
    code = textwrap.dedent(
        f"""
        import time
        from guidance.recording.config import RecordingConfig
        from guidance.recording.writer import Recorder
        rec = Recorder(RecordingConfig(directory={str(folder)!r}, prefix="killed",
                                       flush_interval_s=0.05, chunk_size_bytes=4096))
        rec.start()
        t = 0.0
        while True:
            t += 0.01
            rec.record("/odometry", t, {{"t_s": t, "d_left_m": 0.1, "d_right_m": 0.1}})
            time.sleep(0.0005)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO)
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            files = list(folder.glob("killed-*.mcap"))
            if files and files[0].stat().st_size > 100_000:
                break
            time.sleep(0.05)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    (path,) = folder.glob("killed-*.mcap")
    return path


def _standard_count(path: Path) -> int:
    with path.open("rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def _cli(*argv: str) -> tuple[int, str, str]:
    import io
    from contextlib import redirect_stderr, redirect_stdout

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main(list(argv))
    return rc, out.getvalue(), err.getvalue()


def test_a_recording_cut_by_sigkill_is_repaired_into_one_the_standard_reader_opens(
    tmp_path: Path,
) -> None:
    src = _killed_recording(tmp_path)
    before = src.read_bytes()
    with pytest.raises((McapError, EOFError, ValueError)):  # what users of `mcap` get
        _standard_count(src)
    ours = sum(1 for _ in Reader(src, log_time_order=False))
    assert ours > 1000
    out = tmp_path / "repaired.mcap"
    rc, stdout, err = _cli("recording", "repair", str(src), str(out))
    assert rc == 0, err
    assert f"{ours} messages" in stdout and "cut short" in stdout
    assert _standard_count(out) == ours  # every complete message, readable by anyone
    with out.open("rb") as f:
        reader = make_reader(f)
        assert [m.name for m in reader.iter_metadata()] == ["recording"]
        summary = reader.get_summary()
        assert summary is not None and "/odometry" in {c.topic for c in summary.channels.values()}
    a = [(m.topic, m.data) for m in Reader(src, log_time_order=False)]
    b = [(m.topic, m.data) for m in Reader(out, log_time_order=False)]
    assert a == b  # the same messages, in the same order
    assert src.read_bytes() == before  # the original is never changed
    rc, _, err = _cli("recording", "repair", str(src), str(out))  # OUT exists: refused
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "exists" in err
    rc, _, err = _cli("recording", "repair", "/dev/zero", str(tmp_path / "z.mcap"))
    assert rc == 2 and len(err.strip().splitlines()) == 1


def test_replay_names_the_repair_where_it_reports_a_cut_short_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    raw = RECORDING.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) * 2 // 3])  # what a SIGKILL mid-drive leaves
    rc, out, err = _run(capsys, str(cut), "--json")
    assert rc in (0, 1), err
    lines = [ln for ln in err.splitlines() if "damaged recording" in ln]
    assert len(lines) == 1 and f"guidance recording repair {cut}" in lines[0], err
    damage = _result(out)["damage"]
    assert damage["truncated_files"] + damage["bad_records"] >= 1
    fixed = tmp_path / "fixed.mcap"
    assert main(["recording", "repair", str(cut), str(fixed)]) == 0  # as the line says
    assert _standard_count(fixed) > 1000


def _with(records: list[tuple[str, int, bytes]], topic: str, data: bytes, k: int = 3) -> list:
    """``records`` with the ``k``-th record on ``topic`` replaced by ``data``."""
    out, seen = [], 0
    for tp, t, d in records:
        if tp == topic:
            seen += 1
            if seen == k:
                d = data
        out.append((tp, t, d))
    return out


def _odometry_with_time(t_text: str) -> bytes:
    return b'{"t_s": ' + t_text.encode() + b', "d_left_m": 0.1, "d_right_m": 0.1}'


HOSTILE = {
    "an odometry time of 10^400 (an integer)": ("/odometry", _odometry_with_time("1" + "0" * 400)),
    "an odometry time of 1e400 (a float)": ("/odometry", _odometry_with_time("1e400")),
    "100,000-deep JSON on /odometry": ("/odometry", DEEP),
    "100,000-deep JSON inside an odometry record": (
        "/odometry",
        b'{"t_s": 1.0, "d_left_m": 0.1, "d_right_m": 0.1, "x": ' + DEEP + b"}",
    ),
    "a compass time of 10^400": ("/compass", b'{"t_s": 1' + b"0" * 400 + b', "heading_deg": 1}'),
    "100,000-deep JSON on /state": ("/state", DEEP),
    "a decision time of 10^400": ("/decision", b'{"t_s": 1' + b"0" * 400 + b"}"),
}


@pytest.mark.parametrize("name", list(HOSTILE))
def test_a_huge_time_or_deep_json_is_a_counted_rejection(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    topic, data = HOSTILE[name]
    path = tmp_path / "hostile.mcap"
    _write(path, _with(_messages(), topic, data))
    rc, out, err = _run(capsys, str(path), "--json")  # asserts: no internal error, no traceback
    assert rc in (0, 1), err
    res = _result(out)
    assert res["damaged_records"] >= 1, (res, err)
    assert "damaged records left out" in err
    assert any(w in err for w in ("not a finite number", "nested too deep", "finite")), err
    assert res["inputs"] > 100  # the rest was replayed
    json.dumps(res, allow_nan=False)  # and nothing of it reached the figures


@pytest.mark.parametrize("data", [DEEP, b'{"t_s": 1' + b"0" * 400 + b"}"])
def test_a_session_record_the_parser_cannot_take_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], data: bytes
) -> None:
    path = tmp_path / "hostile.mcap"
    _write(path, _with(_messages(), "/session", data, k=1))
    rc, _, err = _run(capsys, str(path))
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "no readable /session record" in err


def test_raw_replay_of_deep_or_huge_can_and_nmea_records_counts_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    records = _messages()
    records += [("/can", 1_000_000_000, DEEP), ("/nmea", 1_000_000_000, DEEP)]
    records += [("/can", 2_000_000_000, b'{"t_s": 1' + b"0" * 400 + b', "id": 842}')]
    path = tmp_path / "raw.mcap"
    _write(path, records)
    rc, out, err = _run(capsys, str(path), "--raw", "--json")
    assert rc in (0, 1), err
    assert _result(out)["damaged_records"] >= 3
