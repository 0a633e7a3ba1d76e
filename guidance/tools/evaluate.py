"""Evaluate an estimated track against a ground truth (``guidance evaluate``).

The track is the CSV that ``guidance replay --track FILE.csv`` writes (time, east/north,
heading and the 2x2 position covariance of the estimator); the truth is a CSV with
``t,east_m,north_m`` and optionally ``heading_deg`` in the same local frame and time base.
Each track row is compared with the truth linearly interpolated at its time; rows outside
the truth's time span are counted and left out. There is no alignment: the estimator starts
from the operator's start point in the truth's own frame.

Position error statistics (APE, translation part) come from ``evo``; the consistency
figures use the covariance: NEES = e^T P^-1 e with e = truth - estimate (2 dof), the
fraction of steps whose truth lies inside the 2-sigma ellipse (NEES <= 4, 86.5 % for an
honest filter), the mean NEES (2 for an honest filter) and the median ratio of the
2-sigma semi-major axis to the true error.
"""

from __future__ import annotations

import argparse
import csv
import io
import itertools
import json
import math
import re
import sys
import warnings
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, BinaryIO, TextIO

import numpy as np
import numpy.typing as npt

from guidance import files
from guidance.core.model import CHI2_2D_2SIGMA, mahalanobis_sq_2d
from guidance.errors import UserError
from guidance.tools.track import COLUMNS

FloatArray = npt.NDArray[np.float64]

_DECIMAL = re.compile(r"^[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?$|^[+-]?(nan|inf)$", re.I)
"""A number as a CSV from outside may write it: plain ASCII decimal, optional exponent."""

TRACK_COLUMNS = COLUMNS
"""What ``guidance replay --track`` writes (``guidance.tools.track``)."""
TRUTH_COLUMNS = ("t", "east_m", "north_m")
NEES_2SIGMA = CHI2_2D_2SIGMA  # d^2 bound of the 2-sigma ellipse, 2 dof
INSIDE_2SIGMA_EXPECTED = 1.0 - math.exp(-NEES_2SIGMA / 2.0)  # 0.865 for an honest filter
MEAN_NEES_EXPECTED = 2.0
MIN_ERROR_M = 1e-6  # steps with a smaller true error are left out of the axis ratio
MAX_INPUT_BYTES = files.KINDS["truth_csv"].max_bytes
MAX_ROWS = 1_000_000
MAX_LINE_CHARS = 4096
"""Bounds of what is read (14 h of a 20 Hz truth fit): ``/dev/zero``, a file without line breaks
or a runaway log is refused with one line, never read into memory whole."""


@dataclass(frozen=True, eq=False)
class Track:
    """The estimator's output, one entry per track row (times in the logs' time base)."""

    t_s: FloatArray
    east_m: FloatArray
    north_m: FloatArray
    heading_deg: FloatArray
    var_east_m2: FloatArray
    cov_east_north_m2: FloatArray
    var_north_m2: FloatArray
    major_axis_m: FloatArray  # full 2-sigma major axis (2 x semi-major)


@dataclass(frozen=True, eq=False)
class Truth:
    """The ground truth; ``heading_deg`` is None when the file has no such column."""

    t_s: FloatArray
    east_m: FloatArray
    north_m: FloatArray
    heading_deg: FloatArray | None = None


