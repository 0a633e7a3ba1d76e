"""``guidance replay`` on damaged and hostile recordings (issue 14, items 5, 6 and 13): the real
command (``guidance.tools.cli.main``) on real MCAP files, the committed recording of a simulated
drive with bytes flipped, and valid MCAP files whose contents are wrong.

Every case ends with a summary (exit 0 or 1) or one ``error:`` line (exit 2): never a traceback
or "internal error"; damaged chunks (CRC) are counted and reported and the rest replayed; a
/session record with NaN or out-of-range settings is refused naming the setting; a folder of
recordings replays each recorded session on its own.
"""

from __future__ import annotations

import json
import random
import shutil
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from mcap.writer import Writer

from guidance.recording.reader import Reader
from guidance.tools.cli import main

REPO = Path(__file__).resolve().parents[2]
RECORDING = REPO / "tests" / "data" / "replay" / "sim_seed3_landmarks.mcap"


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    rc = main(["replay", *argv])
    cap = capsys.readouterr()
    assert "internal error" not in cap.err, cap.err
    assert "Traceback" not in cap.err, cap.err
    return rc, cap.out, cap.err


def _data_section(raw: bytes) -> tuple[int, int]:
    """[start, end) of the data section: after the header record, before the summary."""
    (header_len,) = struct.unpack_from("<Q", raw, 9)
    footer = len(raw) - 8 - 29
    assert raw[footer] == 0x02
    (summary_start,) = struct.unpack_from("<Q", raw, footer + 9)
    return 8 + 9 + header_len, summary_start


def _result(out: str) -> dict[str, Any]:
    return json.loads(out.strip().splitlines()[-1])


def test_bit_flips_in_a_complete_recording_are_counted_and_the_rest_replayed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc, out, _ = _run(capsys, str(RECORDING), "--json")
    assert rc == 0
    base = _result(out)
    raw = RECORDING.read_bytes()
    start, end = _data_section(raw)
    rng = random.Random(14)
    replayed = reported = 0
    errors: list[str] = []
    for i in range(40):
        data = bytearray(raw)
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(start, end)] ^= 1 << rng.randrange(8)
        path = tmp_path / f"flip{i}.mcap"
        path.write_bytes(bytes(data))
        rc, out, err = _run(capsys, str(path), "--json")
        assert rc in (0, 1, 2), err
        if rc == 2:
            assert len(err.strip().splitlines()) == 1 and "error:" in err
            errors.append(err)
            continue
        replayed += 1
        res = _result(out)
        damaged = "damaged" in err
        reported += damaged
        same = (res["inputs"], res["decisions"], res["final"]) == (
            base["inputs"],
            base["decisions"],
            base["final"],
        )
        # Never silently changed: a replay that differs says the recording is damaged.
        assert same or damaged, (i, err, res["inputs"], base["inputs"])
        if damaged:
            assert res["damage"]["bad_chunks"] + res["damage"]["bad_records"] > 0
            assert res["inputs"] > 0  # the rest was replayed
    assert replayed >= 32, errors  # flips that destroy the /session record end in an error
    assert all("no readable /session record" in e for e in errors), errors
    assert reported >= 10  # the flips that hit chunk data are seen by the CRC


def _messages() -> list[tuple[str, int, bytes]]:
    return [
        (m.topic, round(m.t_s * 1e9), json.dumps(m.data).encode())
        for m in Reader(RECORDING, log_time_order=False)
    ]


def _write(path: Path, records: list[tuple[str, int, bytes]], encoding: str = "json") -> None:
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("anything", "jsonschema", b"{}")
        chans: dict[str, int] = {}
        for topic, t_ns, data in records:
            if topic not in chans:
                chans[topic] = w.register_channel(topic, encoding, sid)
            w.add_message(chans[topic], max(0, t_ns), data, max(0, t_ns))
        w.finish()


def _session(mutate: Callable[[dict[str, Any]], Any]) -> Callable[[list[Any]], list[Any]]:
    def f(records: list[tuple[str, int, bytes]]) -> list[tuple[str, int, bytes]]:
        out = []
        for topic, t, data in records:
            if topic == "/session":
                doc = json.loads(data)
                new = mutate(doc)
                doc = doc if new is None else new
                data = json.dumps(doc).encode()
            out.append((topic, t, data))
        return out

    return f


def _topic(name: str, fn: Callable[[dict[str, Any]], Any]) -> Callable[[list[Any]], list[Any]]:
    def f(records: list[tuple[str, int, bytes]]) -> list[tuple[str, int, bytes]]:
        return [
            (tp, t, json.dumps(fn(json.loads(d))).encode() if tp == name else d)
            for tp, t, d in records
        ]

    return f


