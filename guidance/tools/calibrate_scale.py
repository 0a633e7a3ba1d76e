"""``guidance calibrate --distance-m D`` (or ``--points``): the wheel scale from a known length.

Next to the compass card: drive a stretch whose length is known (between two landmarks whose
distance along the road you measured on a map, or a measured straight), and the wheel-speed
scale is ``known / wheel - 1`` (``guidance.core.localize.wheel_cal``), with its uncertainty from the
distance's own (``--distance-sigma-m``) and the wheel noise. With ``--write`` it goes into
the car's learned-parameters file (``[checkpoint] learned_path`` or ``--learned``;
``guidance.app.learned_file``: atomic, validated), combined with what the file already holds
(inverse-variance, or replacing it when they disagree by more than 3 sigma), so the car's
next drive starts from it. ``--points LAT,LON LAT,LON`` takes the straight-line distance
between two known points instead: only on a straight road, which the odometry's heading span
checks (``wheel_cal.MAX_TURN_DEG``).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from guidance.core.localize.state_limits import FUTURE_TOLERANCE_S, MAX_SCALE_SIGMA, MIN_SCALE_SIGMA
from guidance.core.localize.wheel_cal import (
    MAX_TURN_DEG,
    ScaleFit,
    fuse,
    scale_from_distance,
    stretch,
)
from guidance.errors import UserError, number

if TYPE_CHECKING:  # the estimator stack loads on first use only
    from guidance.core.localize.estimator import EstimatorConfig

DEFAULT_DISTANCE_SIGMA_M = 1.0
"""A distance measured along the road on a map (two landmarks 1 km apart: about 1 m)."""
DEFAULT_POINT_SIGMA_M = 1.0
"""Each known point's position (a map pin on a landmark): the distance gets sqrt(2) of it."""


@dataclass(frozen=True, slots=True)
class ScaleResult:
    fit: ScaleFit
    vehicle_id: str
    learned_path: Path | None
    end_unix_s: float
    from_points: bool
    estimator: EstimatorConfig


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("wheel scale from a drive of known length")
    g.add_argument(
        "--distance-m",
        type=number,
        default=None,
        help="the known length of the drive (or of --from-t..--to-t), metres",
    )
    g.add_argument(
        "--distance-sigma-m",
        type=number,
        default=None,
        help=f"its 1-sigma (default {DEFAULT_DISTANCE_SIGMA_M:g} m; "
        f"{DEFAULT_POINT_SIGMA_M:g} m per point with --points)",
    )
    g.add_argument(
        "--points",
        nargs=2,
        metavar="LAT,LON",
        default=None,
        help="two known points at the stretch's ends, on a straight road",
    )
    g.add_argument(
        "--from-t",
        type=number,
        default=None,
        metavar="T_S",
        help="the stretch starts at this log time (s, the log's time base)",
    )
    g.add_argument(
        "--to-t", type=number, default=None, metavar="T_S", help="the stretch ends at this log time"
    )
    g.add_argument(
        "--learned",
        type=Path,
        default=None,
        metavar="FILE.json",
        help="the learned-parameters file (default: [checkpoint] learned_path)",
    )


def wanted(args: argparse.Namespace) -> bool:
    if args.distance_m is not None and args.points is not None:
        raise UserError("give --distance-m or --points, not both")
    return args.distance_m is not None or args.points is not None


def _point(text: str) -> tuple[float, float]:
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"--points: {text!r} is not LAT,LON") from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise UserError(f"--points: {text!r} is not a latitude,longitude")
    return lat, lon


def scale_calibration(log: Path, args: argparse.Namespace) -> ScaleResult:
    """The wheel scale of the stretch (module docstring); ``UserError`` with one line when it
    cannot be one."""
    from guidance.app.config import load_config
    from guidance.core.geo import Origin
    from guidance.tools.replay import can_inputs, raw_setup

    cfg = load_config(args.config, require_goal=False)
    setup = raw_setup(args.config, args.profile, None, log)
    est = setup.pipeline.estimator
    if not est.car_model:
        raise UserError(f"{args.config}: the paper model has no wheel-scale state to calibrate")
    odo = list(can_inputs(log, setup.profile))
    if len(odo) < 2:
        raise UserError(f"{log}: no wheel odometry decoded with profile {setup.profile!r}")
    try:
        st = stretch([m.t_s for m in odo], [m.d_left_m for m in odo],
                     [m.d_right_m for m in odo], est.track_m, args.from_t, args.to_t)  # fmt: skip
    except ValueError as exc:
        raise UserError(f"{log}: {exc}") from None
    if args.points is not None:
        a, b = _point(args.points[0]), _point(args.points[1])
        known = math.hypot(*Origin.of(a).to_local(b[0], b[1]))
        each = DEFAULT_POINT_SIGMA_M if args.distance_sigma_m is None else args.distance_sigma_m
        sigma = math.sqrt(2.0) * each
        if st.turn_deg > MAX_TURN_DEG:
            raise UserError(
                f"the odometry's heading spans {st.turn_deg:.0f} degrees between the points: "
                "their straight-line distance is not the path's; give --distance-m measured "
                "along the road"
            )
    else:
        known = float(args.distance_m)
        sigma = DEFAULT_DISTANCE_SIGMA_M if args.distance_sigma_m is None else args.distance_sigma_m
    try:
        fit = scale_from_distance(st.wheel_m, known, sigma, est.wheel_walk_var_m2_per_m,
                                  st.turn_deg)  # fmt: skip
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if not fit.scale_sigma <= MAX_SCALE_SIGMA:  # defect 7: a sigma the car's loader refuses
        raise UserError(
            f"the scale's uncertainty, +-{100 * fit.scale_sigma:.0f} %, is no calibration "
            f"(the car takes at most +-{100 * MAX_SCALE_SIGMA:.0f} %): the distance's "
            f"uncertainty ({sigma:g} m) must be well below the distance ({known:g} m)"
        )
    path = args.learned
    if path is None and cfg.checkpoint.learned_path:
        path = Path(cfg.checkpoint.learned_path)
    now = time.time()  # a Unix-time log: its own clock, unless it is ahead of this one
    end = st.t_to_s if 1e9 < st.t_to_s <= now + FUTURE_TOLERANCE_S else now
    return ScaleResult(fit, cfg.vehicle_id, path, end, args.points is not None, est)