@dataclass(frozen=True)
class Evaluation:
    """All figures of one evaluation; None: not defined for this drive."""

    steps: int  # track rows inside the truth's time span
    excluded_steps: int  # track rows outside it
    t_start_s: float
    duration_s: float
    path_m: float  # truth path length over the evaluated span
    ape_rmse_m: float
    ape_mean_m: float
    ape_median_m: float
    ape_std_m: float
    ape_min_m: float
    ape_max_m: float
    final_error_m: float
    final_error_pct: float | None  # of path_m; None for a zero path
    nees_steps: int  # steps with a usable (positive definite) covariance
    inside_2sigma_frac: float | None
    mean_nees: float | None
    median_axis_ratio: float | None  # 2-sigma semi-major axis / true error
    heading_mean_abs_err_deg: float | None = None
    heading_final_err_deg: float | None = None  # estimate - truth, wrapped to +-180
    # The error split along the truth's direction of travel and across it (moving steps only).
    split_steps: int = 0
    along_rms_m: float | None = None
    across_rms_m: float | None = None
    along_final_m: float | None = None  # + the estimate is behind the truth
    across_final_m: float | None = None  # + the truth is to the left of the estimate
    along_nees: float | None = None  # mean (error / sigma)^2 along: 1 for an honest filter
    across_nees: float | None = None
    segments: tuple[dict[str, float], ...] = ()
    """Per part of the drive (``SEGMENTS`` equal lengths of truth path): its start and end
    (m along the path), steps, truth inside 2-sigma and mean NEES."""

    def as_dict(self) -> dict[str, object]:
        """The figures with stable snake_case keys; undefined ones (None, or not finite) are
        left out, so the JSON holds only finite numbers."""
        out: dict[str, object] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "segments":
                out[f.name] = [{k: v for k, v in seg.items() if math.isfinite(v)} for seg in value]
            elif value is not None and (not isinstance(value, float) or math.isfinite(value)):
                out[f.name] = value
        return out


def _read_columns(
    path: Path,
    what: str,
    required: Sequence[str],
    optional: Sequence[str] = (),
    nullable: Sequence[str] = (),
) -> tuple[dict[str, FloatArray], list[int]]:
    """The wanted columns as arrays and the file line of each row; UserError on bad input.
    A ``nullable`` column may be empty or ``nan`` on a row (NaN there: undefined, e.g. the GPS
    course of a car standing still)."""
    with files.opened(path, "truth_csv") as raw:
        return columns_from(raw, path, what, required, optional, nullable)


def columns_from(
    raw: BinaryIO,
    path: Path,
    what: str,
    required: Sequence[str],
    optional: Sequence[str] = (),
    nullable: Sequence[str] = (),
) -> tuple[dict[str, FloatArray], list[int]]:
    """``_read_columns`` on a file already opened through ``guidance.files`` (each reader opens
    its own kind: a truth CSV here, a speed and yaw-rate CSV in ``guidance.tools.odometry_csv``)."""
    line = 1
    try:
        with io.TextIOWrapper(raw, encoding="utf-8-sig", newline="") as f:
            reader = csv.reader(_bounded_lines(f, path, what))
            header = next(reader, None)
            if header is None:
                raise UserError(f"{path}: empty {what} file (no header line)")
            names = [h.strip() for h in header]
            missing = [c for c in required if c not in names]
            if missing:
                raise UserError(f"{path}: line 1: the {what} header lacks {', '.join(missing)}")
            index = {c: names.index(c) for c in (*required, *optional) if c in names}
            values: dict[str, array[float]] = {c: array("d") for c in index}
            lines: list[int] = []
            for row in reader:
                line = reader.line_num
                if not any(cell.strip() for cell in row):
                    continue
                if len(lines) >= MAX_ROWS:
                    raise UserError(f"{path}: the {what} file has more than {MAX_ROWS:,} rows")
                if len(row) != len(names):
                    raise UserError(
                        f"{path}: line {line}: {len(row)} fields, the header has {len(names)}"
                    )
                for col, i in index.items():
                    if col in nullable and row[i].strip().lower() in ("", "nan"):
                        values[col].append(math.nan)
                        continue
                    try:
                        if not _DECIMAL.match(row[i].strip()):  # no 1_0_0, 0x10, "１２"
                            raise ValueError(row[i])
                        v = float(row[i])
                    except ValueError:
                        raise UserError(
                            f"{path}: line {line}: {col} is not a number: {row[i]!r}"
                        ) from None
                    if not math.isfinite(v):
                        raise UserError(f"{path}: line {line}: {col} is not finite: {row[i]!r}")
                    values[col].append(v)
                lines.append(line)
    except OSError as exc:
        raise UserError(f"{path}: cannot read the {what} file: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise UserError(f"{path}: not UTF-8 text after line {line}: is it a CSV file?") from None
    except csv.Error as exc:
        raise UserError(f"{path}: line {line}: bad CSV: {exc}") from None
    if not lines:
        raise UserError(f"{path}: the {what} file has a header but no data rows")
    return {c: np.asarray(v, dtype=np.float64) for c, v in values.items()}, lines


def _bounded_lines(f: TextIO, path: Path, what: str) -> Iterator[str]:
    """The lines of ``f``, each at most ``MAX_LINE_CHARS`` and all at most ``MAX_INPUT_BYTES``
    characters: ``/dev/zero`` or a file without line breaks is refused, never read whole."""
    total = 0
    while True:
        line = f.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        if len(line) > MAX_LINE_CHARS:
            raise UserError(
                f"{path}: a line of the {what} file is longer than {MAX_LINE_CHARS:,} characters:"
                " is it a CSV file?"
            )
        total += len(line)
        if total > MAX_INPUT_BYTES:
            raise UserError(f"{path}: the {what} file is larger than {MAX_INPUT_BYTES >> 20} MiB")
        yield line


def plain(value: float) -> str:
    """A number as a person reads it: ``100.0``, ``1.5e+307``, never ``np.float64(100.0)`` or
    three hundred digits."""
    v = float(value)
    if not math.isfinite(v):
        return "n/a"
    return f"{v:.3f}" if abs(v) < 1e12 else f"{v:.6g}"


def _check_time(path: Path, t: FloatArray, lines: list[int], strict: bool) -> None:
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0 if strict else step < 0)
    if bad.size:
        k = int(bad[0]) + 1
        how = "does not increase" if strict and t[k] == t[k - 1] else "goes back"
        raise UserError(
            f"{path}: line {lines[k]}: time {plain(t[k])} {how} after {plain(t[k - 1])} "
            f"(line {lines[k - 1]}): the rows must be in time order"
        )


