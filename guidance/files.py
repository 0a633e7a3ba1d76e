"""The one door through which the product reads a file (issue 40).

Every file the car or its tools read (config, learned parameters, checkpoint, chance table,
landmark CSVs and photos, recordings, CAN and NMEA logs, truth CSVs) is opened here:

* **a regular file only**, or a character device where the kind allows one (a serial port a
  config names); a FIFO, a folder, ``/dev/zero``, a socket or a symlink loop is refused at once,
  never read (a FIFO is opened non-blocking, so opening one never waits for a writer);
* **a size limit per kind** (``KINDS``): checked on the open file's size, and again on what is
  read, so a file that grows while it is read cannot exceed it;
* **JSON through one strict parser** (``parse_json``): nesting at most ``MAX_JSON_DEPTH``,
  numbers of at most ``MAX_NUMBER_CHARS`` characters, ASCII decimal digits, finite floats
  (no ``NaN``, ``Infinity``, or ``1e999``);
* **one error type with one message format**: ``FileRefused``, ``"<what> <path>: <why>"``.

``READERS`` lists every function of the product that reads a file, with its kind: the layering
test (``tests/test_layers.py``) fails when a function calls the door without an entry, or when
product code opens a file another way; ``tests/reliability/test_file_door.py`` throws one
hostile corpus at every entry.

Only the standard library and ``guidance.errors`` are imported: ``drivers``, ``landmark_db``
and ``guidance.core`` may use this module without an import cycle.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from guidance.errors import UserError

KIB = 1 << 10
MIB = 1 << 20
GIB = 1 << 30

MAX_JSON_DEPTH = 64
"""Deepest nesting of arrays and objects: the product's JSON files nest at most 6 deep."""
MAX_NMEA_LINE_BYTES = 4 * KIB
"""Longest line of an NMEA log: a sentence is at most 82 characters, under 100 with a time
stamp before it; a longer line is cut here (``text_lines``) and the parser rejects it."""
MAX_NUMBER_CHARS = 40
"""Longest JSON number (sign, digits, point, exponent): a float's 17 significant digits and an
exponent fit in 25; a 400-digit integer is damage, not a value (it overflows a float)."""


class FileRefused(UserError):
    """A file the product will not read, and why: ``"<what> <path>: <why>"``, one line."""

    def __init__(self, what: str, path: str | Path, why: str, code: str = "content") -> None:
        super().__init__(f"{what} {path}: {why}")
        self.what = what
        self.path = str(path)
        self.why = why
        self.code = code
        """One of ``missing``, ``not_regular``, ``too_large``, ``unreadable``, ``content``."""


@dataclass(frozen=True)
class Kind:
    """A kind of file: what it is called in a message, its size limit, whether a character
    device may stand for it."""

    what: str
    max_bytes: int
    device_ok: bool = False


KINDS: dict[str, Kind] = {
    "config": Kind("config file", 1 * MIB),
    "learned": Kind("learned parameters", 64 * KIB),
    "checkpoint": Kind("checkpoint", 16 * MIB),
    "chance_table": Kind("chance table", 1 * MIB),
    "landmark_csv": Kind("landmark CSV", 16 * MIB),
    "photo": Kind("photo", 64 * MIB),
    "recording": Kind("recording", 64 * GIB),
    "can_log": Kind("CAN log", 4 * GIB),
    "nmea_log": Kind("NMEA log", 1 * GIB),
    "truth_csv": Kind("truth or track CSV", 128 * MIB),
    "odometry_csv": Kind("speed and yaw-rate CSV", 128 * MIB),
    "wav": Kind("WAV recording", 512 * MIB),
    "zenoh_passwords": Kind("zenoh password dictionary", 64 * KIB),
}
"""Size limits, each far above what the product writes of the kind and far below what would
exhaust the car's memory when read whole: a config or a chance table is a few KiB; a learned
file a few hundred bytes; a checkpoint tens of KiB; a photo a few MiB; a recording and a CAN
log are streamed (never read whole), bounded by the disk; an NMEA log is read line by line;
a zenoh password dictionary is a line per user (read only to warn of the example passwords).
(The landmark database is opened by SQLite, read-only, after ``landmark_db.store.open_db``
refuses anything but a regular file; the co-driver's lines come from a terminal, bounded by
``guidance.core.co_driver.MAX_LINE_CHARS``.)"""

