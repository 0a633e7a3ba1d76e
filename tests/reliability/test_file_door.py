"""Issue 40: one hostile corpus thrown at every reader of ``guidance.files.READERS``.

Each reader is called the way the product calls it, on each case of one corpus: a FIFO (with
no writer: a blocking open would wait for ever), a folder, ``/dev/zero``, a symlink loop, a
sparse file one byte over the kind's limit, JSON nested 200,000 deep, a 400-digit number, a
NaN, the reader's own valid file cut in half, and a JSON array where an object is expected.

* The file-type cases (FIFO, folder, ``/dev/zero``, loop, huge) are refused by every reader,
  at once, with one line naming the file: ``<what> <path>: <why>`` (``guidance.files``).
* The content cases are refused by every JSON reader (learned parameters, checkpoint, chance
  table); the other readers refuse them or read them as what they are (a CSV or a log line
  that is no record is counted), never with another exception.
* Every reader accepts its own valid file (so a reader that refuses everything fails here).

``test_layers.py::test_every_file_is_read_through_the_door_and_every_reader_is_in_the_table``
makes sure the table lists every reader; this test makes sure every entry has an adapter.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from guidance import files
from guidance.errors import UserError

REPO = Path(__file__).resolve().parents[2]
RECORDING = REPO / "tests" / "data" / "replay" / "sim_seed3_landmarks.mcap"
CAN_LOG = REPO / "tests" / "data" / "can" / "rav4_2020-02-03_bus0_wheelspeeds.log"
NMEA_LOG = REPO / "tests" / "data" / "nmea" / "hemi_head.log"
GPS_LOG = REPO / "tests" / "data" / "nmea" / "rst39.log"
TAHOE = REPO / "config" / "tahoe.toml"
ZENOH_PASSWORDS = REPO / "config" / "zenoh" / "passwords.example.txt"
CHANCE = REPO / "guidance" / "core" / "plan" / "chance_table.json"
TIMEOUT_S = 60.0
"""A reader that has not answered in this long hangs (each answers in well under a second)."""

TYPE_CASES = ("fifo", "folder", "dev_zero", "symlink_loop", "huge")
CONTENT_CASES = ("deep", "digits_400", "nan", "truncated", "wrong_type")
JSON_KINDS = {"learned", "checkpoint", "chance_table"}


class Refused(Exception):
    """A reader's refusal that is not an exception (a returned line, a logged warning)."""


def _learned_sample() -> bytes:
    import json

    from guidance.core.localize.learned import LearnedParams

    p = LearnedParams("car1", 1000.0, 2500.0, -0.011, 0.003, 0.0002, 0.0001, 38.0, 3.0)
    return json.dumps(p.to_dict()).encode()


def _checkpoint_sample() -> bytes:
    from guidance.app.checkpoint import SCHEMA

    return b'{"schema": "%s", "finished": false, "pipeline": {"t_s": 1.5}}' % SCHEMA.encode()


def _photo_sample() -> bytes:
    rng = np.random.default_rng(3)
    ok, data = cv2.imencode(".png", rng.integers(0, 255, (64, 64, 3), dtype=np.uint8))
    assert ok
    return bytes(data)


def _truth_sample() -> bytes:
    rows = "".join(f"{t},{t * 10.0},{t * 0.5}\n" for t in range(20))
    return ("t,east_m,north_m\n" + rows).encode()


# -- adapters: how the product calls each reader --------------------------------------------------
def _load_config(path: Path) -> object:
    from guidance.app.config import load_config

    return load_config(path, require_goal=False)


def _raw_table(path: Path) -> object:
    from guidance.app.checks import _raw_table

    if _raw_table(path, "compass") is None:
        raise Refused("no [compass] table read")
    return True


def _write_card(path: Path) -> object:
    from guidance.tools.car_toml import write_card

    return write_card(path, [0.5, 0.1, -0.2, 0.3, 0.0])


def _load_learned(path: Path) -> object:
    from guidance.app.learned_file import load_learned

    params, why = load_learned(path, "car1")
    if params is None:
        raise Refused(why or "no file")
    return params


def _load_checkpoint(path: Path) -> object:
    from guidance.app import checkpoint

    lines: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda r: lines.append(r.getMessage())  # type: ignore[method-assign]
    checkpoint.log.addHandler(handler)
    try:
        doc = checkpoint.load_checkpoint(path)
    finally:
        checkpoint.log.removeHandler(handler)
    if doc is None:
        raise Refused(" ".join(lines) or "no checkpoint")
    return doc


def _load_table(path: Path) -> object:
    from guidance.core.plan.chance import load_table

    return load_table(path)


def _valid_reader(path: Path) -> object:
    from guidance.recording.reader import Reader

    reader = Reader(RECORDING)
    reader.files = [path]  # past recording_files' check: the method's own open is tested
    return reader


def _recording_files(path: Path) -> object:
    from guidance.recording.reader import recording_files

    return recording_files(path)


