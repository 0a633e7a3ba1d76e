"""Crash recovery: the pipeline's state written atomically every few seconds (issue 7).

A checkpoint is one small JSON file: the estimator (pose, covariance, time), the navigator's
memory (remembered intersections, exits taken, mode, passed landmarks), the pending decision
and counters (``Pipeline.snapshot``), plus whatever the caller adds under ``extra`` (the
simulation stores its world's seed and route so far). It is written to a temporary file in the
same folder, flushed, fsynced and renamed over the old one with ``os.replace``: a reader (the
restarted process) sees the previous checkpoint or the new one, never half of one, even after
``kill -9`` or a power cut in the middle of a write.

The interval is measured on the message clock, so an accelerated simulation checkpoints as
often per simulated minute as the car does per real minute.

A checkpoint is checked before it is trusted (issue 14): it names the vehicle, the trip (goal,
start and a digest of the pipeline's configuration) and the software version (``identity``);
a clean stop marks it ``finished``. ``load_checkpoint`` moves a damaged, invalid or foreign
file aside (renamed ``<name>.rejected-<time>``), logs why and returns None, so one bad file
never stops a start; ``Pipeline.restore`` checks every value of the state itself.

``resume_from_checkpoint`` is how a run resumes, for the car and the simulated drive alike:
load, the caller's policy (the car's age limit, the simulator's seed and method), the caller's
restore, and a state it refuses moved aside.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import logging
import math
import os
import stat
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from guidance import files
from guidance.errors import UserError

log = logging.getLogger(__name__)

SCHEMA = "guidance.checkpoint/2"
MAX_BYTES = files.KINDS["checkpoint"].max_bytes
"""A checkpoint is a few kB to a few hundred kB; anything larger is not read."""


def trip_identity(vehicle_id: str, pipeline_config: Mapping[str, Any]) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: vehicle, trip and software version.

    ``pipeline_config`` is ``PipelineConfig.describe()``: the goal and start come from it, and
    its digest changes with any other setting (landmarks, method, estimator)."""
    from guidance.version import version

    text = json.dumps(pipeline_config, sort_keys=True, default=str)
    return {
        "vehicle_id": vehicle_id,
        "software_version": version(),
        "trip": {
            "goal_xy_m": _listed(pipeline_config.get("goal_xy_m", [])),
            "start_xy_m": list(pipeline_config.get("start_xy_m", [])),
            "config_digest": hashlib.sha256(text.encode()).hexdigest()[:16],
        },
    }


def _listed(xy: Any) -> list[Any] | None:
    """A point as the identity holds it; None: no goal."""
    return None if xy is None else list(xy)


class Checkpointer:
    """Writes checkpoints to ``path`` at most every ``interval_s`` of message time."""

    def __init__(
        self,
        path: str | Path,
        interval_s: float = 5.0,
        identity: Mapping[str, Any] | None = None,
    ) -> None:
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise UserError(f"checkpoint interval must be > 0 s, not {interval_s!r}")
        self.path = Path(path)
        self.identity = dict(identity) if identity is not None else None
        self.interval_s = interval_s
        self.resumed = False
        """This run continues a trip from the checkpoint (``start_checkpoints``)."""
        self.extra: Callable[[], Mapping[str, Any]] | None = None
        """What else a checkpoint carries (the simulator: its world), under ``extra``."""
        self.saved = 0
        self.errors = 0
        self._next_t = -math.inf
        self._failing = False
        remove_stale_temps(self.path)  # a write a SIGKILL cut short in an earlier run

    def due(self, t_s: float) -> bool:
        return t_s >= self._next_t

    def maybe_save(self, t_s: float, state: Mapping[str, Any]) -> bool:
        """Save when due; True when written."""
        if not self.due(t_s):
            return False
        return self.save(t_s, state)

    def save(self, t_s: float, state: Mapping[str, Any], *, finished: bool = False) -> bool:
        """Write now (atomically). A failure (disk full, read-only) is logged once, not raised.

        ``finished``: the run stopped cleanly; the next start does not resume this one."""
        self._next_t = t_s + self.interval_s
        doc = {
            "schema": SCHEMA,
            "identity": self.identity,
            "finished": finished,
            "t_s": t_s,
            "wall_time_unix_s": time.time(),
            **state,
        }
        try:
            write_atomic(self.path, json.dumps(doc, allow_nan=False).encode())
        except (OSError, ValueError) as exc:
            self.errors += 1
            if not self._failing:
                self._failing = True
                log.warning("checkpoint %s not written: %s", self.path, exc)
            return False
        if self._failing:
            self._failing = False
            log.warning("checkpoint %s written again", self.path)
        self.saved += 1
        return True


