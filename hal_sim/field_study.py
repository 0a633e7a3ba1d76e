"""``guidance study field``: the paper's field protocol as a study, held against its result.

Each run drives goal after goal (``hal_sim.field``) until lost or the time limit. Two
readings of the paper's field result (80 % success at 6.9 km or more, 0.55 landmarks per
km2, 60 % detection) are reported, each with a 95 % interval:

* per goal (leg): the success of the goals 6.9 km or more away (Wilson), and the leg
  distance at which a logistic fit of success falls to 80 % (bootstrap over runs);
* per run: the distance driven that 80 % of runs reach before being lost (the 20th
  percentile of the distance at which each run is lost, runs that reach the time limit
  counting as never lost; bootstrap over runs).

The relocalising arm (``--relocalise``, ``SimParams.relocalise``): a lost run carries on and
a landmark sighted while lost resets its position. A goal is then reached when the car
arrives, lost on the way or not, and failed when the car was lost on the way and did not
arrive before the time limit; a run is lost for good where the episode still open at the
limit began. ``relocalisation`` in the summary: how many runs were ever lost, how many of
those were found again and reached a goal afterwards, and the false relocalisations.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hal_sim import engine
from hal_sim.analysis import PAPER_FIELD_KM, _row, range_at_success
from hal_sim.params import SimParams
from hal_sim.provenance import bootstrap_mean, wilson_pair

if TYPE_CHECKING:
    from hal_sim.study_design import StudyData

RESAMPLES = 200
RUN_SUCCESS = 0.8


def legs_of(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(run index, leg km, reached) of every recorded leg of a condition's runs."""
    run, col = np.nonzero(np.isfinite(samples))
    v = samples[run, col]
    return run, np.abs(v) / 1000.0, v > 0


def km_at_run_success(lost_km: np.ndarray, target: float = RUN_SUCCESS) -> float:
    """The distance 80 % of runs reach before being lost (inf: more than 80 % never lost)."""
    v = np.where(np.isfinite(lost_km), lost_km, np.inf)
    if len(v) == 0:
        return float("nan")
    return float(np.sort(v)[int(np.floor((1.0 - target) * len(v)))])


def _bootstrap(n_runs: int, seed: int, stat: Any) -> list[float] | None:
    if n_runs < 2:
        return None
    rng = np.random.default_rng([seed, n_runs])
    vals = np.sort([stat(rng.integers(0, n_runs, n_runs)) for _ in range(RESAMPLES)])
    # Order statistics, not np.quantile: a resample with most runs never lost gives inf.
    lo, hi = vals[int(0.025 * (RESAMPLES - 1))], vals[int(np.ceil(0.975 * (RESAMPLES - 1)))]
    return [float(lo), float(hi)]


def summarise_field(data: StudyData, sim: SimParams, seed: int = 0) -> dict[str, Any]:
    conds = []
    for c in data.conditions:
        r = data.results[c.key]
        n = len(r)
        run, leg_km, ok = legs_of(data.samples[c.key])
        lost = r[:, engine.RES_OUTCOME] == engine.OUTCOME_LOST
        end_m = r[:, engine.RES_FINAL_LOST_AT_M] if sim.relocalise else r[:, engine.RES_DRIVEN_M]
        lost_km = np.where(lost, end_m / 1000.0, np.nan)
        far = leg_km >= PAPER_FIELD_KM
        km, censored = range_at_success(leg_km, ok)

        by_run = [np.nonzero(run == i)[0] for i in range(n)]

        def leg_range(idx: np.ndarray, by_run: list[np.ndarray] = by_run,
                      leg_km: np.ndarray = leg_km, ok: np.ndarray = ok) -> float:  # fmt: skip
            take = np.concatenate([by_run[i] for i in idx])
            return range_at_success(leg_km[take], ok[take])[0]

        run80 = km_at_run_success(lost_km)
        extra = {"relocalisation": relocalisation_counts(r)} if sim.relocalise else {}
        conds.append({
            "method": c.method.value,
            "density_per_km2": c.density_per_km2,
            "detection_rate": c.detection_rate,
            "runs": n,
            "legs": len(leg_km),
            "goals_per_run": float(r[:, engine.RES_GOALS].mean()),
            "goal_landmarks_per_run": float(r[:, engine.RES_GOAL_LANDMARKS].mean()),
            "lost_fraction": float(lost.mean()),
            "lost_fraction_ci95": wilson_pair(int(lost.sum()), n),
            "time_limit_fraction": float(
                (r[:, engine.RES_OUTCOME] == engine.OUTCOME_TIMEOUT).mean()
            ),
            "mean_driven_km": float(r[:, engine.RES_DRIVEN_M].mean() / 1000.0),
            "mean_driven_km_ci95": bootstrap_mean(r[:, engine.RES_DRIVEN_M] / 1000.0, seed),
            "leg_success": float(ok.mean()) if len(ok) else None,
            "leg_success_ci95": wilson_pair(int(ok.sum()), len(ok)),
            "far_legs": int(far.sum()),
            "far_leg_success": float(ok[far].mean()) if far.any() else None,
            "far_leg_success_ci95": wilson_pair(int(ok[far].sum()), int(far.sum())),
            "leg_range_km_at_80pct": km,
            "leg_range_censored": censored,
            "leg_range_km_ci95": _bootstrap(n, seed + c.index, leg_range) if len(ok) else None,
            "run_km_at_80pct": None if not np.isfinite(run80) else run80,
            "run_km_ci95": _bootstrap(
                n, seed + 100 + c.index, lambda idx, v=lost_km: km_at_run_success(v[idx])
            ),
            **extra,
        })  # fmt: skip
    return {
        "study": "field",
        "time_limit_min": sim.field_time_limit_min,
        "goal_landmark": sim.field_goal_landmark,
        "relocalise": sim.relocalise,
        "conditions": conds,
    }