def _channels(path: Path) -> object:
    return _valid_reader(path).channels()  # type: ignore[attr-defined]


def _iter_file(path: Path) -> object:
    return list(_valid_reader(path))  # type: ignore[call-overload]


def _scan_records(path: Path) -> object:
    from guidance.recording.scan import Damage, scan_records

    return list(scan_records(path, Damage()))


def _repair(path: Path) -> object:
    from guidance.recording.repair import repair

    return repair(path, path.parent / f"repaired-{path.name}")


def _read_can_log(path: Path) -> object:
    from drivers.can_odometry import LogReadResult, read_can_log

    return list(read_can_log(path, LogReadResult()))


def _read_candump(path: Path) -> object:
    from drivers.can_odometry import LogReadResult
    from drivers.candump import read_candump

    return list(read_candump(path, False, LogReadResult()))


def _parse_capture(path: Path) -> object:
    from drivers.compass import parse_capture

    return parse_capture(path)


def _nmea_inputs(path: Path) -> object:
    from guidance.tools.replay import nmea_inputs

    return list(nmea_inputs(path, 0.0, 10.0))


def _survey_nmea(path: Path) -> object:
    from landmark_db.survey import read_nmea

    return read_nmea(path)


def _odometry_sample() -> bytes:
    rows = "".join(f"{1500000000 + 0.2 * t:.1f},{5.0 + t * 0.1},{0.01 * t}\n" for t in range(20))
    return ("t,speed_mps,yaw_rate_rad_s\n" + rows).encode()


def _read_odometry_csv(path: Path) -> object:
    from guidance.tools.odometry_csv import read_odometry_csv

    return read_odometry_csv(path)


def _read_columns(path: Path) -> object:
    from guidance.tools.evaluate import read_truth

    return read_truth(path)


def _open_csv(path: Path) -> object:
    from landmark_db.inputs import read_csv_rows

    return read_csv_rows(path)


def _read_photo(path: Path) -> object:
    from landmark_db.inputs import read_photo

    return read_photo(path)


def _wav_sample() -> bytes:
    import io
    import wave

    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(16000)
        w.writeframes(b"\x10\x00\xf0\xff" * 4000)
    return buf.getvalue()


def _read_wav(path: Path) -> object:
    from drivers.speech_grammar import read_wav_16k

    return read_wav_16k(path)


def _dictionary_users(path: Path) -> object:
    from guidance.telemetry.example_passwords import dictionary_users

    return dictionary_users(path)


@dataclass(frozen=True)
class Adapter:
    call: Callable[[Path], object]
    sample: Callable[[], bytes]
    suffix: str = ""
    quiet: bool = False
    """Refuses without a line of its own (``checks._raw_table``: ``load_config`` has read the
    same file first and said why)."""
    own_format: bool = False
    """Says why in its own words, naming the file (``write_card``: "cannot write the card into
    PATH: not a regular file; the file is unchanged")."""
    takes_folder: bool = False
    """A folder is a valid input (``recording_files``: a folder of rotated files)."""


def _bytes_of(path: Path) -> Callable[[], bytes]:
    return path.read_bytes


ADAPTERS: dict[str, Adapter] = {
    "guidance.app.config.load_config": Adapter(_load_config, _bytes_of(TAHOE), ".toml"),
    "guidance.app.checks._raw_table": Adapter(_raw_table, _bytes_of(TAHOE), ".toml", quiet=True),
    "guidance.tools.car_toml.write_card": Adapter(
        _write_card, _bytes_of(TAHOE), ".toml", own_format=True
    ),
    "guidance.app.learned_file.load_learned": Adapter(_load_learned, _learned_sample, ".json"),
    "guidance.app.checkpoint.load_checkpoint": Adapter(_load_checkpoint, _checkpoint_sample),
    "guidance.core.plan.chance.load_table": Adapter(_load_table, _bytes_of(CHANCE), ".json"),
    "guidance.recording.reader.recording_files": Adapter(
        _recording_files, _bytes_of(RECORDING), ".mcap", takes_folder=True
    ),
    "guidance.recording.reader.Reader.channels": Adapter(
        _channels, _bytes_of(RECORDING), ".mcap"
    ),
    "guidance.recording.reader.Reader._iter_file": Adapter(
        _iter_file, _bytes_of(RECORDING), ".mcap"
    ),
    "guidance.recording.scan.scan_records": Adapter(_scan_records, _bytes_of(RECORDING), ".mcap"),
    "guidance.recording.repair.repair": Adapter(_repair, _bytes_of(RECORDING), ".mcap"),
    "drivers.can_odometry.read_can_log": Adapter(_read_can_log, _bytes_of(CAN_LOG), ".log"),
    "drivers.candump.read_candump": Adapter(_read_candump, _bytes_of(CAN_LOG), ".log"),
    "drivers.compass.parse_capture": Adapter(_parse_capture, _bytes_of(NMEA_LOG), ".log"),
    "guidance.tools.replay.nmea_inputs": Adapter(_nmea_inputs, _bytes_of(NMEA_LOG), ".log"),
    "landmark_db.survey.read_nmea": Adapter(_survey_nmea, _bytes_of(GPS_LOG), ".log"),
    "guidance.tools.evaluate._read_columns": Adapter(_read_columns, _truth_sample, ".csv"),
    "guidance.tools.odometry_csv.read_odometry_csv": Adapter(
        _read_odometry_csv, _odometry_sample, ".csv"
    ),
    "landmark_db.inputs.open_csv": Adapter(_open_csv, _truth_sample, ".csv"),
    "landmark_db.inputs.read_photo": Adapter(_read_photo, _photo_sample, ".png"),
    "drivers.speech_grammar.read_wav_16k": Adapter(_read_wav, _wav_sample, ".wav"),
    "guidance.telemetry.example_passwords.dictionary_users": Adapter(
        _dictionary_users, _bytes_of(ZENOH_PASSWORDS), ".txt"
    ),
}