def write_atomic(path: Path, data: bytes, mode: int = 0o644) -> None:
    """Write ``data`` to ``path`` so that readers see the old or the new content, never a mix;
    the new file gets ``mode`` (less the umask).

    The temporary file is removed on every error path (a full disk, a size limit, a signal).
    Only a regular file (or a link) is replaced: a FIFO, a device or a folder at ``path`` is not
    the product's to delete (issue 40): ``OSError``, which the callers log once."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        kind = os.lstat(path).st_mode
        if not (stat.S_ISREG(kind) or stat.S_ISLNK(kind)):
            raise OSError(errno.EEXIST, "not a regular file: not replaced", str(path))
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    try:
        try:
            view = memoryview(data)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


STALE_TEMP_AGE_S = 600.0
"""A temporary file of ``write_atomic`` older than this is stale whoever holds its pid (a write
takes milliseconds; the pid may have been reused)."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    except (OverflowError, ValueError):
        return False
    return True


def remove_stale_temps(path: str | Path) -> int:
    """Remove what ``write_atomic`` left beside ``path`` when a SIGKILL or a power cut ended
    it mid-write (``.<name>.<pid>.tmp``): those whose process is gone, this process's own (it
    has no write in flight when it starts), and any older than ``STALE_TEMP_AGE_S``. A live
    process's fresh one is left alone. Returns how many were removed (each is logged)."""
    p = Path(path)
    prefix = f".{p.name}."
    removed = 0
    try:
        candidates = [q for q in p.parent.iterdir() if q.name.startswith(prefix)]
    except OSError:
        return 0
    for tmp in candidates:
        pid_text = tmp.name[len(prefix) : -len(".tmp")]
        if not (tmp.name.endswith(".tmp") and pid_text.isdigit()):
            continue
        try:
            age_s = time.time() - tmp.lstat().st_mtime
        except OSError:
            continue
        pid = int(pid_text)
        if pid != os.getpid() and _alive(pid) and age_s < STALE_TEMP_AGE_S:
            continue
        try:
            tmp.unlink()
        except OSError as exc:
            log.warning("stale temporary file %s not removed: %s", tmp, exc.strerror or exc)
            continue
        removed += 1
        log.warning("removed %s, left by an interrupted write (process %d)", tmp.name, pid)
    return removed


def set_aside(path: str | Path, why: str) -> Path | None:
    """Rename a checkpoint that must not be resumed to ``<name>.rejected-<time>`` and log why;
    the new path, or None when it could not be moved (then it is only ignored)."""
    p = Path(path)
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
    dest = p.with_name(f"{p.name}.rejected-{stamp}")
    n = 1
    while dest.exists():
        n += 1
        dest = p.with_name(f"{p.name}.rejected-{stamp}-{n}")
    try:
        os.replace(p, dest)
    except OSError as exc:
        log.warning("checkpoint %s ignored: %s (could not move it aside: %s)", p, why, exc)
        return None
    log.warning("checkpoint %s ignored: %s; moved aside to %s", p, why, dest.name)
    return dest


def identity_mismatch(found: object, expected: Mapping[str, Any]) -> str:
    """Why a checkpoint's identity is not this run's, or "" when it is."""
    if not isinstance(found, dict):
        return "it names no vehicle or trip"
    if found.get("vehicle_id") != expected.get("vehicle_id"):
        return f"it is from vehicle {str(found.get('vehicle_id'))[:40]!r}, not this one"
    if found.get("software_version") != expected.get("software_version"):
        return (
            f"it was written by version {str(found.get('software_version'))[:40]!r}, "
            f"this is {expected.get('software_version')!r}"
        )
    trip, want = found.get("trip"), expected.get("trip")
    if not isinstance(trip, dict) or not isinstance(want, dict):
        return "it names no trip"
    if trip.get("goal_xy_m") != want.get("goal_xy_m"):
        return "the goal changed since (another trip)"
    if trip.get("start_xy_m") != want.get("start_xy_m"):
        return "the start changed since (another trip)"
    if trip.get("config_digest") != want.get("config_digest"):
        return "the configuration changed since"
    return ""


