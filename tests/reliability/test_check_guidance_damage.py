"""Issue 40, defect 6: ``guidance check-guidance`` reports damage. Of 80 bit-flipped or cut
copies of a recording, ``replay`` flagged 57 and check-guidance none, exiting 0 for 79; a cut
file or one NaN in ``/truth`` "checked" 0 turns and passed. Now what the reader could not read
is said ("damaged recording: ...") and the check fails (exit 1): part of a drive is no pass."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from test_replay_hostile import RECORDING, _data_section, _messages, _write

from guidance.recording.reader import Reader
from guidance.tools.cli import main


def _check(path: Path) -> tuple[int, dict[str, object]]:
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = main(["check-guidance", str(path), "--json"])
    return rc, json.loads(buf.getvalue().strip().splitlines()[-1])


def test_the_clean_recording_passes() -> None:
    rc, res = _check(RECORDING)
    assert rc == 0 and res["ok"] and res["damage"] == [] and res["turns"] >= 1


@pytest.mark.parametrize("keep", [0.3, 0.6, 0.9])
def test_a_recording_cut_short_is_damage_and_no_pass(tmp_path: Path, keep: float) -> None:
    """Cut inside the data section (a cut in the summary after it loses no message)."""
    raw = RECORDING.read_bytes()
    start, end = _data_section(raw)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: start + int((end - start) * keep)])
    rc, res = _check(cut)
    assert rc == 1 and not res["ok"] and res["damage"], res


@pytest.mark.parametrize("value", ["NaN", "1" + "0" * 400])
def test_a_nan_in_the_truth_is_damage_and_no_pass(tmp_path: Path, value: str) -> None:
    """One NaN (or a 400-digit number: an internal error before) in one /truth record."""
    records = _messages()
    i = [k for k, r in enumerate(records) if r[0] == "/truth"][5]
    topic, t_ns, data = records[i]
    doc = json.dumps(json.loads(data) | {"x_m": 7.5}).replace("7.5", value)
    records[i] = (topic, t_ns, doc.encode())
    path = tmp_path / "nan.mcap"
    _write(path, records)
    rc, res = _check(path)
    assert rc == 1 and any("not a finite number" in d for d in res["damage"]), res


def test_bit_flips_are_flagged_whenever_the_reader_finds_damage(tmp_path: Path) -> None:
    """24 copies, each with 8 bytes of its data section flipped (a fixed seed): every copy in
    which the reader finds damage fails the check saying so, and the CRCs find most flips."""
    raw = RECORDING.read_bytes()
    start, end = _data_section(raw)
    rng = np.random.default_rng(40)
    flagged = damaged = 0
    for k in range(24):
        bad = bytearray(raw)
        for pos in rng.integers(start, end, 8):
            bad[pos] ^= 0x5A
        path = tmp_path / f"flip{k}.mcap"
        path.write_bytes(bytes(bad))
        r = Reader(path)
        list(r)
        found = r.damage.any or bool(r.recovered) or r.skipped > 0
        rc, res = _check(path)
        damaged += found
        if found:
            assert rc != 0 and (res["damage"] or not res["ok"]), res
            flagged += 1
    assert damaged >= 16, f"only {damaged} of 24 copies had damage the reader found"
    assert flagged == damaged