def _make(case: str, folder: Path, adapter: Adapter, kind: str) -> Path:
    """The corpus file for ``case``, named with the reader's suffix."""
    path = folder / f"{case}{adapter.suffix}"
    if case == "fifo":
        os.mkfifo(path)
    elif case == "folder":
        path.mkdir()
    elif case == "dev_zero":
        path.symlink_to("/dev/zero")
    elif case == "symlink_loop":
        other = folder / f"{case}-other{adapter.suffix}"
        path.symlink_to(other.name)
        other.symlink_to(path.name)
    elif case == "huge":  # sparse: no disk used, the size alone must refuse it
        with path.open("wb") as f:
            f.truncate(files.KINDS[kind].max_bytes + 1)
    elif case == "deep":
        path.write_bytes(b'{"a": ' + b"[" * 200_000 + b"]" * 200_000 + b"}")
    elif case == "digits_400":
        path.write_bytes(b'{"schema": ' + b"9" * 400 + b"}")
    elif case == "nan":
        path.write_bytes(b'{"schema": NaN, "x": Infinity}')
    elif case == "truncated":
        data = adapter.sample()
        path.write_bytes(data[: len(data) // 2])
    elif case == "wrong_type":
        path.write_bytes(b"[1, 2, 3]")
    else:
        raise AssertionError(case)
    return path


def _outcome(adapter: Adapter, path: Path) -> tuple[str, str]:
    """("accepted", "") or ("refused", the line), run on a thread so a hang is seen."""
    got: list[tuple[str, str]] = []

    def run() -> None:
        try:
            adapter.call(path)
            got.append(("accepted", ""))
        except (UserError, Refused, ValueError) as exc:  # ChanceTableError is a ValueError
            got.append(("refused", str(exc)))
        except BaseException as exc:
            got.append(("crashed", f"{type(exc).__name__}: {exc}"[:200]))

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(TIMEOUT_S)
    if t.is_alive():
        return ("hung", f"no answer in {TIMEOUT_S:.0f} s")
    return got[0]


def _says(adapter: Adapter, case: str, what: str, path: Path, text: str) -> bool:
    """Whether a refusal's line is in the one format, "<what> <path>..." (or the reader's own
    words naming the file, where it has them)."""
    if adapter.quiet:
        return True
    if adapter.own_format or (adapter.takes_folder and case == "folder"):
        return str(path) in text
    return f"{what} {path}" in text


def test_every_reader_in_the_table_has_an_adapter() -> None:
    assert set(ADAPTERS) == set(files.READERS)


@pytest.mark.parametrize("reader", sorted(files.READERS))
def test_the_hostile_corpus_against_every_reader(reader: str, tmp_path: Path) -> None:
    adapter, kind = ADAPTERS[reader], files.READERS[reader]
    what = files.KINDS[kind].what
    valid = tmp_path / f"valid{adapter.suffix}"
    valid.write_bytes(adapter.sample())
    assert _outcome(adapter, valid) == ("accepted", ""), f"{reader} refuses its own valid file"
    problems = []
    for case in (*TYPE_CASES, *CONTENT_CASES):
        folder = tmp_path / case
        folder.mkdir()
        path = _make(case, folder, adapter, kind)
        result, text = _outcome(adapter, path)
        if result in ("hung", "crashed"):
            problems.append(f"{case}: {result}: {text}")
        elif case in TYPE_CASES and result != "refused":
            problems.append(f"{case}: accepted")
        elif case in TYPE_CASES and not _says(adapter, case, what, path, text):
            problems.append(f"{case}: the line does not say '{what} {path}: ...': {text!r}")
        elif kind in JSON_KINDS and case in CONTENT_CASES and result != "refused":
            problems.append(f"{case}: accepted")
        elif result == "refused" and "\n" in text:
            problems.append(f"{case}: more than one line: {text!r}")
    assert not problems, f"{reader} ({kind}):\n" + "\n".join(problems)