def load_checkpoint(
    path: str | Path, expected: Mapping[str, Any] | None = None
) -> dict[str, Any] | None:
    """The checkpoint at ``path`` if it may be resumed, else None.

    None when there is none or the last run finished cleanly; a damaged file, one of another
    schema, vehicle, trip or version (when ``expected`` names them) is moved aside and logged.
    """
    p = Path(path)
    try:
        raw = files.read_bytes(p, "checkpoint")
    except files.FileRefused as exc:
        if exc.code == "too_large":
            set_aside(p, f"it is {exc.why}")
        elif exc.code != "missing":  # a FIFO, a folder, a device: not ours to move
            log.warning("%s: starting afresh", exc)
        return None
    try:
        doc = files.parse_json(raw)
    except ValueError as exc:
        set_aside(p, f"it is damaged ({str(exc)[:80]})")
        return None
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        set_aside(p, f"it is not a {SCHEMA} file")
        return None
    if expected is not None:
        why = identity_mismatch(doc.get("identity"), expected)
        if why:
            set_aside(p, why)
            return None
    if doc.get("finished") is True:
        log.info("checkpoint %s: the last run stopped cleanly; starting afresh", p)
        return None
    if not isinstance(doc.get("pipeline"), dict):
        set_aside(p, "it holds no pipeline state")
        return None
    return doc


def checkpoint_age_s(doc: Mapping[str, Any], now_unix_s: float) -> float:
    """Seconds since the checkpoint was written; inf when its time is missing or not a number."""
    t = doc.get("wall_time_unix_s")
    if isinstance(t, bool) or not isinstance(t, int | float):
        return math.inf
    try:
        age = now_unix_s - float(t)
    except OverflowError:
        return math.inf
    return age if math.isfinite(age) else math.inf


RESUMED = "resumed"
NO_CHECKPOINT = "no checkpoint"
INVALID = "invalid"
RESTORE_ERRORS: tuple[type[Exception], ...] = (
    ValueError,
    KeyError,
    TypeError,
    IndexError,
    AttributeError,
)
"""What restoring a damaged or hostile state raises: ``Pipeline.restore``'s ``SnapshotError``
(a ``ValueError``, raised before anything changes) and what the caller's own state raises (a
world replayed to a step that is not a number)."""


@dataclass(frozen=True, slots=True)
class Resumption:
    """What ``resume_from_checkpoint`` did: ``outcome`` is ``RESUMED``, ``NO_CHECKPOINT``, the
    caller's policy's reason not to ("too old"), or ``INVALID`` (``why``: what the restore
    refused; the file was moved aside and the run starts afresh)."""

    outcome: str
    why: str = ""

    @property
    def resumed(self) -> bool:
        return self.outcome == RESUMED


def resume_from_checkpoint(
    path: str | Path,
    restore: Callable[[dict[str, Any]], object],
    *,
    expected: Mapping[str, Any] | None = None,
    policy: Callable[[dict[str, Any]], str] | None = None,
) -> Resumption:
    """Resume from the checkpoint at ``path``: the mechanics the car and the simulated drive
    share, each with its own policy and state.

    The file is loaded (``load_checkpoint``: none, a clean stop, or a damaged file, or with
    ``expected`` a foreign one, is nothing to resume; a bad file is moved aside); ``policy(doc)``
    says why this run must not resume it ("" to go on; it may raise to refuse the run
    instead); ``restore(doc)`` applies the state, checking every value before it changes
    anything. A state it refuses (``RESTORE_ERRORS``) is moved aside."""
    doc = load_checkpoint(path, expected)
    if doc is None:
        return Resumption(NO_CHECKPOINT)
    why = policy(doc) if policy is not None else ""
    if why:
        return Resumption(why)
    try:
        restore(doc)
    except RESTORE_ERRORS as exc:
        set_aside(path, f"invalid state: {exc}")
        return Resumption(INVALID, str(exc))
    return Resumption(RESUMED)