def read_track(path: Path) -> Track:
    """Read a track CSV of ``guidance replay --track``; UserError naming file and line."""
    cols, lines = _read_columns(path, "track", TRACK_COLUMNS)
    _check_time(path, cols["t_s"], lines, strict=False)
    for col in ("var_east_m2", "var_north_m2", "major_axis_m"):
        bad = np.flatnonzero(cols[col] < 0)
        if bad.size:
            raise UserError(f"{path}: line {lines[int(bad[0])]}: {col} is negative")
    return Track(**cols)


def read_truth(path: Path) -> Truth:
    """Read a truth CSV (``t,east_m,north_m[,heading_deg]``); UserError naming file and line."""
    cols, lines = _read_columns(path, "truth", TRUTH_COLUMNS, ("heading_deg",), ("heading_deg",))
    _check_time(path, cols["t"], lines, strict=True)
    heading = cols.get("heading_deg")
    if heading is not None and not np.any(np.isfinite(heading)):
        heading = None  # a column with no value at all
    return Truth(cols["t"], cols["east_m"], cols["north_m"], heading)


def _wrap_deg(a: FloatArray) -> FloatArray:
    return np.asarray((a + 180.0) % 360.0 - 180.0, dtype=np.float64)


def _ape(
    t: FloatArray, ref: tuple[FloatArray, FloatArray], est: tuple[FloatArray, FloatArray]
) -> tuple[dict[str, float], FloatArray]:
    """evo's APE (translation part, no alignment): its statistics and the per-step errors."""
    try:  # lazily: evo.core pulls in scipy, and the rest of the command line needs neither
        from evo.core import metrics, trajectory
    except ModuleNotFoundError as exc:
        raise UserError(f"evaluate needs the evo package ({exc}): pip install evo") from None

    unit_quat = np.tile([1.0, 0.0, 0.0, 0.0], (t.size, 1))  # unused by the translation part

    def traj(xy: tuple[FloatArray, FloatArray]) -> trajectory.PoseTrajectory3D:
        xyz = np.column_stack([xy[0], xy[1], np.zeros_like(xy[0])])
        return trajectory.PoseTrajectory3D(
            positions_xyz=xyz, orientations_quat_wxyz=unit_quat, timestamps=t
        )

    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((traj(ref), traj(est)))
    kinds = ("rmse", "mean", "median", "std", "min", "max")
    stats = {k: float(ape.get_statistic(metrics.StatisticsType(k))) for k in kinds}
    return stats, np.asarray(ape.error, dtype=np.float64)


