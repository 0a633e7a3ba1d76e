"""One car's learned-parameters file (``guidance.core.localize.learned``): JSON, atomic, versioned.

Written with the checkpoint's ``write_atomic`` (temp file, fsync, rename: a SIGKILL leaves the
old file or the new one, never a mix). Read with every value checked; a file that fails (not
JSON, larger than ``MAX_BYTES``, another schema, a value out of the physical bounds of
``guidance.core.localize.state_limits``, another vehicle's) is refused with one line and
the car starts from its priors, so a damaged or tampered file never makes it confident.

The running car and the tools share the file through a lock (``LearnedLock``, an advisory
``flock`` on ``<file>.lock`` beside it, which holds the holder's pid): the car holds it from
start to stop, and a tool that writes the file (``guidance calibrate --write``) takes it for
its read-modify-write or refuses, naming the car's pid. Without it the car's periodic save
would silently overwrite a calibration written while it drives with its own older value.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import stat
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from guidance import files
from guidance.app.checkpoint import remove_stale_temps, write_atomic
from guidance.core.localize import compass_mount
from guidance.core.localize.learned import LearnedParams
from guidance.core.localize.state_limits import FUTURE_TOLERANCE_S

if TYPE_CHECKING:  # the car's first stage; what reads the file alone does not load it
    from guidance.core.localize.localizer import Localizer

MAX_BYTES = files.KINDS["learned"].max_bytes
"""The file is a few hundred bytes; a larger one (or ``/dev/zero``) is not read."""


def load_learned(
    path: Path, vehicle_id: str, now_unix_s: float | None = None
) -> tuple[LearnedParams | None, str | None]:
    """(the parameters, None), or (None, the one line why they were refused); (None, None)
    when there is no file yet. Given ``now_unix_s`` (the wall clock: the car, a tool), a file
    saved more than ``FUTURE_TOLERANCE_S`` after it is refused: its age, which widens it, is
    unknown (a replay of an old log passes None: its clock is the log's)."""
    if not os.path.lexists(path):
        return None, None
    try:
        data = files.read_json(path, "learned")
    except files.FileRefused as exc:
        return None, f"{exc}: starting from the priors"
    if not isinstance(data, dict):
        return (
            None,
            f"{path}: learned parameters refused (not a JSON object): starting from the priors",
        )
    try:
        params = LearnedParams.from_dict(data)
    except ValueError as exc:
        return None, f"{path}: learned parameters refused ({exc}): starting from the priors"
    if now_unix_s is not None and params.saved_unix_s > now_unix_s + FUTURE_TOLERANCE_S:
        ahead_d = (params.saved_unix_s - now_unix_s) / 86400.0
        return None, (
            f"{path}: learned parameters refused (saved {ahead_d:.1f} days after this clock's "
            "now: their age is unknown): starting from the priors"
        )
    if params.vehicle_id != vehicle_id:
        return None, (
            f"{path}: learned parameters are vehicle {params.vehicle_id!r}'s, not "
            f"{vehicle_id!r}: starting from the priors"
        )
    return params, None


class LearnedLock:
    """An exclusive claim on one learned-parameters file (``<file>.lock``, ``flock``).

    ``LearnedLock.take(path)`` returns the lock, or raises ``LearnedBusy`` naming the holder's
    pid when another process (the running car, or a tool mid-write) has it. Released by
    ``release()`` or when the process ends, however it ends (the kernel drops a ``flock`` with
    its last descriptor), so a SIGKILLed car never leaves the file locked."""

    def __init__(self, path: Path, fd: int) -> None:
        self.path = path
        self._fd: int | None = fd

    @staticmethod
    def lock_path(path: Path) -> Path:
        return path.with_name(path.name + ".lock")

    @classmethod
    def take(cls, path: Path) -> LearnedLock:
        lock = cls.lock_path(path)
        try:
            lock.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
        except OSError as exc:
            raise LearnedBusy(f"{lock}: cannot open the lock ({exc.strerror})") from None
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise LearnedBusy(f"{lock}: not a regular file")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise LearnedBusy(
                    f"{path} is in use by a running car (pid {_holder(fd)})"
                ) from None
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except BaseException:
            os.close(fd)
            raise
        return cls(path, fd)

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None

    def __enter__(self) -> LearnedLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class LearnedBusy(Exception):
    """The learned file is held by another process (its message names the pid)."""


def _holder(fd: int) -> str:
    with contextlib.suppress(OSError, ValueError):
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
        if text.isdigit():
            return text
    return "unknown"


def save_learned(path: Path, params: LearnedParams) -> None:
    """Write atomically: readers see the old file or the new one."""
    write_atomic(path, (json.dumps(params.to_dict(), indent=1) + "\n").encode())


def start_from_learned(
    localizer: Localizer,
    path: Path,
    vehicle_id: str,
    now_unix_s: float,
    *,
    wall_clock: bool = True,
) -> tuple[LearnedParams | None, str]:
    """Start a fresh car's first stage from the file (widened for the time since, adopted by
    ``Localizer.adopt``): what was used, and one line saying so (or why not). ``wall_clock``:
    ``now_unix_s`` is the wall clock (the car), so a file saved in the future is refused; a
    replay's is the log's."""
    remove_stale_temps(path)  # a save a SIGKILL cut short
    params, refused = load_learned(path, vehicle_id, now_unix_s if wall_clock else None)
    if params is None:
        return None, refused or f"{path}: no learned parameters yet: starting from the priors"
    used = params.widened(now_unix_s, localizer.config.estimator)
    localizer.adopt(used)
    days = max(0.0, now_unix_s - params.saved_unix_s) / 86400.0
    bias = (
        ""
        if used.compass_bias_deg is None or used.compass_bias_sigma_deg is None
        else f", compass bias {used.compass_bias_deg:+.1f} +- {used.compass_bias_sigma_deg:.1f} deg"
    )
    turn = (
        ""
        if used.turn_scale is None or used.turn_scale_sigma is None
        else f", turn scale {100 * used.turn_scale:+.2f} +- {100 * used.turn_scale_sigma:.2f} %"
    )
    moving = compass_mount.warning(params.compass_drives) if bias else ""
    return used, (
        f"{path}: starting from learned parameters ({params.distance_m / 1000:.1f} km, "
        f"{days:.1f} days old): wheel scale {100 * used.scale:+.2f} +- "
        f"{100 * used.scale_sigma:.2f} %, left/right {100 * used.diff:+.3f} +- "
        f"{100 * used.diff_sigma:.3f} %{bias}{turn}" + (f"; {moving}" if moving else "")
    )


def counter_after_resume(
    path: Path, vehicle_id: str, odometer_m: float
) -> LearnedParams | None:
    """A resumed trip's ``before`` (its state already carries what was learned): the file's
    distance counter, less the trip's odometer so far, which the periodic saves of this trip
    already added (at most one ``learned_interval_s`` of driving is lost, never the file's
    history: a crash-resume once restarted 12,000 km at 2.4 m). Temp files a SIGKILL left
    beside the file are removed here too."""
    remove_stale_temps(path)
    params, _ = load_learned(path, vehicle_id)
    if params is None:
        return None
    return replace(params, distance_m=max(0.0, params.distance_m - max(0.0, odometer_m)))


def save_after(
    localizer: Localizer,
    path: Path,
    vehicle_id: str,
    now_unix_s: float,
    driven_m: float,
    before: LearnedParams | None,
) -> LearnedParams | None:
    """Save what the first stage knows now (``Localizer.learned``; nothing for the paper
    model)."""
    params = localizer.learned(vehicle_id, now_unix_s, driven_m, before)
    if params is not None:
        save_learned(path, params)
    return params
