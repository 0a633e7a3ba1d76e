"""``guidance calibrate``: fit the compass deviation card from a recorded calibration drive.

The drive (a candump CAN log and a time-stamped NMEA capture, the inputs ``guidance replay``
takes) starts with the car standing at a known true heading (``[start] heading_deg`` in the
car's TOML, or ``--start-heading-deg``); wheel odometry carries that heading through the drive
as the reference, and ``guidance.core.localize.compass_cal`` fits
``deviation = A + B sin h + C cos h + D sin 2h + E cos 2h`` to the readings (docs/estimation.md,
"Calibrating the compass"). With
``--write`` the card goes into the TOML as ``[compass] deviation_deg = [A, B, C, D, E]``
(``guidance.tools.car_toml``: edited with tomlkit, loaded back before it replaces the file);
the car then applies it to every reading before the declination.

With ``--distance-m D`` (or ``--points``) the same drive, or another of known length, teaches
the wheel-speed scale, written with ``--write`` into the car's learned-parameters file
(``guidance.tools.calibrate_scale``); ``--nmea`` is then optional.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from guidance.core.localize.compass_cal import (
    FitResult,
    calibrate_from_drive,
    reference_headings_from_odometry,
)
from guidance.core.model import heading_to_compass
from guidance.errors import UserError, number
from guidance.tools import calibrate_scale, calibrate_track
from guidance.tools.car_toml import write_card
from guidance.tools.replay import can_inputs, nmea_inputs, raw_setup


def calibrate(
    log: Path, nmea: Path, config: str, *, profile: str | None, start_heading_deg: float | None
) -> FitResult:
    """The deviation card of one calibration drive (see the module docstring)."""
    setup = raw_setup(config, profile, start_heading_deg, log)
    pcfg = setup.pipeline
    if pcfg.start_heading_rad is None:
        raise UserError("the start heading is needed: [start] heading_deg or --start-heading-deg")
    start_true_deg = heading_to_compass(pcfg.start_heading_rad, 0.0)  # true: no declination
    odo = list(can_inputs(log, setup.profile))
    if len(odo) < 2:
        raise UserError(f"{log}: no wheel odometry decoded with profile {setup.profile!r}")
    readings = [h for h in nmea_inputs(nmea, odo[0].t_s, 5.0) if not h.is_true]
    if not readings:
        raise UserError(f"{nmea}: no magnetic compass readings (HDG/HDM)")
    # The card must give reading + deviation + mounting = magnetic: fit against magnetic -
    # mounting, i.e. shift the reference by the mounting offset as if it were declination.
    ref = reference_headings_from_odometry(
        [m.t_s for m in odo],
        [m.d_left_m for m in odo],
        [m.d_right_m for m in odo],
        track_m=pcfg.estimator.track_m,
        start_true_heading_deg=float(start_true_deg),
        declination_deg=pcfg.declination_deg + pcfg.mounting_offset_deg,
    )
    try:
        return calibrate_from_drive(
            [h.t_s for h in readings], [h.heading_deg for h in readings], ref
        )
    except ValueError as exc:
        raise UserError(str(exc)) from None


def card(result: FitResult) -> list[float]:
    c = result.calibration
    return [round(v, 2) for v in (c.a_deg, c.b_deg, c.c_deg, c.d_deg, c.e_deg)]


def register(sub: Any) -> None:
    p = sub.add_parser(
        "calibrate",
        help="fit the compass deviation card, or the wheel scale, from a calibration drive",
        description=(
            "Fit the compass deviation card (A + B sin h + C cos h + D sin 2h + E cos 2h) from a "
            "calibration drive: a CAN log and a time-stamped NMEA capture, starting at a known "
            "true heading. Best: two slow circles in a car park, one each way. With "
            "--distance-m (or --points), the wheel-speed scale from a drive of known length "
            "(docs/estimation.md)."
        ),
    )
    p.add_argument("log", type=Path, help="the drive's CAN log (candump .log, .asc, .blf)")
    p.add_argument("--nmea", type=Path, default=None, help="the compass capture (time-stamped)")
    p.add_argument("--config", required=True, help="the car's TOML (profile, start, place)")
    p.add_argument("--profile", default=None, help="CAN profile (default: the config's)")
    p.add_argument(
        "--start-heading-deg",
        type=number,
        default=None,
        help="true heading at the start, clockwise from north (default: [start])",
    )
    p.add_argument(
        "--write",
        action="store_true",
        help="write the card into the config, the wheel scale into the learned file",
    )
    calibrate_scale.add_arguments(p)
    calibrate_track.add_arguments(p)
    p.add_argument("--json", action="store_true", help="last stdout line: the result as JSON")
    p.set_defaults(func=_cli)


def _cli(args: argparse.Namespace) -> int:
    scale = calibrate_scale.wanted(args)
    track = args.turned_deg is not None
    if args.nmea is None and not scale and not track:
        raise UserError("give --nmea (the compass card), --distance-m/--points (wheel scale) "
                        "or --turned-deg (effective track)")  # fmt: skip
    doc: dict[str, Any] = {}
    if track:  # checked (and refused) before anything is written
        res_track = calibrate_track.track_calibration(args.log, args)
        text, doc["turn_scale"] = calibrate_track.summary(res_track)
        sys.stdout.write(text)
    if scale:  # checked (and refused) before anything is written
        res_scale = calibrate_scale.scale_calibration(args.log, args)
        text, doc["wheel_scale"] = calibrate_scale.summary(res_scale)
        sys.stdout.write(text)
    if args.nmea is not None:
        doc.update(_card_cli(args))
    if scale:
        if args.write:
            sys.stdout.write(calibrate_scale.write_scale(res_scale, args) + "\n")
        else:
            sys.stdout.write("wheel scale not written: add --write to put it into the car's "
                             "learned parameters\n")  # fmt: skip
        doc["wheel_scale"]["written"] = bool(args.write)
    if track:
        if args.write:
            sys.stdout.write(calibrate_track.write_track(res_track, args) + "\n")
        else:
            sys.stdout.write("turn scale not written: add --write to put it into the car's "
                             "learned parameters\n")  # fmt: skip
        doc["turn_scale"]["written"] = bool(args.write)
    moving = compass_mount_note(args)
    if moving:
        sys.stdout.write(f"note: {moving}\n")
    doc["compass_offset_moves"] = bool(moving)
    if args.json:
        sys.stdout.write(json.dumps(doc) + "\n")
    return 0


def compass_mount_note(args: argparse.Namespace) -> str:
    """The learned file's word on the compass mount (``compass_mount.warning``), or ""."""
    from guidance.app.config import load_config
    from guidance.app.learned_file import load_learned
    from guidance.core.localize.compass_mount import warning

    cfg = load_config(args.config, require_goal=False)
    path = getattr(args, "learned", None)
    if path is None and cfg.checkpoint.learned_path:
        path = Path(cfg.checkpoint.learned_path)
    if path is None:
        return ""
    params, _ = load_learned(Path(path), cfg.vehicle_id)
    return "" if params is None else warning(params.compass_drives)


