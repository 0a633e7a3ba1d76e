"""guidance.tools.evaluate: track-vs-truth errors (real evo) and consistency figures."""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from guidance.errors import UserError
from guidance.tools.evaluate import (
    TRACK_COLUMNS,
    Evaluation,
    Track,
    Truth,
    evaluate,
    format_report,
    read_track,
    read_truth,
    register,
    run,
)

T0 = 1_500_000_000.0  # Unix-like time base, as in the real truth files
REALDRIVES = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "realdrives"


def write_csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[object]]) -> Path:
    lines = [",".join(header)] + [",".join(str(v) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def circle_truth(n: int = 1201, rate_hz: float = 20.0, radius_m: float = 100.0) -> Truth:
    """Clockwise circle starting north-bound at the origin (heading = tangent)."""
    t = T0 + np.arange(n) / rate_hz
    phi = (t - T0) * 0.1  # rad along the circle, 10 m/s at 100 m
    east = radius_m * (1.0 - np.cos(phi))
    north = radius_m * np.sin(phi)
    heading = np.degrees(phi) % 360.0
    return Truth(t, east, north, heading)


def make_track(
    truth: Truth,
    offset: tuple[float, float],
    cov: tuple[float, float, float] | Sequence[tuple[float, float, float]],
    heading_offset_deg: float = 0.0,
) -> Track:
    """The truth moved by ``offset`` (estimate - truth), with covariance (var_e, cov, var_n)."""
    n = truth.t_s.size
    c = np.broadcast_to(np.asarray(cov, dtype=float), (n, 3))
    lam = 0.5 * (c[:, 0] + c[:, 2]) + np.hypot(0.5 * (c[:, 0] - c[:, 2]), c[:, 1])
    assert truth.heading_deg is not None
    return Track(
        t_s=truth.t_s.copy(),
        east_m=truth.east_m + offset[0],
        north_m=truth.north_m + offset[1],
        heading_deg=(truth.heading_deg + heading_offset_deg) % 360.0,
        var_east_m2=c[:, 0].copy(),
        cov_east_north_m2=c[:, 1].copy(),
        var_north_m2=c[:, 2].copy(),
        major_axis_m=2.0 * np.sqrt(4.0 * lam),
    )


def line_truth(n: int = 41) -> Truth:
    """East-bound at 10 m/s, sampled at 2 Hz; integer coordinates keep error arithmetic exact."""
    k = np.arange(n, dtype=float)
    return Truth(T0 + 0.5 * k, 5.0 * k, np.zeros(n), np.full(n, 90.0))


def write_track(path: Path, track: Track) -> Path:
    cols = [getattr(track, c) for c in TRACK_COLUMNS]
    return write_csv(path, TRACK_COLUMNS, list(zip(*cols, strict=True)))


def polyline_length(truth: Truth) -> float:
    return float(np.sum(np.hypot(np.diff(truth.east_m), np.diff(truth.north_m))))


def test_known_offset_and_covariance() -> None:
    truth = circle_truth()
    # Error 5 m; sigma 5 m on three steps of four (NEES 1, inside, semi-major 10 m, ratio 2)
    # and sigma 1 m on the fourth (NEES 25, outside, ratio 0.4).
    cov = [(1.0, 0.0, 1.0) if i % 4 == 0 else (25.0, 0.0, 25.0) for i in range(1200)]
    cov.append((25.0, 0.0, 25.0))
    ev = evaluate(make_track(truth, (3.0, -4.0), cov, heading_offset_deg=-2.0), truth)
    assert ev.steps == 1201 and ev.excluded_steps == 0
    assert ev.duration_s == pytest.approx(60.0)
    assert ev.path_m == pytest.approx(polyline_length(truth), rel=1e-9)
    assert ev.path_m == pytest.approx(600.0, rel=1e-3)  # 60 s at 10 m/s
    for v in (ev.ape_rmse_m, ev.ape_mean_m, ev.ape_median_m, ev.ape_min_m, ev.ape_max_m):
        assert v == pytest.approx(5.0)
    assert ev.ape_std_m == pytest.approx(0.0, abs=1e-9)
    assert ev.final_error_m == pytest.approx(5.0)
    assert ev.final_error_pct == pytest.approx(100 * 5.0 / ev.path_m)
    assert ev.nees_steps == 1201
    assert ev.inside_2sigma_frac == pytest.approx(901 / 1201)
    assert ev.mean_nees == pytest.approx((901 * 1.0 + 300 * 25.0) / 1201)
    assert ev.median_axis_ratio == pytest.approx(2.0)
    assert ev.heading_mean_abs_err_deg == pytest.approx(2.0)
    assert ev.heading_final_err_deg == pytest.approx(-2.0)


@pytest.mark.parametrize(
    ("offset", "cov", "nees"),
    [
        ((2.0, 0.0), (4.0, 0.0, 1.0), 1.0),
        ((0.0, 2.0), (4.0, 0.0, 1.0), 4.0),  # on the 2-sigma boundary: counts as inside
        ((1.0, 1.0), (2.0, 1.0, 2.0), 2.0 / 3.0),  # correlated: the off-diagonal term matters
        ((1.0, -1.0), (2.0, 1.0, 2.0), 2.0),
        ((0.0, 2.1), (4.0, 0.0, 1.0), 4.41),
    ],
)
def test_nees_uses_the_full_covariance(
    offset: tuple[float, float], cov: tuple[float, float, float], nees: float
) -> None:
    truth = line_truth()
    ev = evaluate(make_track(truth, offset, cov), truth)
    assert ev.mean_nees == pytest.approx(nees)
    assert ev.inside_2sigma_frac == (1.0 if nees <= 4.0 else 0.0)


def test_singular_covariance_left_out_of_nees() -> None:
    truth = circle_truth(n=11)
    cov = [(0.0, 0.0, 0.0)] * 3 + [(1.0, 0.0, 1.0)] * 8
    ev = evaluate(make_track(truth, (1.0, 0.0), cov), truth)
    assert ev.nees_steps == 8 and ev.mean_nees == pytest.approx(1.0)
    truth_only = evaluate(make_track(truth, (1.0, 0.0), (0.0, 0.0, 0.0)), truth)
    assert truth_only.nees_steps == 0 and truth_only.mean_nees is None
    assert "mean_nees" not in truth_only.as_dict()
    assert "n/a" in format_report(truth_only)


def test_time_interpolation_and_excluded_rows() -> None:
    # Truth at 1 Hz, straight east at 10 m/s; heading crosses north (350 -> 10 deg per second).
    t = T0 + np.arange(6.0)
    truth = Truth(t, 10.0 * (t - T0), np.zeros(6), np.array([330, 350, 10, 30, 50, 70.0]))
    tq = T0 + np.array([-1.0, 0.5, 1.5, 2.25, 5.0, 6.5])  # first and last outside the span
    ref_e = 10.0 * (tq - T0)
    track = Track(
        t_s=tq,
        east_m=ref_e + np.array([9, 0.0, 3.0, 0.0, 4.0, 9]),
        north_m=np.zeros(6),
        heading_deg=np.array([0, 340.0, 359.0, 15.0, 72.0, 0]),
        var_east_m2=np.ones(6),
        cov_east_north_m2=np.zeros(6),
        var_north_m2=np.ones(6),
        major_axis_m=np.full(6, 4.0),
    )
    ev = evaluate(track, truth)
    assert ev.steps == 4 and ev.excluded_steps == 2
    assert ev.t_start_s == pytest.approx(T0 + 0.5) and ev.duration_s == pytest.approx(4.5)
    assert ev.path_m == pytest.approx(45.0)
    assert ev.ape_max_m == pytest.approx(4.0) and ev.ape_min_m == pytest.approx(0.0)
    assert ev.ape_mean_m == pytest.approx(7.0 / 4)
    assert ev.ape_rmse_m == pytest.approx(math.sqrt(25.0 / 4))
    assert ev.final_error_m == pytest.approx(4.0)
    # Truth headings at the track times: 340, 0 (on the circle, not 180), 15, 70.
    assert ev.heading_mean_abs_err_deg == pytest.approx((0 + 1 + 0 + 2) / 4)
    assert ev.heading_final_err_deg == pytest.approx(2.0)
    # Axis ratio: semi-major 2 m over errors 3 and 4 (zero errors skipped).
    assert ev.median_axis_ratio == pytest.approx((2 / 3 + 2 / 4) / 2)


def test_fewer_than_two_rows_inside_the_truth_span() -> None:
    truth = circle_truth(n=21)
    track = make_track(truth, (0.0, 0.0), (1.0, 0.0, 1.0))
    late = dataclasses.replace(track, t_s=track.t_s + 0.97)  # only the first row inside
    with pytest.raises(UserError, match=r"only 1 of the 21 track rows .* same time base"):
        evaluate(late, truth)


def test_without_truth_heading(tmp_path: Path) -> None:
    truth = circle_truth(n=21)
    write_csv(
        tmp_path / "truth.csv",
        ["t", "east_m", "north_m"],
        list(zip(truth.t_s, truth.east_m, truth.north_m, strict=True)),
    )
    plain = read_truth(tmp_path / "truth.csv")
    assert plain.heading_deg is None
    ev = evaluate(make_track(truth, (1.0, 0.0), (1.0, 0.0, 1.0)), plain)
    d = ev.as_dict()
    assert "heading_mean_abs_err_deg" not in d and "heading_final_err_deg" not in d
    assert "heading" not in format_report(ev)


def track_rows(n: int = 5) -> list[list[object]]:
    return [[T0 + i, i, 0.0, 90.0, 1.0, 0.0, 1.0, 4.0, "extra"] for i in range(n)]


def test_read_track_round_trip_with_extra_columns(tmp_path: Path) -> None:
    header = [*TRACK_COLUMNS, "mode"]
    path = write_csv(tmp_path / "track.csv", header, track_rows())
    tr = read_track(path)
    assert tr.t_s.tolist() == [T0 + i for i in range(5)]
    assert tr.east_m.tolist() == [0.0, 1.0, 2.0, 3.0, 4.0]


@pytest.mark.parametrize(
    ("row", "col", "value", "match"),
    [
        (2, "east_m", "nan", r"line 4: east_m is not finite: 'nan'"),
        (3, "north_m", "abc", r"line 5: north_m is not a number: 'abc'"),
        (1, "major_axis_m", "inf", r"line 3: major_axis_m is not finite"),
        (1, "var_east_m2", "-1.0", r"line 3: var_east_m2 is negative"),
        (2, "t_s", "", r"line 4: t_s is not a number: ''"),
    ],
)
def test_bad_track_values(tmp_path: Path, row: int, col: str, value: str, match: str) -> None:
    rows = track_rows()
    rows[row][TRACK_COLUMNS.index(col)] = value
    path = write_csv(tmp_path / "track.csv", [*TRACK_COLUMNS, "mode"], rows)
    with pytest.raises(UserError, match=match) as info:
        read_track(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_bad_track_files(tmp_path: Path) -> None:
    header = [*TRACK_COLUMNS, "mode"]
    rows = track_rows()
    cases: list[tuple[list[str], list[list[object]], str]] = [
        (
            [c for c in header if c != "var_north_m2"],
            [r[:6] + r[7:] for r in rows],
            r"line 1: the track header lacks var_north_m2$",
        ),
        (header, [rows[0], rows[2], rows[1], *rows[3:]], r"line 4: time .* goes back .*line 3"),
        (header, [*rows[:2], rows[2][:5], *rows[3:]], r"line 4: 5 fields, the header has 9"),
        (header, [], r"header but no data rows"),
    ]
    for i, (h, r, match) in enumerate(cases):
        path = write_csv(tmp_path / f"track{i}.csv", h, r)
        with pytest.raises(UserError, match=match) as info:
            read_track(path)
        assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)
    # Equal times are allowed in a track (not in a truth); blank lines are skipped.
    path = write_csv(tmp_path / "same.csv", header, [rows[0], rows[0], [], rows[1]])
    assert read_track(path).t_s.size == 3


def test_bad_truth_files(tmp_path: Path) -> None:
    rows: list[list[object]] = [[T0 + i, i, 0.0] for i in range(4)]
    dup = write_csv(tmp_path / "dup.csv", ["t", "east_m", "north_m"], [*rows[:2], rows[1]])
    with pytest.raises(UserError, match=r"dup.csv: line 4: time .* does not increase"):
        read_truth(dup)
    no_t = write_csv(tmp_path / "no_t.csv", ["time", "east_m", "north_m"], rows)
    with pytest.raises(UserError, match=r"no_t.csv: line 1: the truth header lacks t$"):
        read_truth(no_t)
    nan_h = write_csv(  # an undefined course (standing still) is allowed, infinity is not
        tmp_path / "nan_h.csv", ["t", "east_m", "north_m", "heading_deg"], [[*rows[0], "NaN"]]
    )
    assert read_truth(nan_h).heading_deg is None
    inf_h = write_csv(
        tmp_path / "inf_h.csv", ["t", "east_m", "north_m", "heading_deg"], [[*rows[0], "inf"]]
    )
    with pytest.raises(UserError, match=r"line 2: heading_deg is not finite"):
        read_truth(inf_h)
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(UserError, match=r"empty truth file"):
        read_truth(tmp_path / "empty.csv")
    with pytest.raises(UserError, match=r"absent.csv: not found"):
        read_truth(tmp_path / "absent.csv")
    (tmp_path / "bin.csv").write_bytes(b"t,east_m,north_m\n\xff\xfe\x00\x01")
    with pytest.raises(UserError, match=r"not UTF-8"):
        read_truth(tmp_path / "bin.csv")


def write_pair(tmp_path: Path, truth: Truth, track: Track) -> tuple[Path, Path]:
    assert truth.heading_deg is not None
    truth_path = write_csv(
        tmp_path / "truth.csv",
        ["t", "east_m", "north_m", "heading_deg", "speed_mps"],
        [
            [t, e, n, h, 10.0]
            for t, e, n, h in zip(
                truth.t_s, truth.east_m, truth.north_m, truth.heading_deg, strict=True
            )
        ],
    )
    return write_track(tmp_path / "track.csv", track), truth_path


def test_cli_register_json_on_the_last_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = circle_truth(n=201)
    track_path, truth_path = write_pair(
        tmp_path, truth, make_track(truth, (0.0, 1.0), (1.0, 0.0, 1.0))
    )
    parser = argparse.ArgumentParser(prog="guidance")
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(
        ["evaluate", "--track", str(track_path), "--truth", str(truth_path), "--json"]
    )
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "86.5 % inside, mean NEES 2" in out
    d = json.loads(out.splitlines()[-1])
    assert d["steps"] == 201 and d["excluded_steps"] == 0
    assert d["ape_rmse_m"] == pytest.approx(1.0) and d["final_error_m"] == pytest.approx(1.0)
    assert d["inside_2sigma_frac"] == 1.0 and d["mean_nees"] == pytest.approx(1.0)
    assert d["median_axis_ratio"] == pytest.approx(2.0)
    assert d["heading_mean_abs_err_deg"] == pytest.approx(0.0, abs=1e-9)
    assert set(d) == {f.name for f in dataclasses.fields(Evaluation)}

    # Without --json: the report only, no JSON line.
    buf = io.StringIO()
    assert run(track_path, truth_path, as_json=False, out=buf) == 0
    assert not buf.getvalue().splitlines()[-1].startswith("{")
    assert "truth path length" in buf.getvalue()


@pytest.mark.shared_data
def test_real_truth_against_itself_shifted(tmp_path: Path) -> None:
    src = REALDRIVES / "comma2k19_ex1_truth.csv"
    if not src.exists():
        pytest.skip("../shared/data/realdrives not present")
    truth = read_truth(src)
    assert truth.heading_deg is not None and truth.t_s.size > 100
    # The track: the truth moved 1 m north-east, at every other truth time plus mid-points.
    half = 0.5 * (truth.t_s[:-1] + truth.t_s[1:])
    t = np.sort(np.concatenate([truth.t_s[::2], half[::7]]))
    sel = (t >= truth.t_s[0]) & (t <= truth.t_s[-1])
    assert sel.all()
    s = math.sqrt(0.5)
    e = np.interp(t, truth.t_s, truth.east_m) + s
    n = np.interp(t, truth.t_s, truth.north_m) + s
    h = np.interp(t, truth.t_s, np.unwrap(truth.heading_deg, period=360.0)) % 360.0
    ones = np.ones_like(t)
    track = Track(t, e, n, h, 0.25 * ones, 0.0 * ones, 0.25 * ones, 2.0 * ones)
    ev = evaluate(track, truth)
    assert ev.steps == t.size and ev.excluded_steps == 0
    assert ev.ape_rmse_m == pytest.approx(1.0, abs=1e-6)
    assert ev.ape_max_m == pytest.approx(1.0, abs=1e-6)
    assert ev.final_error_m == pytest.approx(1.0, abs=1e-6)
    assert ev.mean_nees == pytest.approx(4.0, abs=1e-5)  # 1 m at sigma 0.5 m
    assert ev.median_axis_ratio == pytest.approx(1.0, abs=1e-5)
    assert ev.heading_mean_abs_err_deg == pytest.approx(0.0, abs=1e-6)
    assert ev.path_m > 100.0
    assert ev.final_error_pct == pytest.approx(100.0 / ev.path_m, rel=1e-5)
    # And through the files, as the command reads them.
    track_path = write_track(tmp_path / "track.csv", track)
    buf = io.StringIO()
    assert run(track_path, src, as_json=True, out=buf) == 0
    d = json.loads(buf.getvalue().splitlines()[-1])
    assert d["ape_rmse_m"] == pytest.approx(1.0, abs=1e-5)


def test_numbers_in_a_csv_are_plain_decimals(tmp_path: Path) -> None:
    """Outside text: Python's float() would take '1_0_0' and fullwidth digits; not here."""
    for bad in ("1_0_0", "0x10", "１２", "1e", "--1"):
        truth = tmp_path / "truth.csv"
        truth.write_text(f"t,east_m,north_m\n0,0,0\n1,{bad},0\n")
        with pytest.raises(UserError, match="not a number"):
            read_truth(truth)


# ----------------------------------------------------------------------------- issue 21, item 4


def test_a_truth_heading_may_be_empty_or_nan_on_some_rows(tmp_path: Path) -> None:
    """Standing still, a GPS course is undefined: those rows leave the heading empty or nan."""
    truth = line_truth()
    rows = []
    for k, (t, e, n) in enumerate(zip(truth.t_s, truth.east_m, truth.north_m, strict=True)):
        h = "" if k % 5 == 0 else ("nan" if k % 7 == 0 else "90.0")
        rows.append((float(t), e, n, h))
    path = write_csv(tmp_path / "truth.csv", ("t", "east_m", "north_m", "heading_deg"), rows)
    read = read_truth(path)
    assert read.heading_deg is not None and np.isnan(read.heading_deg).sum() > 0
    ev = evaluate(make_track(truth, (0.0, 1.0), (4.0, 0.0, 4.0), heading_offset_deg=2.0), read)
    assert ev.heading_mean_abs_err_deg == pytest.approx(2.0)
    empty = write_csv(tmp_path / "none.csv", ("t", "east_m", "north_m", "heading_deg"),
                      [(repr(t), e, n, "") for t, e, n, *_ in rows])  # fmt: skip
    assert read_truth(empty).heading_deg is None
    bad = write_csv(tmp_path / "bad.csv", ("t", "east_m", "north_m"), [(repr(T0), "", 0.0)])
    with pytest.raises(UserError, match="east_m is not a number"):
        read_truth(bad)  # only the heading may be missing


def test_the_error_is_split_along_and_across_the_direction_of_travel() -> None:
    """East-bound: an estimate 3 m behind and 4 m to the right of the truth, with a covariance
    long across the road (north) and thin along it (east): the split shows which is which."""
    truth = line_truth()
    track = make_track(truth, (-3.0, -4.0), (1.0, 0.0, 64.0))
    ev = evaluate(track, truth)
    assert ev.along_rms_m == pytest.approx(3.0) and ev.across_rms_m == pytest.approx(4.0)
    assert ev.along_final_m == pytest.approx(3.0)  # + behind: the truth is ahead
    assert ev.across_final_m == pytest.approx(4.0)  # + the truth is to the left
    assert ev.along_nees == pytest.approx(9.0) and ev.across_nees == pytest.approx(16.0 / 64.0)
    assert len(ev.segments) == 4 and all(s["steps"] > 0 for s in ev.segments)


def test_the_json_holds_only_finite_numbers(tmp_path: Path) -> None:
    truth = line_truth()
    track = make_track(truth, (0.0, 0.0), (1.0, 0.0, 1.0))  # zero error: ratios undefined
    out = io.StringIO()
    tr = write_track(tmp_path / "track.csv", track)
    tp = write_csv(tmp_path / "truth.csv", ("t", "east_m", "north_m"),
                   [(float(t), e, n) for t, e, n in zip(truth.t_s, truth.east_m, truth.north_m,
                                                      strict=True)])  # fmt: skip
    assert run(tr, tp, as_json=True, out=out) == 0
    doc = json.loads(out.getvalue().strip().splitlines()[-1], parse_constant=pytest.fail)
    assert "along_nees" in doc and isinstance(doc["segments"], list)
