"""``guidance calibrate --turned-deg T``: the effective track (the turn scale ``kt``) from a
drive whose net heading change is known (issue 38, item 3).

The car model's turn scale is the effective track: the heading turns by the wheels'
difference over ``track / (1 + kt)`` (``model.effective_track``), the configured track
being a spec sheet's or a profile's (docs/estimation.md, "The effective track"). A drive
that starts and ends aligned with the same kerb after whole circles (two slow circles the
same way in a car park: 720 degrees, the compass calibration drive's figure) turns by a
known angle; the wheels' raw net turn ``W`` over the configured track then gives
``(1 + k)(1 + kt) = T / W``, the wheel scale ``k`` taken from the learned file when it holds
one. Its uncertainty: the alignment at both ends (``--turned-sigma-deg``, 3 degrees by
default: a car parked along a kerb by eye), the wheels' walk over the distance, the
left/right difference's prior over that distance, and the file's scale. With ``--write``
it goes into the learned file (``[checkpoint] learned_path`` or ``--learned``), combined with
what the file holds as the wheel scale is (``wheel_cal.fuse``).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from guidance.core.localize.state_limits import MAX_ABS_TURN, MIN_TURN_SIGMA
from guidance.core.localize.wheel_cal import fuse
from guidance.errors import UserError, number

DEFAULT_TURNED_SIGMA_DEG = 3.0
"""Parked along the same kerb by eye at both ends: about 2 degrees each, sqrt(2) x 2."""
MIN_TURN_DEG = 180.0
"""Less than half a turn cannot teach a scale of a few % better than its prior (2 % of 180
degrees is 3.6 degrees, about the alignment's own uncertainty)."""


@dataclass(frozen=True, slots=True)
class TrackResult:
    turn_scale: float
    turn_scale_sigma: float
    wheels_deg: float
    turned_deg: float
    track_m: float
    distance_m: float
    vehicle_id: str
    learned_path: Path | None
    end_unix_s: float

    @property
    def effective_track_m(self) -> float:
        return self.track_m / (1.0 + self.turn_scale)


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("effective track from a drive of known net turn")
    g.add_argument("--turned-deg", type=number, default=None,
                   help="the drive's true net heading change, degrees counter-clockwise "
                   "(two circles to the left: 720)")  # fmt: skip
    g.add_argument("--turned-sigma-deg", type=number, default=None,
                   help=f"its 1-sigma (default {DEFAULT_TURNED_SIGMA_DEG:g})")  # fmt: skip


def track_calibration(log: Path, args: argparse.Namespace) -> TrackResult:
    """The turn scale of the drive (module doc); ``UserError`` when it cannot be one."""
    from guidance.app.config import load_config
    from guidance.app.learned_file import load_learned
    from guidance.tools.replay import can_inputs, raw_setup

    cfg = load_config(args.config, require_goal=False)
    setup = raw_setup(args.config, args.profile, None, log)
    est = setup.pipeline.estimator
    if not est.car_model:
        raise UserError(f"{args.config}: the paper model has no turn-scale state to calibrate")
    turned = math.radians(float(args.turned_deg))
    sigma_t = math.radians(DEFAULT_TURNED_SIGMA_DEG if args.turned_sigma_deg is None
                           else float(args.turned_sigma_deg))  # fmt: skip
    if abs(math.degrees(turned)) < MIN_TURN_DEG or not sigma_t > 0.0:
        raise UserError(f"--turned-deg must be at least {MIN_TURN_DEG:g} degrees either way "
                        "and its sigma > 0: a smaller turn teaches no track")  # fmt: skip
    odo = list(can_inputs(log, setup.profile))
    if len(odo) < 2:
        raise UserError(f"{log}: no wheel odometry decoded with profile {setup.profile!r}")
    diff = sum(m.d_right_m - m.d_left_m for m in odo)
    dist = sum(abs(m.d_right_m + m.d_left_m) for m in odo) / 2.0
    wheels = diff / est.track_m
    if abs(wheels) < 0.5 * abs(turned) or wheels * turned <= 0.0:
        raise UserError(
            f"the wheels turned {math.degrees(wheels):+.0f} degrees against the "
            f"{math.degrees(turned):+.0f} given: not this drive, or the sign"
        )
    path = args.learned
    if path is None and cfg.checkpoint.learned_path:
        path = Path(cfg.checkpoint.learned_path)
    k, k_sigma = 0.0, est.scale_sigma
    if path is not None:
        old, _ = load_learned(Path(path), cfg.vehicle_id)
        if old is not None:
            k, k_sigma = old.scale, old.scale_sigma
    ratio = turned / (wheels * (1.0 + k))
    var_w = (2.0 * est.wheel_walk_var_m2_per_m * dist / est.track_m**2
             + (est.diff_sigma * dist / est.track_m) ** 2)  # fmt: skip
    rel = math.sqrt((sigma_t / turned) ** 2 + var_w / wheels**2 + (k_sigma / (1.0 + k)) ** 2)
    kt, kt_sigma = ratio - 1.0, max(MIN_TURN_SIGMA, ratio * rel)
    if abs(kt) > MAX_ABS_TURN:
        raise UserError(f"a turn scale of {100 * kt:+.0f} % is beyond any car's "
                        f"(+-{100 * MAX_ABS_TURN:.0f} %): check --turned-deg")  # fmt: skip
    end = odo[-1].t_s if 1e9 < odo[-1].t_s <= time.time() else time.time()
    return TrackResult(kt, kt_sigma, math.degrees(wheels), math.degrees(turned), est.track_m,
                       dist, cfg.vehicle_id, Path(path) if path else None, end)  # fmt: skip


def summary(res: TrackResult) -> tuple[str, dict[str, Any]]:
    text = (
        f"turn scale {100 * res.turn_scale:+.2f} +- {100 * res.turn_scale_sigma:.2f} %: "
        f"effective track {res.effective_track_m:.3f} m against the configured "
        f"{res.track_m:.3f} m (the wheels turned {res.wheels_deg:+.1f} deg over "
        f"{res.distance_m:.0f} m, the drive {res.turned_deg:+.1f})\n"
    )
    doc = {"turn_scale": res.turn_scale, "turn_scale_sigma": res.turn_scale_sigma,
           "effective_track_m": res.effective_track_m, "wheels_deg": res.wheels_deg}  # fmt: skip
    return text, doc


def write_track(res: TrackResult, args: argparse.Namespace) -> str:
    """Into the learned file under its lock, combined with what it holds: the line saying so."""
    from guidance.app.learned_file import LearnedBusy, LearnedLock, load_learned, save_learned
    from guidance.core.localize.learned import LearnedParams

    if res.learned_path is None:
        raise UserError(f"{args.config}: no [checkpoint] learned_path: give --learned FILE.json")
    try:
        lock = LearnedLock.take(res.learned_path)
    except LearnedBusy as exc:
        raise UserError(f"{exc}: not written; stop the car, then run this again") from None
    with lock:
        old, refused = load_learned(res.learned_path, res.vehicle_id, time.time())
        if refused is not None:
            raise UserError(f"{refused.split(': starting')[0]}; not written")
        if old is None:
            from guidance.app.config import load_config

            est = load_config(args.config, require_goal=False).pipeline.estimator
            new = LearnedParams(res.vehicle_id, res.end_unix_s, res.distance_m, 0.0,
                                est.scale_sigma, 0.0, est.diff_sigma, turn_scale=res.turn_scale,
                                turn_scale_sigma=res.turn_scale_sigma)  # fmt: skip
            how = "a new file"
        else:  # a file without a turn scale: its prior, the configured one
            kt0, s0 = old.turn_scale, old.turn_scale_sigma
            if kt0 is None or s0 is None:
                kt0, s0 = 0.0, 0.0  # fuse() takes the new value alone
            kt, s, fused = fuse(kt0, s0, res.turn_scale, res.turn_scale_sigma)
            new = replace(old, turn_scale=kt, turn_scale_sigma=max(s, MIN_TURN_SIGMA))
            how = "combined with the file's" if fused else "replacing the file's (3 sigma apart)"
        LearnedParams.from_dict(new.to_dict())  # what the car would refuse is not written
        save_learned(res.learned_path, new)
    return (f"written to {res.learned_path} ({how}): turn scale {100 * (new.turn_scale or 0):+.2f}"
            f" +- {100 * (new.turn_scale_sigma or 0):.2f} %")  # fmt: skip