def evaluate(track: Track, truth: Truth) -> Evaluation:
    """Compare the track with the truth interpolated at the track's times."""
    t_lo, t_hi = float(truth.t_s[0]), float(truth.t_s[-1])
    sel = (track.t_s >= t_lo) & (track.t_s <= t_hi)
    n = int(np.count_nonzero(sel))
    if n < 2:
        raise UserError(
            f"only {n} of the {track.t_s.size} track rows fall inside the truth's time span "
            f"{plain(t_lo)} to {plain(t_hi)} s "
            f"(track: {plain(track.t_s[0])} to {plain(track.t_s[-1])} s); at least 2 are needed:"
            " are both files in the same time base?"
        )
    t = track.t_s[sel]
    tt, tq = truth.t_s - t_lo, t - t_lo  # small numbers for the interpolation
    ref_e = np.interp(tq, tt, truth.east_m)
    ref_n = np.interp(tq, tt, truth.north_m)
    est_e, est_n = track.east_m[sel], track.north_m[sel]
    stats, err = _ape(t, (ref_e, ref_n), (est_e, est_n))

    # Truth path over the evaluated span: its own samples inside plus the interpolated ends.
    inner = (truth.t_s > t[0]) & (truth.t_s < t[-1])
    pe = np.concatenate([ref_e[:1], truth.east_m[inner], ref_e[-1:]])
    pn = np.concatenate([ref_n[:1], truth.north_m[inner], ref_n[-1:]])
    path_m = float(np.sum(np.hypot(np.diff(pe), np.diff(pn))))
    final_m = float(err[-1])

    # Consistency: NEES = e^T P^-1 e, the estimator's own Mahalanobis distance (core.model).
    ex, en = ref_e - est_e, ref_n - est_n
    a, b, c = track.var_east_m2[sel], track.cov_east_north_m2[sel], track.var_north_m2[sel]
    ok = (a > 0) & (c > 0) & (a * c - b * b > 1e-12 * a * c)
    nees = np.array(
        [
            mahalanobis_sq_2d(float(e0), float(e1), float(s00), float(s01), float(s11))
            for e0, e1, s00, s01, s11 in zip(ex[ok], en[ok], a[ok], b[ok], c[ok], strict=True)
        ],
        dtype=np.float64,
    )
    big = err >= MIN_ERROR_M
    ratio = 0.5 * track.major_axis_m[sel][big] / err[big]

    head_mean: float | None = None
    head_final: float | None = None
    if truth.heading_deg is not None:  # the rows that have one (standing still: none)
        have = np.isfinite(truth.heading_deg)
        if np.count_nonzero(have) >= 2:
            ref_h = np.interp(tq, tt[have], np.unwrap(truth.heading_deg[have], period=360.0))
            dh = _wrap_deg(track.heading_deg[sel] - ref_h)
            head_mean, head_final = float(np.mean(np.abs(dh))), float(dh[-1])
    split = along_across(t, (ref_e, ref_n), (ex, en), (a, b, c))

    return Evaluation(
        steps=n,
        excluded_steps=int(track.t_s.size - n),
        t_start_s=float(t[0]),
        duration_s=float(t[-1] - t[0]),
        path_m=path_m,
        ape_rmse_m=stats["rmse"],
        ape_mean_m=stats["mean"],
        ape_median_m=stats["median"],
        ape_std_m=stats["std"],
        ape_min_m=stats["min"],
        ape_max_m=stats["max"],
        final_error_m=final_m,
        final_error_pct=100.0 * final_m / path_m if path_m > 0 else None,
        nees_steps=int(nees.size),
        inside_2sigma_frac=float(np.mean(nees <= NEES_2SIGMA)) if nees.size else None,
        mean_nees=float(np.mean(nees)) if nees.size else None,
        median_axis_ratio=float(np.median(ratio)) if ratio.size else None,
        heading_mean_abs_err_deg=head_mean,
        heading_final_err_deg=head_final,
        **split,
        segments=_segments(t, ref_e, ref_n, nees, ok),
    )


