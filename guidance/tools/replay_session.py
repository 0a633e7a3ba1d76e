"""What ``guidance replay`` reads from a recording, checked at the boundary (issue 14).

A recording is a file from outside: a valid MCAP may carry a ``/session`` record of another
schema, NaN or 1e308 in the pipeline settings, text where numbers belong, a million landmarks.
``pipeline_config_from_session`` rebuilds the ``PipelineConfig`` only from values that are the
right type, finite and within the range the pipeline needs, and otherwise raises one
``UserError`` line naming the setting. ``recording_sessions`` splits a folder into the recorded
sessions (``<prefix>-<YYYYmmdd-HHMMSS>-<NNNN>.mcap``, one per start of the recorder), so each is
replayed on its own instead of merging different drives.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from guidance.config_tables import from_table
from guidance.errors import UserError, checked_number

if TYPE_CHECKING:
    from guidance.core.pipeline import PipelineConfig

MAX_COORD_M = 1e8
MAX_LANDMARKS = 100_000
MAX_VALUE = 1e9
MAX_ITEMS = 64
"""Any other list or table in the record (rates, the deviation card, a config table)."""
POSITIVE = frozenset(
    {
        "track_m",
        "initial_position_sigma_m",
        "initial_heading_sigma_deg",
        "max_wheel_step_m",
        "lost_major_axis_m",
        "compass_gate_chi2",
        "landmark_gate_chi2",
        "compass_two_sigma_deg",
        "state_period_s",
        "straight_after_m",
        "uncertain_warn_m",
        "silence_periods",
        "min_timeout_s",
        "min_turn_rad",
        "window_m",
        "settle_m",
        "settle_tol_rad",
    }
)
"""Settings that must be above zero (a zero track or period divides by zero)."""
INT_LIMITS = {
    "max_intersections": (1, 100_000),
    "max_exits": (1, 64),
    "min_reads_for_validity": (1, 1_000_000),
}
"""Integer settings that size the navigator's arrays (or count reads)."""
RANGES = {
    "declination_deg": (-180.0, 180.0),
    "mounting_offset_deg": (-360.0, 360.0),
    "compass_deviation_deg": (-90.0, 90.0),
    "compass_unusable_after_s": (0.1, 1e6),
    "start_heading_rad": (-7.0, 7.0),
    "state_period_s": (1e-3, 60.0),
    "expected_rates_hz": (1e-3, 1e4),
    "max_reject_fraction": (0.0, 1.0),
}
"""Ranges beyond finite and ``MAX_VALUE`` (a list's or a table's items take its key's)."""
COORDINATES = frozenset({"start_xy_m", "goal_xy_m", "x_m", "y_m"})
_SESSION_FILE = re.compile(r"^(?P<key>.+-\d{8}-\d{6})-\d{4}\.mcap$")
PREFIX = "the recording's /session record: "


def _bad(where: str, key: str, why: str) -> UserError:
    return UserError(f"{PREFIX}[{where}] {key} {why}")


def _limits(v: object, where: str, key: str, name: str) -> None:
    """What the types do not say, checked before the types are read: sizes (a million
    landmarks), finite numbers within ``MAX_VALUE`` or their own range, integers that size
    arrays, settings that must be > 0. ``name`` is the setting a list item or a rate belongs
    to; a value of the wrong type is left to ``from_table``, which names what was expected."""
    if isinstance(v, Mapping):
        if len(v) > (MAX_ITEMS if key else 100):
            raise _bad(where, key, f"has more than {MAX_ITEMS} entries")
        inner = f"{where}.{key}" if key else where
        for k, x in v.items():
            sub = str(k)[:40]
            _limits(x, inner, sub, name if name == "expected_rates_hz" else sub)
    elif isinstance(v, list):
        cap = MAX_LANDMARKS if name == "landmarks" else MAX_ITEMS
        if len(v) > cap:
            raise _bad(where, key, f"must be a list of at most {cap}")
        for i, x in enumerate(v):
            _limits(x, where, f"{key}[{i}]", name)
    elif isinstance(v, int | float) and not isinstance(v, bool):
        if name == "id":
            if abs(v) >= 2**63:
                raise _bad(where, key, "must be a 64-bit integer")
            return
        if name in INT_LIMITS:
            lo, hi = INT_LIMITS[name]
            if not isinstance(v, int) or not lo <= v <= hi:
                raise _bad(where, key, f"must be an integer in [{lo}, {hi}]")
            return
        lim = MAX_COORD_M if name in COORDINATES else MAX_VALUE
        low, high = RANGES.get(name, (-lim, lim))
        positive = name in POSITIVE and low <= 0.0  # > 0 is the binding bound
        checked_number(v, f"[{where}] {key}", 0.0 if positive else low, high, lo_open=positive,
                       error=lambda m: UserError(PREFIX + m))  # fmt: skip


def pipeline_config_from_session(session: Mapping[str, Any]) -> PipelineConfig:
    """Rebuild the pipeline configuration from a recording's ``/session`` record (checked):
    ``PipelineConfig.describe()`` read back by the config loader, so the replay is the car
    that was recorded, ``[health]`` and the turn detector included. A record from before a
    setting existed keeps that setting's default."""
    from guidance.core.pipeline_config import PipelineConfig

    d = session.get("pipeline") if isinstance(session, Mapping) else None
    if not isinstance(d, Mapping):
        raise UserError("the recording's /session record has no pipeline configuration")
    _limits(d, "pipeline", "", "")
    try:
        return from_table(PipelineConfig, d, "pipeline")
    except UserError as exc:
        raise UserError(f"{PREFIX}{str(exc)[:300]}") from None


def recording_sessions(path: Path) -> list[list[Path]]:
    """The recorded sessions of a folder (rotated files of one start together, in order); a
    file is one session. Files not named by the recorder are each a session of their own."""
    if not path.is_dir():
        return [[path]]
    groups: dict[str, list[Path]] = {}
    for f in sorted(path.glob("*.mcap")):
        m = _SESSION_FILE.match(f.name)
        groups.setdefault(m.group("key") if m else f.name, []).append(f)
    if not groups:
        raise UserError(f"no .mcap files in {path}")
    return list(groups.values())


OUTPUT_FIELDS = {
    "/decision": ("t_s", "exit_index", "intersection_id", "exit_heading_rad"),
    "/state": ("t_s", "x_m", "y_m", "heading_rad"),
}


def well_formed_output(topic: str, data: Mapping[str, Any]) -> bool:
    """A recorded decision or state with the fields the comparison reads, each a finite
    number (else it is counted as damaged, never a crash)."""
    for key in OUTPUT_FIELDS[topic]:
        v = data.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float):
            return False
        try:
            if not math.isfinite(v):
                return False
        except OverflowError:
            return False
    return True
