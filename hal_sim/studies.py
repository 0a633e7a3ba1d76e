"""Monte Carlo studies (SPEC section 5): conditions, seeding, parallel runs, resume, outputs.

Trials are grouped in chunks; each chunk is one call of the compiled engine and
is saved to ``OUT/chunks/`` as soon as it finishes, so an interrupted study
resumes where it stopped. Every trial's seed is derived from (study seed,
condition, trial index) alone, so results do not depend on the number of
workers or on where a chunk ran (local processes or a Dask cluster).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from guidance.core.plan.navigator import NavigatorConfig
from guidance.errors import UserError
from hal_sim import engine, params
from hal_sim.params import SimParams
from hal_sim.seeds import trial_seeds as trial_seeds
from hal_sim.study_design import (
    Condition,
    StudyData,
    field_conditions,
    interference_conditions,
    landmark_conditions,
    range_conditions,
)

DEFAULT_TRIALS = {
    "range": 1000,
    "landmarks": 700,
    "interference": 500,
    "field": 200,
    "chance": 200,
}
STUDY_CODES = {
    "range": engine.STUDY_RANGE,
    "interference": engine.STUDY_RANGE,
    "landmarks": engine.STUDY_LANDMARKS,
    "field": engine.STUDY_FIELD,
    "chance": engine.STUDY_CHANCE,
}
"""Condition.study to ``engine.STUDY_*``."""
CHUNK_TRIALS = 25
CHUNK_TRIALS_MAX = 100
"""A condition's trials run in chunks of ``chunk_trials(trials)``: at least CHUNK_TRIALS, at
most CHUNK_TRIALS_MAX, about an eighth of the condition. Each chunk costs the parent a
transfer, a file written and one read back (about 2 ms), so the defaults' 2,260 chunks of
25 cost some 4 s of a 2-core machine; the results do not depend on the chunk size."""


@dataclass(frozen=True, slots=True)
class ChunkTask:
    condition: Condition
    chunk: int
    seeds: np.ndarray = field(compare=False)
    p: np.ndarray = field(compare=False)
    n_samples: int

    @property
    def name(self) -> str:
        return f"{self.condition.key}/{self.chunk:05d}"


def run_chunk(task: ChunkTask) -> tuple[np.ndarray, np.ndarray]:
    """Run one chunk in the compiled engine (top-level so processes and Dask can call it)."""
    study = STUDY_CODES[task.condition.study]
    out: tuple[np.ndarray, np.ndarray] = engine.run_batch(
        task.seeds,
        study,
        task.condition.method.code,
        task.condition.density_per_km2,
        task.p,
        task.n_samples,
    )
    return out


def sample_distances_km(p: np.ndarray, n: int) -> np.ndarray:
    return np.array([engine.sample_distance_m(i, n, p) for i in range(n)]) / 1000.0


def chunk_trials(trials: int) -> int:
    """Trials per chunk for a study of ``trials`` per condition (see CHUNK_TRIALS_MAX)."""
    return max(CHUNK_TRIALS, min(CHUNK_TRIALS_MAX, trials // 8))


def make_tasks(
    conditions: Sequence[Condition], trials: int, seed: int, sim: SimParams
) -> list[ChunkTask]:
    nav = NavigatorConfig()
    tasks = []
    for cond in conditions:
        # the chance study's rows: the major axis, then the estimated distance to go
        n_samples = params.N_SAMPLES * (2 if cond.study == "chance" else 1)
        sim_c = replace(sim, interference_frac=cond.interference_frac)
        est = replace(
            params.estimator_config(sim, cond.compass_two_sigma_deg),
            interference_detection=cond.interference_detection,
        )
        p = params.pack(sim_c, est, nav, cond.detection_rate)
        size = chunk_trials(trials)
        for chunk, first in enumerate(range(0, trials, size)):
            count = min(size, trials - first)
            tasks.append(
                ChunkTask(cond, chunk, trial_seeds(seed, cond.index, first, count), p, n_samples)
            )
    return tasks


# ----------------------------------------------------------------------------- storage
class ChunkStore:
    """Completed chunks on disk: one .npz per chunk, written atomically. The chunks this
    process saved are also kept in memory, as they read back (samples as float32), so that
    collecting them does not read the files again (675 files, half a second, at the landmark
    study's defaults)."""

    def __init__(self, out: Path) -> None:
        self.dir = out / "chunks"
        self.dir.mkdir(parents=True, exist_ok=True)
        self._saved: dict[Path, tuple[np.ndarray, np.ndarray]] = {}

    def path(self, task: ChunkTask) -> Path:
        return self.dir / f"{task.condition.key}__{task.chunk:05d}.npz"

    def has(self, task: ChunkTask) -> bool:
        return self.path(task).exists()

    def save(self, task: ChunkTask, results: np.ndarray, samples: np.ndarray) -> None:
        final = self.path(task)
        tmp = final.with_suffix(".tmp.npz")
        stored = samples.astype(np.float32)
        np.savez(tmp, results=results, samples=stored, seeds=task.seeds)
        os.replace(tmp, final)
        self._saved[final] = (results, stored.astype(float))

    def load(self, task: ChunkTask) -> tuple[np.ndarray, np.ndarray]:
        saved = self._saved.get(self.path(task))
        if saved is not None:
            return saved
        with np.load(self.path(task)) as z:
            if not np.array_equal(z["seeds"], task.seeds):
                raise UserError(f"{self.path(task)} was made with other seeds; use a fresh --out")
            return z["results"], z["samples"].astype(float)


def _check_manifest(out: Path, manifest: dict[str, Any]) -> None:
    path = out / "study.json"
    if path.exists():
        old = json.loads(path.read_text())
        if old != manifest:
            raise UserError(
                f"{out} holds a study with other settings ({path}); use another --out to start over"
            )
    else:
        path.write_text(json.dumps(manifest, indent=2))


# ----------------------------------------------------------------------------- running
ProgressHook = Callable[[int, int], None]


def _warm_up(sim: SimParams) -> None:
    """Compile (or load from cache) once before workers start, so they only load."""
    task = make_tasks(range_conditions()[-1:], 1, 0, sim)[0]
    run_chunk(task)


def _import_outputs() -> None:
    """Import what the outputs need (matplotlib: about a second of the parent's) while the
    workers run the chunks."""
    from hal_sim import analysis, figures, provenance  # noqa: F401


def _can_fork() -> bool:
    """Whether a child may be forked: on a platform with fork, and no other thread running (a
    fork copies none, and a lock one of them holds would stay held in the child)."""
    return hasattr(os, "fork") and threading.active_count() == 1


def execute(
    tasks: Sequence[ChunkTask],
    store: ChunkStore,
    workers: int,
    scheduler: str | None,
    on_progress: ProgressHook | None = None,
    on_started: Callable[[], None] | None = None,
) -> None:
    """Run the chunks not yet on disk, saving each as it completes; ``on_started`` is called
    once the workers run (a local pool: after they are forked).

    The local pool's workers are forked when nothing else runs (``_can_fork``): they start
    with the engine the parent's warm-up loaded, where spawned ones import the package and
    load the compiled engine again (about a second before their first chunk)."""
    todo = [t for t in tasks if not store.has(t)]
    done = len(tasks) - len(todo)
    if on_progress:
        on_progress(done, len(tasks))
    if not todo:
        return
    if scheduler:
        if on_started:
            on_started()
        _execute_dask(todo, store, scheduler, done, len(tasks), on_progress)
        return
    if workers <= 1:
        for t in todo:
            store.save(t, *run_chunk(t))
            done += 1
            if on_progress:
                on_progress(done, len(tasks))
        return
    ctx = get_context("fork" if _can_fork() else "spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        pending: dict[Future[tuple[np.ndarray, np.ndarray]], ChunkTask] = {}
        queue = list(reversed(todo))
        while queue or pending:
            while queue and len(pending) < 2 * workers:
                t = queue.pop()
                pending[pool.submit(run_chunk, t)] = t
            if on_started:  # the first submission started the workers (forked: all of them)
                on_started()
                on_started = None
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for f in finished:
                t = pending.pop(f)
                store.save(t, *f.result())
                done += 1
                if on_progress:
                    on_progress(done, len(tasks))


def _execute_dask(
    todo: Sequence[ChunkTask],
    store: ChunkStore,
    scheduler: str,
    done: int,
    total: int,
    on_progress: ProgressHook | None,
) -> None:
    from distributed import Client, as_completed

    try:
        client = Client(scheduler, timeout="10s")
    except OSError as exc:
        raise UserError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
    try:
        futures = {client.submit(run_chunk, t, pure=False): t for t in todo}
        for f in as_completed(futures):
            t = futures[f]
            store.save(t, *f.result())
            done += 1
            if on_progress:
                on_progress(done, total)
    finally:
        client.close()


# ----------------------------------------------------------------------------- results
def collect(
    tasks: Iterable[ChunkTask], store: ChunkStore, conditions: list[Condition]
) -> StudyData:
    res: dict[str, list[np.ndarray]] = {c.key: [] for c in conditions}
    smp: dict[str, list[np.ndarray]] = {c.key: [] for c in conditions}
    last: ChunkTask | None = None
    for t in tasks:
        r, s = store.load(t)
        res[t.condition.key].append(r)
        smp[t.condition.key].append(s)
        last = t
    # Where the samples are taken depends on the range cap and the first distance alone,
    # the same in every condition.
    sample_km = np.zeros(0) if last is None else sample_distances_km(last.p, last.n_samples)
    return StudyData(
        conditions,
        {k: np.vstack(v) for k, v in res.items()},
        {k: np.vstack(v) for k, v in smp.items()},
        sample_km,
    )


def study_manifest(name: str, trials: int, seed: int, sim: SimParams) -> dict[str, Any]:
    return {"study": name, "trials_per_condition": trials, "seed": seed, "sim": asdict(sim)}


@dataclass
class StudyRun:
    name: str
    out: Path
    trials: int
    seed: int
    workers: int
    scheduler: str | None = None
    sim: SimParams = field(default_factory=SimParams)

    def conditions(self) -> list[Condition]:
        if self.name == "range":
            return range_conditions()
        if self.name == "interference":
            return interference_conditions()
        if self.name == "field":
            return field_conditions()
        if self.name == "chance":
            from hal_sim import chance

            return chance.conditions()
        return landmark_conditions()

    def run(self, on_progress: ProgressHook | None = None) -> dict[str, Any]:
        if self.trials < 1:
            raise UserError("--trials-per-condition must be at least 1")
        self.out.mkdir(parents=True, exist_ok=True)
        _check_manifest(self.out, study_manifest(self.name, self.trials, self.seed, self.sim))
        conditions = self.conditions()
        tasks = make_tasks(conditions, self.trials, self.seed, self.sim)
        store = ChunkStore(self.out)
        t0 = time.monotonic()
        preload = threading.Thread(target=_import_outputs, daemon=True)
        started: Callable[[], None] | None = None
        if any(not store.has(t) for t in tasks):
            if not self.scheduler:
                _warm_up(self.sim)
            if self.scheduler or self.workers > 1:  # the parent waits: import meanwhile
                started = preload.start
        execute(tasks, store, self.workers, self.scheduler, on_progress, started)
        if preload.is_alive():
            preload.join()
        data = collect(tasks, store, conditions)
        summary = self.outputs(data, time.monotonic() - t0)
        return summary

    def parameters(self) -> dict[str, Any]:
        """Every parameter a trial's numbers depend on, besides its seed."""
        conds = self.conditions()
        est = {
            c.key: asdict(params.estimator_config(self.sim, c.compass_two_sigma_deg)) for c in conds
        }
        return {
            "trials_per_condition": self.trials,
            "seed": self.seed,
            "seeding": "numpy SeedSequence([seed, condition index, trial index])",
            "chunk_trials": chunk_trials(self.trials),
            "n_samples": params.N_SAMPLES,
            "sim": asdict(self.sim),
            "navigator": asdict(NavigatorConfig()),
            "estimator": est,
            "conditions": [
                {**asdict(c), "method": c.method.value, "label": c.label} for c in conds
            ],
        }

    def outputs(self, data: StudyData, wall_s: float) -> dict[str, Any]:
        """Summary JSON, tables and figures, each carrying the provenance and N."""
        from hal_sim import analysis, figures, provenance

        drawn: Callable[[], None] = lambda: None  # noqa: E731  (joins a figure drawn aside)
        prov = provenance.provenance()
        n = sum(len(r) for r in data.results.values())
        cap = provenance.caption(prov, self.seed, n, self.trials)
        if self.name in ("range", "interference"):
            summary = analysis.summarise_range(data, self.sim, self.seed)
            if self.name == "range":
                summary["paper_check"] = analysis.paper_check_range(summary)
                fits = [analysis.fit_of(row) for row in summary["conditions"]]
                drawn = _draw_aside(
                    lambda: figures.fig3(data, self.out / "fig3.png", caption=cap, fits=fits)
                )
            else:
                summary["study"] = "interference"
                for c, row in zip(data.conditions, summary["conditions"], strict=True):
                    row["interference_frac"] = c.interference_frac
                    row["interference_detection"] = c.interference_detection
                    r = data.results[c.key]
                    row["interference_rejects_per_trial"] = float(
                        r[:, engine.RES_INTERFERENCE_REJECTS].mean()
                    )
                figures.fig3(
                    data,
                    self.out / "fig_interference.png",
                    title="Range with magnetic interference zones, detector on and off",
                    caption=cap,
                    fits=[analysis.fit_of(row) for row in summary["conditions"]],
                )
        elif self.name == "field":
            from hal_sim import field_study

            summary = field_study.summarise_field(data, self.sim, self.seed)
            summary["paper_check"] = field_study.paper_check_field(summary)
            field_study.fig_field(data, summary, self.out / "fig_field.png", caption=cap)
            field_study.write_field_table(summary, self.out / "field_table.csv", header=cap)
        elif self.name == "chance":
            from hal_sim import chance

            summary = chance.summarise(data, self.out, self.seed, prov, cap)
        else:
            fig4 = self.out / "fig4.png"
            drawn = _draw_aside(
                lambda: figures.fig4(data, fig4, caption=cap, heatmap=False),
                lambda: figures.range_heatmap(
                    data, fig4.with_name(figures.RANGE_HEATMAP_NAME), caption=cap
                ),
            )
            summary = analysis.summarise_landmarks(data, self.seed)
            summary["paper_check"] = analysis.paper_check_landmarks(data, summary, self.seed)
            figures.write_range_table(summary, self.out / "range_at_80pct.csv", header=cap)
        summary["seed"] = self.seed
        summary["n_trials"] = n
        summary["wall_s"] = wall_s
        summary["provenance"] = prov
        summary["parameters"] = self.parameters()
        analysis.write_trials_csv(
            data, self.out / "trials.csv", header=cap, relocalise=self.sim.relocalise
        )
        if "paper_check" in summary:
            analysis.write_paper_check(summary["paper_check"], self.out / "paper_check.csv", cap)
        drawn()
        (self.out / "summary.json").write_text(json.dumps(summary, indent=2))
        return summary


def _draw_aside(*draws: Callable[[], None]) -> Callable[[], None]:
    """Draw figures in forked children, one each, while the parent computes and writes the
    tables (the landmark study's two figures take about 2 s and 1 s of matplotlib, fig3
    about 1 s); returns what waits for them. Drawn here instead when a fork is not safe
    (``_can_fork``)."""
    if not _can_fork():
        for draw in draws:
            draw()
        return lambda: None
    children = [get_context("fork").Process(target=d, name="study-figure") for d in draws]
    for child in children:
        child.start()

    def join() -> None:
        for child in children:
            child.join()
        failed = [c.exitcode for c in children if c.exitcode != 0]
        if failed:
            raise RuntimeError(f"drawing a study figure failed (exit codes {failed})")

    return join
