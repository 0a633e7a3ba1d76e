"""The pipeline's own bookkeeping as data (ARCHITECTURE-2.md change 5): ``PipelineState`` is
everything a checkpoint carries (``asdict`` out, field by field back in, each checked by its
type), ``Transient`` what a restart rightly forgets. Readers use ``pipeline.st.odometer_m``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields

from guidance.core.messages import WheelOdometry
from guidance.core.snapshot_check import (
    MAX_ODOMETER_M,
    MAX_SPEED_MPS,
    SnapshotError,
    integer,
    number,
)

MAX_WARNED = 64
"""Inputs the driver may have been warned about (a checkpoint's list is refused beyond)."""
MAX_LANDMARKS_SAID = 100_000


@dataclass(slots=True)
class PipelineState:
    """The pipeline's own bookkeeping: with the estimator, the navigator's memory, the turn
    detector and the pending decision, everything a checkpoint carries. ``snapshot`` writes it
    with ``asdict`` and ``restore`` reads it back field by field: nothing is forgotten."""

    heading_known: bool = True
    odometer_m: float = 0.0
    speed_mps: float = 0.0
    landmark_updates: int = 0
    prompt_count: int = 0
    arrived: bool = False
    finished: bool = False
    lost_said: bool = False
    uncertain_said: bool = False
    chance_said: bool = False
    placed: bool = True
    """The position has been known since the start or found since (False: "start anywhere",
    until the first landmark)."""
    waiting_said: bool = False
    """"Waiting for the first odometry" has been said."""
    warned: list[str] = field(default_factory=list)
    """Inputs the driver has been warned about (by the pipeline or in the driver's words)."""
    landmark_said: dict[str, float] = field(default_factory=dict)
    """Landmark id (as text: JSON's keys) -> message time its name was last said. Message
    times: a restore on another clock forgets them (``Pipeline.restore``)."""

    @classmethod
    def from_snapshot(cls, snap: Mapping[str, object]) -> PipelineState:
        """Each field from ``snap``, checked by its own type (a bool is true or false, a count
        a non-negative integer, a number finite and within its bounds): ``SnapshotError``
        names the first bad one. A field added later is checked without another list."""
        out = cls()
        for f in fields(cls):
            if f.name not in snap:
                continue
            v = snap[f.name]
            default = getattr(out, f.name)
            if isinstance(default, list):
                v = _names(v, f.name)
            elif isinstance(default, dict):
                v = _times(v, f.name)
            elif isinstance(default, bool):
                if not isinstance(v, bool):
                    raise SnapshotError(f"{f.name} must be true or false, not {type(v).__name__}")
            elif isinstance(default, int):
                v = integer(v, f.name)
            else:
                v = number(v, f.name, *_BOUNDS.get(f.name, (-MAX_NUMBER, MAX_NUMBER)))
            setattr(out, f.name, v)
        return out


_BOUNDS = {"odometer_m": (0.0, MAX_ODOMETER_M), "speed_mps": (-MAX_SPEED_MPS, MAX_SPEED_MPS)}
"""A number field's bounds in a checkpoint (others: finite and at most ``MAX_NUMBER``)."""
MAX_NUMBER = 1e12


def _names(v: object, name: str) -> list[str]:
    if not isinstance(v, list) or len(v) > MAX_WARNED:
        raise SnapshotError(f"{name} must be a list of at most {MAX_WARNED} names")
    if not all(isinstance(x, str) and 0 < len(x) <= 64 for x in v):
        raise SnapshotError(f"{name} must hold input names (text of 1-64 characters)")
    return sorted(set(v))


def _times(v: object, name: str) -> dict[str, float]:
    if not isinstance(v, Mapping) or len(v) > MAX_LANDMARKS_SAID:
        raise SnapshotError(f"{name} must be a table of at most {MAX_LANDMARKS_SAID} entries")
    out = {}
    for k, t in v.items():
        if not isinstance(k, str) or not k.lstrip("-").isdigit() or len(k) > 20:
            raise SnapshotError(f"{name}: {k!r} is not a landmark id")
        out[k] = number(t, f"{name}[{k}]", -MAX_NUMBER, MAX_NUMBER)
    return out


@dataclass(slots=True)
class Transient:
    """What a restart rightly forgets (not in a checkpoint): an odometry message held back for
    the reorder window, the dead reckoning through a gap, the input times (``restore`` sets
    them again from the estimator's time on the same clock) and when the next state and
    health evaluations are due."""

    held_odometry: WheelOdometry | None = None
    dr_to_t: float | None = None
    """Dead reckoning through an odometry gap: the time it has reached (None: no gap)..."""
    dr_m: float = 0.0
    """...and the distance it has moved the estimate."""
    last_t: float | None = None
    last_odo_t: float | None = None
    next_state_t: float = float("-inf")
    next_health_t: float = float("-inf")