def _est(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: d["pipeline"]["estimator"].__setitem__(key, value)


def _pipe(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: d["pipeline"].__setitem__(key, value)


CASES: dict[str, tuple[Callable[[list[Any]], list[Any]], str]] = {
    # name: (mutation, "error" to require an error naming it, else "" for a summary)
    "session a list": (_session(lambda d: [1, 2]), "no readable /session record"),
    "session a number": (_session(lambda d: 5), "no readable /session record"),
    "session without pipeline": (_session(lambda d: {"schema": 1}), "no pipeline configuration"),
    "NaN track": (
        _session(_est("track_m", float("nan"))),
        "track_m: NaN is not a finite number",
    ),
    "zero track": (_session(_est("track_m", 0)), "[pipeline.estimator] track_m must be > 0"),
    "text sigma": (_session(_est("wheel_slip_frac", "0.01")), "must be a number"),
    "unknown setting": (_session(_est("warp", 9.0)), "[pipeline.estimator] unknown key(s): warp"),
    "goal 1e400": (
        _session(_pipe("goal_xy_m", [float("inf"), 0.0])),
        "no readable /session record",
    ),
    "start text": (
        _session(_pipe("start_xy_m", ["a", 1])),
        "[pipeline] start_xy_m[0] must be a number",
    ),
    "landmarks a table": (_session(_pipe("landmarks", {"a": 1})), "landmarks must be a list"),
    "landmark without y": (
        _session(lambda d: d["pipeline"]["landmarks"][0].__delitem__("y_m")),
        "[pipeline.landmarks[0]] y_m is required",
    ),
    "huge memory": (
        _session(lambda d: d["pipeline"]["navigator"].__setitem__("max_intersections", 10**12)),
        "max_intersections must be within [1, 100000]",
    ),
    "method fly": (
        _session(lambda d: d["pipeline"]["navigator"].__setitem__("method", "fly")),
        "method",
    ),
    "units parsecs": (_session(_pipe("units", "parsecs")), "units"),
    "rates a list": (_session(_pipe("expected_rates_hz", [1])), "expected_rates_hz"),
    "no session": (lambda r: [x for x in r if x[0] != "/session"], "no readable /session"),
    "odometry text times": (_topic("/odometry", lambda d: {**d, "t_s": "soon"}), ""),
    "odometry NaN": (_topic("/odometry", lambda d: {**d, "d_left_m": float("nan")}), ""),
    "odometry a list": (_topic("/odometry", lambda d: [d]), ""),
    "states without numbers": (_topic("/state", lambda d: {"t_s": d["t_s"]}), ""),
    "decision index a list": (_topic("/decision", lambda d: {**d, "exit_index": [0]}), ""),
    "compass huge": (_topic("/compass", lambda d: {**d, "heading_deg": 1e308}), ""),
}


@pytest.mark.parametrize("name", list(CASES))
def test_valid_mcap_files_with_wrong_contents_end_in_a_summary_or_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    mutate, error = CASES[name]
    path = tmp_path / "hostile.mcap"
    _write(path, mutate(_messages()))
    rc, out, err = _run(capsys, str(path), "--json")
    if error:
        assert rc == 2 and len(err.strip().splitlines()) == 1, err
        assert "error:" in err and error in err, err
        return
    assert rc in (0, 1), err
    res = _result(out)
    assert all(
        isinstance(v, bool | None) or (isinstance(v, int | float) and abs(v) < 1e12)
        for v in res["final"].values()
    ), res["final"]  # finite: no NaN made it into the estimate
    assert "damaged records left out" in err or res["differences"]


def test_raw_replay_of_hostile_can_and_nmea_records(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    records = _messages()
    records += [
        ("/can", 1_000_000_000, json.dumps({"t_s": 1.0, "id": "x", "data_hex": "zz"}).encode()),
        ("/can", 1_100_000_000, json.dumps({"t_s": 1.1, "id": 842, "data_hex": "0g"}).encode()),
        ("/can", 1_200_000_000, json.dumps({"t_s": float("nan")}).encode()),
        ("/nmea", 1_300_000_000, json.dumps({"t_s": 1.3, "line": 7}).encode()),
    ]
    path = tmp_path / "raw.mcap"
    _write(path, records)
    rc, _, err = _run(capsys, str(path), "--raw", "--json")
    assert rc in (0, 1)
    assert "4 damaged records left out" in err


def test_a_folder_replays_each_recorded_session_on_its_own(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    for stamp in ("20260101-100000", "20260101-110000"):
        shutil.copy(RECORDING, folder / f"sim-seed3-{stamp}-0001.mcap")
    raw = bytearray(RECORDING.read_bytes())
    start, _end = _data_section(bytes(raw))
    for k in range(0, 4000, 97):  # a damaged third session: a chunk after the first fails
        raw[start + 40_000 + k] ^= 0x5A
    (folder / "sim-seed3-20260101-120000-0001.mcap").write_bytes(bytes(raw))
    rc, out, err = _run(capsys, str(folder))
    assert out.count("matches the recording exactly") == 2, out
    assert out.count("session sim-seed3-") == 3
    assert "damaged recording" in err and rc == 1
    rc, out, _ = _run(capsys, str(folder), "--json")
    sessions = _result(out)["sessions"]
    assert [s["matches_recording"] for s in sessions] == [True, True, False]
    assert sessions[2]["damage"]["bad_chunks"] >= 1 and sessions[2]["inputs"] > 0


def test_the_debug_hint_works_as_written(capsys: pytest.CaptureFixture[str]) -> None:
    """`guidance CMD --debug` is accepted (as the hint says), like `guidance --debug CMD`."""
    for argv in (["replay", "/nonexistent.mcap", "--debug"], ["--debug", "replay", "/none.mcap"]):
        assert main(argv) == 2
        assert ": not found" in capsys.readouterr().err