SEGMENTS = 4
MOVING_MPS = 0.5
"""Below this truth speed the direction of travel is undefined: no along/across split."""


def along_across(
    t: FloatArray,
    ref: tuple[FloatArray, FloatArray],
    err: tuple[FloatArray, FloatArray],
    cov: tuple[FloatArray, FloatArray, FloatArray],
) -> dict[str, Any]:
    """The error (truth - estimate) split along the truth's direction of travel (from its
    positions, so a truth without headings works too) and across it, with each part's own
    variance from the covariance: u^T P u. An ellipse long across the road and thin along it
    shows as a small ``across_nees`` and a large ``along_nees``."""
    e, n = ref
    dt = np.gradient(t)
    ve, vn = (
        np.gradient(e) / np.where(dt > 0, dt, np.inf),
        np.gradient(n) / np.where(dt > 0, dt, np.inf),
    )
    speed = np.hypot(ve, vn)
    a, b, c = cov
    use = (speed >= MOVING_MPS) & (a > 0) & (c > 0) & (a * c - b * b > 1e-12 * a * c)
    if np.count_nonzero(use) < 2:
        return {"split_steps": int(np.count_nonzero(use))}
    ue, un = ve[use] / speed[use], vn[use] / speed[use]
    ee, en = err[0][use], err[1][use]
    along = ee * ue + en * un
    across = -ee * un + en * ue
    aa, bb, cc = a[use], b[use], c[use]
    var_along = aa * ue * ue + 2 * bb * ue * un + cc * un * un
    var_across = aa * un * un - 2 * bb * ue * un + cc * ue * ue
    return {
        "split_steps": int(along.size),
        "along_rms_m": float(np.sqrt(np.mean(along**2))),
        "across_rms_m": float(np.sqrt(np.mean(across**2))),
        "along_final_m": float(along[-1]),
        "across_final_m": float(across[-1]),
        "along_nees": float(np.mean(along**2 / var_along)),
        "across_nees": float(np.mean(across**2 / np.maximum(var_across, 1e-12))),
    }