READERS: dict[str, str] = {
    "guidance.app.config.load_config": "config",
    "guidance.app.checks._raw_table": "config",
    "guidance.tools.car_toml.write_card": "config",
    "guidance.app.learned_file.load_learned": "learned",
    "guidance.app.checkpoint.load_checkpoint": "checkpoint",
    "guidance.core.plan.chance.load_table": "chance_table",
    "guidance.recording.reader.recording_files": "recording",
    "guidance.recording.reader.Reader.channels": "recording",
    "guidance.recording.reader.Reader._iter_file": "recording",
    "guidance.recording.scan.scan_records": "recording",
    "guidance.recording.repair.repair": "recording",
    "drivers.can_odometry.read_can_log": "can_log",
    "drivers.candump.read_candump": "can_log",
    "drivers.compass.parse_capture": "nmea_log",
    "guidance.tools.replay.nmea_inputs": "nmea_log",
    "landmark_db.survey.read_nmea": "nmea_log",
    "guidance.tools.evaluate._read_columns": "truth_csv",
    "guidance.tools.odometry_csv.read_odometry_csv": "odometry_csv",
    "landmark_db.inputs.open_csv": "landmark_csv",
    "landmark_db.inputs.read_photo": "photo",
    "drivers.speech_grammar.read_wav_16k": "wav",
    "guidance.telemetry.example_passwords.dictionary_users": "zenoh_passwords",
}
"""Every function of the product that opens a file to read, and the kind it reads (the
functions' own names: ``module.function`` or ``module.Class.method``)."""


def kind_of(kind: str) -> Kind:
    try:
        return KINDS[kind]
    except KeyError:
        raise ValueError(f"no file kind {kind!r}") from None


def _refuse_stat(k: Kind, path: str | Path, st: os.stat_result) -> None:
    mode = st.st_mode
    if stat.S_ISREG(mode):
        if st.st_size > k.max_bytes:
            raise FileRefused(k.what, path, f"larger than {_size(k.max_bytes)}", "too_large")
        return
    if stat.S_ISCHR(mode) and k.device_ok:
        return
    raise FileRefused(k.what, path, f"not a regular file ({_type_name(mode)})", "not_regular")


def _type_name(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a file"


def _size(n: int) -> str:
    for unit, name in ((GIB, "GiB"), (MIB, "MiB"), (KIB, "KiB")):
        if n >= unit:
            return f"{n / unit:g} {name}"
    return f"{n} bytes"


def _os_refusal(k: Kind, path: str | Path, exc: OSError) -> FileRefused:
    if exc.errno == errno.ENOENT:
        return FileRefused(k.what, path, "not found", "missing")
    if exc.errno == errno.ELOOP:
        return FileRefused(k.what, path, "a symlink loop", "not_regular")
    if exc.errno in (errno.ENXIO, errno.EISDIR):
        return FileRefused(k.what, path, exc.strerror or str(exc), "not_regular")
    return FileRefused(k.what, path, exc.strerror or str(exc), "unreadable")


def check(path: str | Path, kind: str) -> Path:
    """``path`` when it is a file of ``kind`` that may be read (for a library that opens the
    file itself, such as SQLite), else ``FileRefused``. The reader must still bound what it
    reads."""
    k = kind_of(kind)
    try:
        st = os.stat(path)
    except OSError as exc:
        raise _os_refusal(k, path, exc) from None
    _refuse_stat(k, path, st)
    return Path(path)


def open_binary(path: str | Path, kind: str) -> BinaryIO:
    """The file opened for binary reading, after the checks above (the caller closes it)."""
    k = kind_of(kind)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | os.O_NOCTTY)
    except OSError as exc:
        raise _os_refusal(k, path, exc) from None
    try:
        _refuse_stat(k, path, os.fstat(fd))
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


@contextmanager
def opened(path: str | Path, kind: str) -> Iterator[BinaryIO]:
    """``with files.opened(path, kind) as f:``: ``open_binary`` with the file closed after."""
    f = open_binary(path, kind)
    try:
        yield f
    finally:
        f.close()


def read_bytes(path: str | Path, kind: str) -> bytes:
    """The whole file, at most the kind's limit (a file that grew past it is refused)."""
    k = kind_of(kind)
    with opened(path, kind) as f:
        try:
            data = f.read(k.max_bytes + 1)
        except OSError as exc:
            raise _os_refusal(k, path, exc) from None
    if len(data) > k.max_bytes:
        raise FileRefused(k.what, path, f"larger than {_size(k.max_bytes)}", "too_large")
    return data


