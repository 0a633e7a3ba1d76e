"""``guidance study``: the Monte Carlo studies."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from guidance.errors import UserError

STUDIES = ("range", "landmarks", "interference", "field", "chance")
"""range: without a map; landmarks: with them; interference: range with magnetic zones."""


def register(sub: Any) -> None:
    register_check(sub)
    study = sub.add_parser(
        "study",
        help=f"run a Monte Carlo study ({', '.join(STUDIES)})",
        description="Monte Carlo studies of SPEC section 5; resumable, reproducible from --seed.",
    )
    study.add_argument(
        "which",
        choices=STUDIES,
        help="which study (interference: range with magnetic interference zones; field: the "
        "paper's field protocol, successive goals until lost or 75 min)",
    )
    study.add_argument(
        "--trials-per-condition",
        type=int,
        default=None,
        help="trials per condition (default: 1000 range, 700 landmarks, 500 interference, "
        "200 field)",
    )
    study.add_argument("--out", type=Path, default=None, help="output folder (default out/<study>)")
    study.add_argument("--seed", type=int, default=1, help="study seed (default 1)")
    study.add_argument(
        "--workers", type=int, default=os.cpu_count() or 1, help="local worker processes"
    )
    study.add_argument(
        "--scheduler", default=None, metavar="ADDRESS", help="run on a Dask distributed scheduler"
    )
    study.add_argument("--no-progress", action="store_true", help="no progress bar")
    study.add_argument("--json", action="store_true", help="print summary.json at the end")
    study.add_argument(
        "--check-paper",
        action="store_true",
        help="print the comparison with the paper's figures (also in paper_check.csv)",
    )
    study.add_argument(
        "--relocalise",
        action="store_true",
        help="field study: the relocalising arm (a lost run carries on; a landmark sighted "
        "while lost resets the position around it); default out/field-relocalise",
    )
    study.set_defaults(func=_study)


def _study(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.table import Table

    from hal_sim.params import SimParams
    from hal_sim.studies import DEFAULT_TRIALS, StudyRun

    trials = (
        DEFAULT_TRIALS[args.which]
        if args.trials_per_condition is None
        else args.trials_per_condition
    )
    if args.seed < 0:
        raise UserError("--seed must be a non-negative integer")
    if args.workers < 1:
        raise UserError("--workers must be at least 1")
    if args.relocalise and args.which != "field":
        raise UserError("--relocalise applies to the field study only")
    out = args.out or Path("out") / (args.which + ("-relocalise" if args.relocalise else ""))
    sim = SimParams(relocalise=args.relocalise)
    run = StudyRun(args.which, out, trials, args.seed, args.workers, args.scheduler, sim)
    console = Console(stderr=True)
    if args.no_progress:
        summary = run.run()
    else:
        with Progress(
            TextColumn(f"[bold]{args.which} study[/]"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("chunks"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=console,
            auto_refresh=False,  # no refresh thread: the study forks its workers (studies.py)
        ) as progress:
            bar = progress.add_task(args.which, total=None)
            shown = [0.0]

            def hook(done: int, total: int) -> None:
                progress.update(bar, completed=done, total=total)
                now = time.monotonic()  # drawn at most 10 times a second, and at the end
                if done == total or now - shown[0] >= 0.1:
                    shown[0] = now
                    progress.refresh()

            summary = run.run(hook)
    if args.json:
        print(json.dumps(summary))
        return 0
    _print_summary(console, summary, out, Table)
    if args.check_paper:
        _print_paper_check(console, summary, Table)
    return 0


def _interval(ci: list[float] | None, fmt: str) -> str:
    return "-" if ci is None else f"{fmt.format(ci[0])}-{fmt.format(ci[1])}"


def _print_paper_check(console: Any, summary: dict[str, Any], table_cls: Any) -> None:
    from hal_sim.analysis import paper_check_table

    rows = paper_check_table(summary.get("paper_check", []))
    t = table_cls(title="against the paper (inside: the paper's value in our 95 % interval)")
    for col in ("condition", "quantity", "paper", "ours", "95 % interval", "inside", "within"):
        t.add_column(col, overflow="fold")
    for r in rows:
        ci = f"{r['ci95_low']}-{r['ci95_high']}"
        t.add_row(r["condition"], r["quantity"], r["paper"], r["ours"], ci,
                  r["paper_inside_ci"], r["within_tolerance"])  # fmt: skip
    console.print(t)
    notes = sorted({r["note"] for r in rows if r["note"]})
    console.print("; ".join(notes))
    prov = summary["provenance"]
    commit = prov["commit"] or "no git"
    console.print(
        f"commit {commit}{' (dirty)' if prov['dirty'] else ''}, N = {summary['n_trials']}"
    )


def _print_summary(console: Any, summary: dict[str, Any], out: Path, table_cls: Any) -> None:
    t = table_cls(title=f"{summary['study']} study ({summary['wall_s']:.0f} s)")
    if summary["study"] in ("range", "interference"):
        zones = summary["study"] == "interference"
        cols = [
            "compass 2σ",
            "trials",
            "mean lost km",
            "95 % interval",
            "never lost",
            "fit lost km",
        ]
        if zones:
            cols[1:1] = ["zones", "detector", "rejected/trial"]
            cols += ["truth > 50 m", "max error m", "lost by either km"]
        for col in cols:
            t.add_column(col, justify="right")
        for c in summary["conditions"]:
            comp = "none" if c["compass_2sigma_deg"] is None else f"±{c['compass_2sigma_deg']:g}°"
            mean = "-" if c["mean_lost_km"] is None else f"{c['mean_lost_km']:.2f}"
            fit = "-" if c["fit_lost_km"] is None else f"{c['fit_lost_km']:.1f}"
            ci = c["mean_lost_km_ci95"]
            inter = "-" if ci is None else f"{ci[0]:.2f}-{ci[1]:.2f}"
            row = [comp, str(c["trials"]), mean, inter, f"{c['never_lost_fraction']:.0%}", fit]
            if zones:
                row[1:1] = [
                    f"{c['interference_frac']:.0%}",
                    "on" if c["interference_detection"] else "off",
                    f"{c['interference_rejects_per_trial']:.0f}",
                ]
                either = c["mean_lost_either_km"]
                row += [
                    f"{c['true_lost_fraction']:.0%}",
                    f"{c['mean_max_true_error_m']:.0f}",
                    "-" if either is None else f"{either:.2f}",
                ]
            t.add_row(*row)
    elif summary["study"] == "chance":
        cal = summary["calibration"]
        for col in ("decile", "predicted", "realised", "95 %", "drives"):
            t.add_column(col, justify="right")
        for i, row in enumerate(cal["deciles"], 1):
            t.add_row(str(i), f"{row['predicted']:.0%}", f"{row['realised']:.0%}",
                      _interval(row["realised_ci95"], "{:.0%}"), str(row["drives"]))  # fmt: skip
        t.caption = (
            f"{cal['drives']} held-back drives: largest gap {cal['max_gap'] * 100:.1f} points "
            f"({'within' if cal['within_10_points'] else 'NOT within'} 10); the table is "
            f"{summary['table']} (the car's: guidance/core/plan/chance_table.json)"
        )
    elif summary["study"] == "field":
        for col in ("method", "runs", "goals/run", "lost", "goals ≥ 6.9 km reached", "95 %",
                    "goal km @80%", "95 %", "run km @80%"):  # fmt: skip
            t.add_column(col, justify="right")
        for c in summary["conditions"]:
            far = c["far_leg_success"]
            run = c["run_km_at_80pct"]
            t.add_row(
                c["method"], str(c["runs"]), f"{c['goals_per_run']:.1f}",
                f"{c['lost_fraction']:.0%}", "-" if far is None else f"{far:.0%}",
                _interval(c["far_leg_success_ci95"], "{:.0%}"),
                f"{c['leg_range_km_at_80pct']:.1f}" + ("+" if c["leg_range_censored"] else ""),
                _interval(c["leg_range_km_ci95"], "{:.1f}"),
                "limit" if run is None else f"{run:.1f}",
            )  # fmt: skip
        if summary.get("relocalise"):
            t.caption = "relocalising: " + "; ".join(
                _relocalised(c["method"], c["relocalisation"]) for c in summary["conditions"]
            )
    else:
        for col in ("method", "density/km²", "detection", "success", "95 %", "range@80% km",
                    "driven km"):  # fmt: skip
            t.add_column(col, justify="right")
        for c in summary["conditions"]:
            rng = f"{c['range_km_at_80pct']:.1f}" + ("+" if c["range_censored"] else "")
            t.add_row(
                c["method"],
                f"{c['density_per_km2']:g}",
                f"{c['detection_rate']:.0%}",
                f"{c['success_rate']:.0%}",
                "{:.0%}-{:.0%}".format(*c["success_rate_ci95"]),
                rng,
                f"{c['mean_driven_km']:.1f}",
            )
    console.print(t)
    console.print(f"results in {out}/ (summary.json, trials.csv, figures)")


def _relocalised(method: str, r: dict[str, Any]) -> str:
    """One method's relocalising counts, for the field table's caption."""
    return (
        f"{method}: {r['found_again']} of {r['ever_lost']} lost runs found again "
        f"({_interval(r['found_again_ci95'], '{:.0%}')}), {r['goal_after_lost']} reached a goal "
        f"after, {r['ended_lost']} ended lost, {r['false_relocalisations']} false of "
        f"{r['relocalisations']} relocalisations"
    )


def register_check(sub: Any) -> None:
    """``guidance check-guidance REC``: the truth oracle (``hal_sim.oracle``) on a recorded
    simulated drive."""
    p = sub.add_parser(
        "check-guidance",
        help="check every spoken manoeuvre of a recorded simulated drive against its truth",
        description=(
            "Reads a recording of `guidance sim` (or `guidance run` on the simulated devices) "
            "and checks each turn prompt against the turn the car then made, the spoken "
            "distances against the distance to go, the margin before each turn and repeats. "
            "Exit 0 when all hold, 1 when not."
        ),
    )
    p.add_argument("recording", help="an .mcap file or a folder of rotated files")
    p.add_argument("--json", action="store_true", help="the figures as one JSON line")
    p.set_defaults(func=_cli_check)


def _cli_check(args: argparse.Namespace) -> int:
    from hal_sim.oracle import from_recording

    res = from_recording(args.recording)
    if args.json:
        print(json.dumps({
            "turn_prompts": res.turn_prompts,
            "manoeuvres_checked": res.manoeuvres_checked,
            "wrong": len(res.wrong),
            "distances_checked": res.distances_checked,
            "distances_ok": res.distances_ok,
            "turns": res.turns,
            "unannounced": len(res.unannounced),
            "late": len(res.late),
            "repeats": len(res.repeats),
            "min_margin_s": min(res.margins_s) if res.margins_s else None,
            "damage": res.damage,
            "ok": res.ok(),
        }))  # fmt: skip
    else:
        print(res.summary())
    return 0 if res.ok() else 1