def _segments(
    t: FloatArray, e: FloatArray, n: FloatArray, nees: FloatArray, ok: npt.NDArray[np.bool_]
) -> tuple[dict[str, float], ...]:
    """Consistency per ``SEGMENTS`` equal parts of the truth path (where it goes wrong)."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(e), np.diff(n)))])[ok]
    if s.size < SEGMENTS or s[-1] <= 0:
        return ()
    edges = np.linspace(0.0, float(s[-1]), SEGMENTS + 1)
    out = []
    for lo, hi in itertools.pairwise(edges):
        m = (s >= lo) & ((s < hi) | (hi == edges[-1]))
        k = int(np.count_nonzero(m))
        out.append({
            "from_m": float(lo), "to_m": float(hi), "steps": float(k),
            "inside_2sigma_frac": float(np.mean(nees[m] <= NEES_2SIGMA)) if k else math.nan,
            "mean_nees": float(np.mean(nees[m])) if k else math.nan,
        })  # fmt: skip
    return tuple(out)


def _num(value: float | None, fmt: str = ".2f") -> str:
    """A figure of the report: n/a when undefined or not finite, a short exponent form when
    too large for ``fmt`` to be read."""
    if value is None or not math.isfinite(value):
        return "n/a"
    return format(value, fmt) if abs(value) < 1e9 else format(value, ".3g")


def format_report(ev: Evaluation) -> str:
    """A readable, aligned text report with units (ends with a newline)."""

    def row(label: str, value: str, unit: str = "", note: str = "") -> str:
        return f"  {label:<26}{value:>10} {unit:<4}{note}".rstrip()

    pct = "" if ev.final_error_pct is None else f"({_num(ev.final_error_pct)} % of the path)"
    lines = [
        f"{ev.steps} steps over {_num(ev.duration_s, '.1f')} s from t = {plain(ev.t_start_s)} s "
        f"({ev.excluded_steps} track rows outside the truth's time span left out)",
        row("truth path length", _num(ev.path_m, ".1f"), "m"),
        "position error (APE, translation part, no alignment)",
        row("rmse", _num(ev.ape_rmse_m), "m"),
        row("mean", _num(ev.ape_mean_m), "m"),
        row("median", _num(ev.ape_median_m), "m"),
        row("std", _num(ev.ape_std_m), "m"),
        row("min", _num(ev.ape_min_m), "m"),
        row("max", _num(ev.ape_max_m), "m"),
        row("final", _num(ev.final_error_m), "m", pct),
        f"consistency of the 2-sigma ellipse ({ev.nees_steps} steps with a usable covariance)",
        row(
            "truth inside the ellipse",
            _num(None if ev.inside_2sigma_frac is None else 100 * ev.inside_2sigma_frac, ".1f"),
            "%",
        ),
        row("mean NEES", _num(ev.mean_nees, ".2f")),
        row("median semi-major / error", _num(ev.median_axis_ratio, ".2f")),
        f"  an honest filter: {100 * INSIDE_2SIGMA_EXPECTED:.1f} % inside, mean NEES "
        f"{MEAN_NEES_EXPECTED:.0f} (fewer inside or a larger NEES: overconfident),",
        "  axis ratio about 1.7 for a round ellipse, more for a long one",
    ]
    if ev.along_nees is not None:
        lines += [
            f"error along the direction of travel and across it ({ev.split_steps} moving steps)",
            row("rms along / across", f"{_num(ev.along_rms_m)} / {_num(ev.across_rms_m)}", "m"),
            row(
                "final along / across",
                f"{_num(ev.along_final_m, '+.1f')} / {_num(ev.across_final_m, '+.1f')}",
                "m",
            ),
            row("(error/sigma)^2 along", _num(ev.along_nees), "", "(1 for an honest filter)"),
            row("(error/sigma)^2 across", _num(ev.across_nees), "", "(1 for an honest filter)"),
        ]
    if ev.segments:
        lines.append("by part of the drive (truth path)")
        for seg in ev.segments:
            inside, nees = seg["inside_2sigma_frac"], seg["mean_nees"]
            pct = _num(100 * inside, ".1f")
            mean = _num(nees, ".2f")
            span = f"{_num(seg['from_m'], '.0f')}-{_num(seg['to_m'], '.0f')} m"
            lines.append(row(span, pct, "%", f"inside, mean NEES {mean}"))
    if ev.heading_mean_abs_err_deg is not None:
        lines += [
            "heading error (estimate - truth)",
            row("mean abs", _num(ev.heading_mean_abs_err_deg), "deg"),
            row("final", _num(ev.heading_final_err_deg, "+.2f"), "deg"),
        ]
    return "\n".join(lines) + "\n"


def run(track_path: Path, truth_path: Path, *, as_json: bool, out: TextIO) -> int:
    """Read, evaluate and write the report (then, with ``as_json``, one JSON line).

    Extreme inputs (1e308, a variance of 1e-320) overflow inside the figures; those come out
    undefined ("n/a", left out of the JSON), so numpy's overflow warnings are not printed."""
    track, truth = read_track(track_path), read_truth(truth_path)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ev = evaluate(track, truth)
    out.write(format_report(ev).rstrip("\n") + "\n")
    if as_json:
        out.write(json.dumps(ev.as_dict(), allow_nan=False) + "\n")  # only finite numbers
    return 0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``evaluate`` subcommand."""
    p = sub.add_parser(
        "evaluate",
        help="compare an estimated track with a ground truth (errors and consistency)",
        description=(
            "Compare a track CSV of 'guidance replay --track' with a ground-truth CSV "
            "(t,east_m,north_m[,heading_deg]) in the same frame and time base: position "
            "error statistics (APE, no alignment), final error, and the consistency of the "
            "estimator's 2-sigma ellipse (fraction inside, NEES)."
        ),
    )
    p.add_argument("--track", type=Path, required=True, metavar="FILE", help="track CSV")
    p.add_argument("--truth", type=Path, required=True, metavar="FILE", help="truth CSV")
    p.add_argument("--json", action="store_true", help="last stdout line: the figures as JSON")
    p.set_defaults(func=_cli_evaluate)


def _cli_evaluate(args: argparse.Namespace) -> int:
    return run(args.track, args.truth, as_json=args.json, out=sys.stdout)