def _card_cli(args: argparse.Namespace) -> dict[str, Any]:
    config = Path(args.config)
    res = calibrate(
        args.log, args.nmea, args.config, profile=args.profile,
        start_heading_deg=args.start_heading_deg,
    )  # fmt: skip
    values = card(res)
    w = sys.stdout.write
    w(
        f"compass deviation card ({res.terms}): A {values[0]:+.2f}, B {values[1]:+.2f}, "
        f"C {values[2]:+.2f}, D {values[3]:+.2f}, E {values[4]:+.2f} deg\n"
        f"residual {res.residual_rms_deg:.2f} deg rms, {res.residual_max_deg:.2f} deg max; "
        f"{res.n_used} readings used, {res.n_outliers} outliers; "
        f"heading coverage {res.coverage_deg:.0f} deg\n"
    )
    if res.note:
        w(f"note: {res.note}\n")
    if args.write:
        target = write_card(config, values)
        via = f" (the file it links to: {target})" if target != config.absolute() else ""
        w(f"written to {config} as [compass] deviation_deg{via}\n")
    else:
        w(f"not written: add --write to put it into {config}\n")
    return {
        "deviation_deg": values,
        "terms": res.terms,
        "residual_rms_deg": res.residual_rms_deg,
        "residual_max_deg": res.residual_max_deg,
        "n_used": res.n_used,
        "n_outliers": res.n_outliers,
        "coverage_deg": res.coverage_deg,
        "note": res.note,
        "written": bool(args.write),
    }
