"""``guidance evaluate`` on hostile inputs (issue 23, item 11): extreme values never print NaN or
Infinity (nor a 300-digit number), ``/dev/zero`` and oversized files are refused with one line
in bounded time and memory, and messages show plain numbers. Real files, the real CLI."""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
import textwrap
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

from guidance.tools.cli import main
from guidance.tools.evaluate import MAX_INPUT_BYTES, TRACK_COLUMNS

REPO = Path(__file__).resolve().parents[3]
T0 = 1.5e9
N = 41


def _run(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(["evaluate", *args])
    return code, out.getvalue(), err.getvalue()


def _csv(path: Path, header: tuple[str, ...], rows: list[tuple[object, ...]]) -> str:
    path.write_text("\n".join([",".join(header), *(",".join(map(str, r)) for r in rows)]) + "\n")
    return str(path)


def _truth(path: Path, east: float | None = None) -> str:
    rows = [(T0 + 0.5 * i, 5.0 * i if east is None else east * (-1) ** i, 0.0, 90.0)
            for i in range(N)]  # fmt: skip
    return _csv(path, ("t", "east_m", "north_m", "heading_deg"), rows)


TRACKS = {
    "an east of 1e308 at the end": lambda i: (
        5.0 * i + (1e308 if i == N - 1 else 1.0),
        0,
        1,
        0,
        1,
        4,
    ),
    "everything 1e308": lambda i: (1e308 * (-1) ** i, 1e308, 1e308, 0, 1e308, 1e308),
    "a variance of 1e-320": lambda i: (5.0 * i + 1, 1, 1e-320, 0, 1e-320, 1e-300),
    "variances of 1e-160": lambda i: (5.0 * i + 1, 1, 1e-160, 0, 1e-160, 1e-300),
    "a north of 1e154": lambda i: (5.0 * i + 1, 1e154, 1, 0, 1, 4),
    "a covariance of 1e308": lambda i: (5.0 * i + 1e308, 1e308, 1e308, 1e308, 1e308, 1e308),
}
# columns after t_s: east, north, var_e, cov, var_n, major (heading 90)


def _track(path: Path, name: str) -> str:
    rows = []
    for i in range(N):
        e, n, ve, c, vn, major = TRACKS[name](i)
        rows.append((T0 + 0.5 * i, e, n, 90.0, ve, c, vn, major))
    return _csv(path, TRACK_COLUMNS, rows)


_NONFINITE = re.compile(r"\b(nan|inf|infinity)\b", re.I)
_LONG_NUMBER = re.compile(r"\d{25,}")


@pytest.mark.parametrize("truth_kind", ["straight", "east of +-1e308"])
@pytest.mark.parametrize("name", list(TRACKS))
def test_extreme_values_never_print_nan_infinity_or_a_300_digit_number(
    tmp_path: Path, name: str, truth_kind: str
) -> None:
    track = _track(tmp_path / "track.csv", name)
    truth = _truth(tmp_path / "truth.csv", None if truth_kind == "straight" else 1e308)
    code, out, err = _run("--track", track, "--truth", truth, "--json")
    assert "Traceback" not in err and "internal error" not in err, err
    if code == 2:  # refused: one line
        assert len(err.strip().splitlines()) == 1
        return
    assert code == 0 and not err, err  # no RuntimeWarning either
    doc = json.loads(out.splitlines()[-1], parse_constant=pytest.fail)
    assert isinstance(doc["steps"], int)
    assert not _NONFINITE.search(out), out
    assert not _LONG_NUMBER.search(out), out


def test_messages_show_plain_numbers(tmp_path: Path) -> None:
    rows = [(T0 + 0.5 * i if i != 5 else 100.0, 5.0 * i, 0, 90, 1, 0, 1, 4) for i in range(N)]
    track = _csv(tmp_path / "track.csv", TRACK_COLUMNS, rows)
    code, _, err = _run("--track", track, "--truth", _truth(tmp_path / "truth.csv"))
    assert code == 2 and "np.float64" not in err and "float64" not in err
    assert "time 100.000 goes back after 1500000002.000" in err
    far = [(T0 * 1e298 + i, 5.0 * i, 0, 90, 1, 0, 1, 4) for i in range(N)]
    track = _csv(tmp_path / "far.csv", TRACK_COLUMNS, far)
    code, _, err = _run("--track", track, "--truth", _truth(tmp_path / "truth.csv"))
    assert code == 2 and "1.5e+307" in err and not _LONG_NUMBER.search(err), err


def test_dev_zero_and_a_file_without_line_breaks_are_refused_in_bounded_memory(
    tmp_path: Path,
) -> None:
    truth = _truth(tmp_path / "truth.csv")
    track = _track(tmp_path / "track.csv", "a north of 1e154")
    one_line = tmp_path / "one-line.csv"
    one_line.write_bytes(b"t_s" + b"x" * (8 << 20))  # 8 MiB and no line break
    code = textwrap.dedent(
        f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (1 << 31, 1 << 31))
        from guidance.tools.cli import main
        for track, truth in (("/dev/zero", {truth!r}), ({track!r}, "/dev/zero"),
                             ({str(one_line)!r}, {truth!r})):
            assert main(["evaluate", "--track", track, "--truth", truth]) == 2
        """
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr[-2000:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 3, lines  # /dev/zero: refused by the file door before a byte is read
    assert all("/dev/zero: not a regular file" in ln for ln in lines[:2]), lines
    assert "longer than 4,096 characters" in lines[2], lines


def test_a_file_over_the_stated_size_is_refused_before_it_is_read(tmp_path: Path) -> None:
    big = tmp_path / "big.csv"
    with big.open("wb") as f:  # sparse: no disk, no time
        f.write(",".join(TRACK_COLUMNS).encode() + b"\n")
        f.truncate(MAX_INPUT_BYTES + 1)
    code, _, err = _run("--track", str(big), "--truth", _truth(tmp_path / "t.csv"))
    assert code == 2 and f"larger than {MAX_INPUT_BYTES >> 20} MiB" in err
    assert os.path.getsize(big) == MAX_INPUT_BYTES + 1