def relocalisation_counts(r: np.ndarray) -> dict[str, Any]:
    """The relocalising arm's counts over a condition's runs (``engine.RES_*``): runs ever
    lost; of those, found again (at least one relocalisation) and reaching a goal after their
    first lost, each with its Wilson interval; relocalisations and false ones (the truth
    outside the reset's 2-sigma circle); the distance driven after first lost."""
    ever = np.isfinite(r[:, engine.RES_LOST_AT_M])
    found = ever & (r[:, engine.RES_RELOCALISATIONS] > 0)
    goal_after = ever & (r[:, engine.RES_GOALS_AFTER_LOST] > 0)
    n_ever = int(ever.sum())
    after_km = (r[ever, engine.RES_DRIVEN_M] - r[ever, engine.RES_LOST_AT_M]) / 1000.0
    return {
        "ever_lost": n_ever,
        "found_again": int(found.sum()),
        "found_again_ci95": wilson_pair(int(found.sum()), n_ever),
        "goal_after_lost": int(goal_after.sum()),
        "goal_after_lost_ci95": wilson_pair(int(goal_after.sum()), n_ever),
        "ended_lost": int((r[:, engine.RES_OUTCOME] == engine.OUTCOME_LOST).sum()),
        "lost_episodes": int(r[:, engine.RES_LOST_EPISODES].sum()),
        "relocalisations": int(r[:, engine.RES_RELOCALISATIONS].sum()),
        "false_relocalisations": int(r[:, engine.RES_FALSE_RELOCALISATIONS].sum()),
        "goals_after_lost": int(r[:, engine.RES_GOALS_AFTER_LOST].sum()),
        "mean_km_after_first_lost": float(after_km.mean()) if n_ever else None,
    }