def write_scale(res: ScaleResult, args: argparse.Namespace) -> str:
    """Into the learned-parameters file, combined with what it holds: the line saying so."""
    from guidance.app.learned_file import LearnedBusy, LearnedLock

    if res.learned_path is None:
        raise UserError(
            f"{args.config}: no [checkpoint] learned_path: give --learned FILE.json to write"
        )
    try:
        lock = LearnedLock.take(res.learned_path)
    except LearnedBusy as exc:
        raise UserError(
            f"{exc}: not written (the car would overwrite it with its own value at its next "
            "save); stop the car (systemctl stop guidance), then run this again"
        ) from None
    with lock:
        return _write_scale_locked(res)


def _write_scale_locked(res: ScaleResult) -> str:
    """The read-modify-write, under the file's lock; what is written passes the car's own
    loader first, or nothing is written."""
    from guidance.app.learned_file import load_learned, save_learned
    from guidance.core.localize.learned import LearnedParams

    assert res.learned_path is not None
    est = res.estimator
    old, refused = load_learned(res.learned_path, res.vehicle_id, time.time())
    if refused is not None:
        raise UserError(f"{refused.split(': starting')[0]}; not written (move it away first)")
    fit = res.fit
    if fit.scale_sigma < MIN_SCALE_SIGMA:  # no drive knows the scale better (state_limits)
        fit = replace(fit, scale_sigma=MIN_SCALE_SIGMA)
    if old is None:
        new = LearnedParams(res.vehicle_id, res.end_unix_s, fit.wheel_m, fit.scale,
                            fit.scale_sigma, 0.0, est.diff_sigma)  # fmt: skip
        how = "a new file"
    else:
        before = old.widened(res.end_unix_s, est)
        k, s, fused = fuse(before.scale, before.scale_sigma, fit.scale, fit.scale_sigma)
        s = max(s, MIN_SCALE_SIGMA)
        new = replace(before, saved_unix_s=max(res.end_unix_s, old.saved_unix_s), scale=k,
                      scale_sigma=s, distance_m=old.distance_m + fit.wheel_m)  # fmt: skip
        how = (
            f"combined with the file's {100 * before.scale:+.2f} +- "
            f"{100 * before.scale_sigma:.2f} %" if fused else
            f"replacing the file's {100 * before.scale:+.2f} +- {100 * before.scale_sigma:.2f} %"
            " (more than 3 sigma apart)"
        )  # fmt: skip
    try:
        LearnedParams.from_dict(new.to_dict())
    except ValueError as exc:
        raise UserError(
            f"{res.learned_path}: not written: the car would refuse it ({exc})"
        ) from None
    save_learned(res.learned_path, new)
    return (
        f"written to {res.learned_path} ({how}): wheel scale {100 * new.scale:+.2f} +- "
        f"{100 * new.scale_sigma:.2f} %"
    )


def summary(res: ScaleResult) -> tuple[str, dict[str, Any]]:
    f = res.fit
    what = "between the points" if res.from_points else "known"
    text = (
        f"wheel scale {100 * f.scale:+.3f} +- {100 * f.scale_sigma:.3f} % (true distance = "
        f"measured x (1 + k)): {f.wheel_m:.1f} m by the wheels, {f.known_m:.1f} +- "
        f"{f.known_sigma_m:.1f} m {what}; wheel noise {f.wheel_sigma_m:.2f} m; heading span "
        f"{f.turn_deg:.1f} deg\n"
    )
    doc = {
        "scale": f.scale,
        "scale_sigma": f.scale_sigma,
        "wheel_m": f.wheel_m,
        "known_m": f.known_m,
        "known_sigma_m": f.known_sigma_m,
        "wheel_sigma_m": f.wheel_sigma_m,
        "turn_deg": f.turn_deg,
    }
    return text, doc