def read_text(path: str | Path, kind: str) -> str:
    """The whole file as UTF-8 text (a byte-order mark dropped), or ``FileRefused``."""
    data = read_bytes(path, kind)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FileRefused(kind_of(kind).what, path, f"not UTF-8 text (byte {exc.start})") from None


def text_lines(f: BinaryIO, max_line_bytes: int) -> Iterator[bytes]:
    """The lines of an open file, each at most ``max_line_bytes`` (a longer one is cut there:
    the reader refuses or counts it), without reading a line of any length into memory."""
    while True:
        line = f.readline(max_line_bytes + 1)
        if not line:
            return
        if len(line) > max_line_bytes and not line.endswith(b"\n"):
            rest = line
            while rest and not rest.endswith(b"\n"):  # skip to the end of the long line
                rest = f.readline(64 * KIB)
        yield line


def read_json(path: str | Path, kind: str) -> Any:
    """The file parsed by ``parse_json``; any failure is ``FileRefused``."""
    text = read_text(path, kind)
    try:
        return parse_json(text)
    except ValueError as exc:
        raise FileRefused(kind_of(kind).what, path, str(exc)) from None


_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_SUSPECT = re.compile(rf"[-+.0-9eE]{{{MAX_NUMBER_CHARS + 1},}}|[eE][-+]?[0-9]{{3,}}")
"""Text that may hold a number too long or too large: only then are numbers checked one by one
(in Python); without it the C parser's numbers are short and finite (it takes ASCII digits
only), and a recording's messages parse at full speed."""
_ASCII_NUMBER = re.compile(r"-?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?(?:[eE][-+]?[0-9]+)?")


def json_depth(text: str) -> int:
    """The deepest nesting of arrays and objects in JSON ``text`` (brackets inside strings not
    counted)."""
    brackets = _NOT_BRACKET.sub("", _STRING.sub("", text))
    depth = deepest = 0
    for c in brackets:
        if c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        else:
            depth -= 1
    return deepest


def _number(text: str) -> str:
    if len(text) > MAX_NUMBER_CHARS:
        raise ValueError(
            f"a number of {len(text)} characters is not a finite number (at most "
            f"{MAX_NUMBER_CHARS} characters)"
        )
    if not _ASCII_NUMBER.fullmatch(text):
        raise ValueError(f"{text[:20]!r} is not a plain decimal number")
    return text


def _int(text: str) -> int:
    return int(_number(text))


def _float(text: str) -> float:
    value = float(_number(text))
    if not math.isfinite(value):
        raise ValueError(f"{text[:20]} is not a finite number")
    return value


def _constant(name: str) -> Any:
    raise ValueError(f"{name} is not a finite number")


def parse_json(data: str | bytes) -> Any:
    """JSON, strictly: ``ValueError`` with one line for text that is not JSON, nests deeper
    than ``MAX_JSON_DEPTH``, holds a number longer than ``MAX_NUMBER_CHARS``, a non-ASCII digit,
    ``NaN``, ``Infinity`` or a float that overflows."""
    if isinstance(data, bytes | bytearray):
        try:
            data = bytes(data).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"not UTF-8 text (byte {exc.start})") from None
    if data.count("[") + data.count("{") > MAX_JSON_DEPTH:  # cheap for the usual small document
        depth = json_depth(data)
        if depth > MAX_JSON_DEPTH:
            raise ValueError(f"JSON nested too deep ({depth} levels, at most {MAX_JSON_DEPTH})")
    precise = _SUSPECT.search(data) is not None  # else the C parser's numbers are all fine
    try:
        if precise:
            return json.loads(data, parse_int=_int, parse_float=_float, parse_constant=_constant)
        return json.loads(data, parse_constant=_constant)
    except RecursionError:
        raise ValueError("JSON nested too deep") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"not JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except ValueError as exc:  # a number refused by a hook above: say whose
        key = _key_of_bad_number(data)
        raise ValueError(f"{key}: {exc}" if key else str(exc)) from None


_BAD_NUMBER = re.compile(
    r'"([^"\\]{1,60})"\s*:\s*(?:'
    rf"[-+.0-9eE]{{{MAX_NUMBER_CHARS + 1},}}|-?[0-9.]+[eE][-+]?[0-9]{{3,}}|-?Infinity|NaN)"
)


def _key_of_bad_number(text: str) -> str:
    """The key of the first number the strict parser refuses (for the message), or ""."""
    m = _BAD_NUMBER.search(text)
    return m.group(1) if m else ""
