"""``guidance sim``: its options checked before anything starts, and a stop on a signal that
ends the drive with its summary (issue 14, item 13).

``check_drive_options`` turns every option a drive cannot use (a negative or 70-bit seed,
``inf``/``nan`` densities, durations and distances, a speed of 1e-300, a camera at -1 Hz, an
``--out`` that is a file) into one ``UserError`` line, before the world is built; a drive
asked for ``--duration inf`` would otherwise never end, and ``--out /etc/passwd`` failed only
after the whole drive. ``stop_on_signals`` makes SIGINT and SIGTERM end the drive loop, so the
summary is printed and the recording closed with its summary and footer.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
from pathlib import Path
from typing import Any

from guidance.errors import UserError, checked_number

MAX_SEED = 2**32 - 1


def _finite(name: str, value: Any, lo: float, hi: float, *, lo_open: bool = False) -> None:
    checked_number(value, name, lo, hi, lo_open=lo_open)


def check_drive_options(opts: Any) -> None:
    """Raise one ``UserError`` line for the first option a drive cannot use."""
    seed = opts.seed
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise UserError(f"--seed must be an integer in [0, {MAX_SEED}], not {seed!r}")
    _finite("--density", opts.density_per_km2, 0.0, 1000.0)
    _finite("--detection-rate", opts.detection_rate, 0.0, 1.0)
    if opts.speed is not None:
        _finite("--speed", opts.speed, 0.01, 1e6)
    if opts.duration_s is not None:
        _finite("--duration", opts.duration_s, 0.0, 1e7, lo_open=True)
    _finite("--decision-distance", opts.decision_distance_m, 0.0, 10_000.0, lo_open=True)
    if opts.camera_hz is not None:
        _finite("--camera", opts.camera_hz, 0.0, 100.0, lo_open=True)
    if opts.compass_deg is not None:
        _finite("--compass-deg", opts.compass_deg, 0.0, 180.0, lo_open=True)
    _finite("area_km2", opts.area_km2, 0.0, 10_000.0, lo_open=True)
    _finite("goal_min_m", opts.goal_min_m, 0.0, 1e6)
    _finite("goal_max_m", opts.goal_max_m, 0.0, 1e6, lo_open=True)
    _finite("checkpoint interval", opts.checkpoint_interval_s, 0.0, 1e6, lo_open=True)
    for name, window in (
        ("--can-silent", opts.can_silent),
        ("--compass-garbage", opts.compass_garbage),
    ):
        if window is not None:
            _finite(f"{name} start", window[0], 0.0, 1e7)
            _finite(f"{name} duration", window[1], 0.0, 1e7)
    check_out_folder(Path(opts.out))
    if opts.voice_to:
        check_out_folder(Path(opts.voice_to).parent or Path("."), what="--voice-to")


def check_out_folder(path: Path, what: str = "--out") -> None:
    """The folder exists (made here) and can be written; else one line, before the drive."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise UserError(f"{what} {path}: exists and is not a folder") from None
    except OSError as exc:
        raise UserError(f"{what} {path}: cannot be created ({exc.strerror or exc})") from None
    if not path.is_dir():
        raise UserError(f"{what} {path}: not a folder")
    if not os.access(path, os.W_OK | os.X_OK):
        raise UserError(f"{what} {path}: not writable")


def stop_on_signals() -> asyncio.Event:
    """An event set by SIGINT or SIGTERM (on the running loop, main thread only): the drive
    loop ends as at its end (outcome "stopped"), so the summary, PNG and recording complete."""
    event = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError, RuntimeError, NotImplementedError):
            loop.add_signal_handler(sig, event.set)
    return event