def paper_check_field(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """The paper's field result against each method, in both readings."""
    rows = []
    for c in summary["conditions"]:
        name = f"field, {c['method']}, {c['density_per_km2']:g}/km2, {c['detection_rate']:.0%}"
        far = c["far_leg_success"]
        rows.append(_row(
            "field", name, f"success of goals >= {PAPER_FIELD_KM} km (n={c['far_legs']})", 0.8,
            far, c["far_leg_success_ci95"], 0.8, None if far is None else far >= 0.8,
            "within: ours at least 80 %",
        ))  # fmt: skip
        km = c["leg_range_km_at_80pct"]
        rows.append(_row(
            "field", name, "goal distance at 80 % success, km", f">= {PAPER_FIELD_KM}", km,
            c["leg_range_km_ci95"], PAPER_FIELD_KM, km >= PAPER_FIELD_KM,
            f"within: ours at least {PAPER_FIELD_KM} km" + (" (censored: at least)"
                                              if c["leg_range_censored"] else ""),
        ))  # fmt: skip
        run = c["run_km_at_80pct"]
        ci = c["run_km_ci95"]
        rows.append(_row(
            "field", name, "distance 80 % of runs drive before lost, km", f">= {PAPER_FIELD_KM}",
            run, None if ci is None or not np.isfinite(ci[1]) else ci, PAPER_FIELD_KM,
            run is None or run >= PAPER_FIELD_KM,
            f"within: ours at least {PAPER_FIELD_KM} km"
            + ("" if run is not None else "; no value: over 80 % of runs were never lost"),
        ))  # fmt: skip
    return rows


TABLE_COLUMNS = (
    "method", "runs", "legs", "goals_per_run", "lost_fraction", "time_limit_fraction",
    "mean_driven_km", "leg_success", "far_legs", "far_leg_success", "far_ci95_low",
    "far_ci95_high", "leg_range_km_at_80pct", "leg_range_ci95_low", "leg_range_ci95_high",
    "run_km_at_80pct",
)  # fmt: skip


RELOCALISE_COLUMNS = (
    "ever_lost", "found_again", "goal_after_lost", "ended_lost", "relocalisations",
    "false_relocalisations",
)  # fmt: skip
"""The relocalising arm's columns of ``field_table.csv`` (only when it ran)."""


def write_field_table(summary: dict[str, Any], path: Path, header: str) -> None:
    reloc = bool(summary.get("relocalise"))
    cols = TABLE_COLUMNS + (RELOCALISE_COLUMNS if reloc else ())
    with path.open("w", newline="") as f:
        f.write(f"# {header}\n")
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for c in summary["conditions"]:
            far = c["far_leg_success_ci95"] or [None, None]
            rng = c["leg_range_km_ci95"] or [None, None]
            w.writerow({**c, **c.get("relocalisation", {}), "far_ci95_low": far[0],
                        "far_ci95_high": far[1], "leg_range_ci95_low": rng[0],
                        "leg_range_ci95_high": rng[1]})  # fmt: skip


def fig_field(data: StudyData, summary: dict[str, Any], path: Path, caption: str = "") -> None:
    """One panel per method: goal success against goal distance (pooled 1 km bins, Wilson
    bands), the paper's field result marked; a last panel: the runs not yet lost against
    distance driven."""
    import matplotlib.pyplot as plt

    from hal_sim import figures

    conds = data.conditions
    fig, axes = plt.subplots(1, len(conds) + 1, figsize=(4.2 * (len(conds) + 1), 4.4), dpi=100,
                             squeeze=False)  # fmt: skip
    colours = plt.get_cmap("tab10")
    d_max = 1.0
    for i, c in enumerate(conds):
        ax = axes[0, i]
        _, leg_km, ok = legs_of(data.samples[c.key])
        if len(leg_km):
            d_max = max(d_max, float(leg_km.max()))
        pooled, too_few = figures.success_panel(ax, leg_km, ok, colours(i))
        s = summary["conditions"][i]
        ax.set_title(f"{figures._method_name(c.method)} ({s['legs']} goals)", fontsize=10)
        ax.set_xlabel("Euclidean distance to the goal, km")
        if pooled or too_few:
            ax.text(0.97, 0.04, "bins pooled to ≥ 5 goals" if pooled else "fewer than 5 goals",
                    transform=ax.transAxes, ha="right", fontsize=7, color="0.3")  # fmt: skip
    for ax in axes[0, : len(conds)]:
        ax.set_xlim(0.0, float(np.ceil(d_max)))
    reloc = bool(summary.get("relocalise"))
    axes[0, 0].set_ylabel("Goals reached" if reloc else "Goals reached (never lost on the way)")
    surv = axes[0, -1]
    end = engine.RES_FINAL_LOST_AT_M if reloc else engine.RES_DRIVEN_M  # where lost for good
    for i, c in enumerate(conds):
        r = data.results[c.key]
        lost = r[:, engine.RES_OUTCOME] == engine.OUTCOME_LOST
        km = np.sort(r[lost, end] / 1000.0)
        n = len(r)
        xs = np.concatenate([[0.0], km, [r[:, engine.RES_DRIVEN_M].max() / 1000.0]])
        ys = 1.0 - np.concatenate([[0], np.arange(1, len(km) + 1), [len(km)]]) / n
        surv.step(xs, ys, where="post", color=colours(i), label=figures._method_name(c.method))
    surv.set_xlabel("Distance driven, km")
    surv.set_ylabel("Runs not yet lost for good" if reloc else "Runs not yet lost")
    surv.set_title("Runs (75 min; relocalising)" if reloc else "Runs (75 min or lost)", fontsize=10)
    surv.legend(fontsize=8, loc="lower left")
    for ax in axes[0]:
        ax.set_ylim(0, 1.02)
        ax.axhline(0.8, color="black", lw=0.8, ls="--")
        ax.axvline(PAPER_FIELD_KM, color="0.5", lw=0.8, ls=":")
        ax.plot([PAPER_FIELD_KM], [0.8], marker="*", ms=12, color="crimson", ls="none",
                label="paper (field)")  # fmt: skip
        ax.grid(True, alpha=0.3)
    c0 = conds[0]
    fig.suptitle(
        f"Field protocol: successive goals until lost or {summary['time_limit_min']:g} min, "
        f"{c0.density_per_km2:g} landmarks/km², {c0.detection_rate:.0%} detection, compass "
        f"±{c0.compass_two_sigma_deg:g}° (2σ); ★ paper: 80 % at 6.9 km; bands: 95 % Wilson"
        + (
            "\nrelocalising arm: lost runs carry on, a landmark sighted while lost resets the "
            "position (reached: arrived, lost on the way or not)"
            if reloc
            else ""
        )
    )
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    figures._caption(fig, caption)
    fig.savefig(path)
    plt.close(fig)
