"""``guidance.files``: the one door (issue 40). Its strict JSON parser and its one message
format, on the cases each round's attacks used; the readers are walked in
``tests/reliability/test_file_door.py``."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from guidance import files
from guidance.errors import UserError


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ('{"a": ' + "[" * 200_000 + "]" * 200_000 + "}", "nested too deep"),
        ("[" * 65 + "]" * 65, "nested too deep (65 levels, at most 64)"),
        ('{"scale": ' + "1" * 400 + "}", "scale: a number of 400 characters"),
        ('{"t": -' + "9" * 41 + "}", "t: a number of 42 characters"),
        ('{"x": 1e999}', "x: 1e999 is not a finite number"),
        ('{"x": -1e400}', "x: -1e400 is not a finite number"),
        ('{"x": NaN}', "x: NaN is not a finite number"),
        ('{"x": Infinity}', "x: Infinity is not a finite number"),
        ("[-Infinity]", "-Infinity is not a finite number"),
        ('{"x": 1', "not JSON"),
        ("\u0661\u0662", "not JSON"),  # Arabic-Indic digits
        (b"\xff\xfe", "not UTF-8"),
    ],
)
def test_the_strict_parser_refuses_with_one_line(text: str | bytes, why: str) -> None:
    with pytest.raises(ValueError) as exc:
        files.parse_json(text)
    assert why in str(exc.value) and "\n" not in str(exc.value)


def test_the_strict_parser_takes_what_the_product_writes() -> None:
    doc = {
        "a": [1.5, -0.0, 1e308, 5e-324, 123456789012345678, True, None],
        "b": {"c": "1e999 NaN [[[[ in a string"},
        "deep": [[[[[[[[1]]]]]]]],
        "long text": "9" * 1000,  # digits in a string are no number
    }
    text = json.dumps(doc)
    assert files.parse_json(text) == doc
    assert files.parse_json(text.encode()) == doc
    nested = "[" * files.MAX_JSON_DEPTH + "]" * files.MAX_JSON_DEPTH
    assert files.parse_json(nested) == json.loads(nested)


def test_one_error_type_one_format(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    loop = tmp_path / "loop.json"
    loop.symlink_to("loop.json")
    big = tmp_path / "big.json"
    with big.open("wb") as f:
        f.truncate(files.KINDS["learned"].max_bytes + 1)
    cases = {
        tmp_path / "none.json": ("not found", "missing"),
        tmp_path: ("not a regular file (a folder)", "not_regular"),
        fifo: ("not a regular file (a FIFO)", "not_regular"),
        Path("/dev/zero"): ("not a regular file (a character device)", "not_regular"),
        loop: ("a symlink loop", "not_regular"),
        big: ("larger than 64 KiB", "too_large"),
    }
    for path, (why, code) in cases.items():
        with pytest.raises(files.FileRefused) as exc:
            files.read_json(path, "learned")
        assert str(exc.value) == f"learned parameters {path}: {why}"
        assert exc.value.code == code and isinstance(exc.value, UserError)
    bad = tmp_path / "bad.json"
    bad.write_text('{"x": NaN}')
    with pytest.raises(files.FileRefused, match=rf"^learned parameters {bad}: x: NaN is not"):
        files.read_json(bad, "learned")


def test_text_lines_are_bounded(tmp_path: Path) -> None:
    path = tmp_path / "log.nmea"
    path.write_bytes(b"a" * 100_000 + b"\nshort\n" + b"b" * 10)
    with files.opened(path, "nmea_log") as f:
        lines = list(files.text_lines(f, 64))
    assert [len(x) for x in lines] == [65, 6, 10] and lines[1] == b"short\n"
