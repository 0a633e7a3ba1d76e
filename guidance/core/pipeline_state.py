"""The core's bookkeeping as data (ARCHITECTURE-2.md change 5, split by stage in issue 37):
``LocalizeState``, ``PlanState`` and ``PipelineState`` are everything a checkpoint carries
besides the filter, the navigator and the road ahead (``asdict`` out, field by field back in,
each checked by its type), ``Transient`` what a restart rightly forgets. Readers use
``pipeline.estimate.odometer_m``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import TypeVar

from guidance.config_tables import rule, rule_of
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


class _Checked:
    """A state read back from a checkpoint field by field (``from_snapshot``)."""

    __slots__ = ()

    @classmethod
    def from_snapshot(cls: type[_S], snap: Mapping[str, object]) -> _S:
        """Each field from ``snap``, checked by its own type (a bool is true or false, a count
        a non-negative integer, a number finite and within its field's ``rule``): ``SnapshotError``
        names the first bad one. A field added later is checked without another list."""
        out = cls()
        for f in fields(cls):  # type: ignore[arg-type]
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
                r = rule_of(cls, f.name)  # the field's own bounds, else finite and moderate
                lo = -MAX_NUMBER if r.lo is None else r.lo
                v = number(v, f.name, lo, MAX_NUMBER if r.hi is None else r.hi)
            setattr(out, f.name, v)
        return out


_S = TypeVar("_S", bound=_Checked)


@dataclass(slots=True)
class LocalizeState(_Checked):
    """What the estimate is read with (``Localizer``): with the filter's x and P, what a
    checkpoint carries of the first stage."""

    heading_known: bool = True
    odometer_m: float = field(default=0.0, metadata=rule(lo=0.0, hi=MAX_ODOMETER_M))
    speed_mps: float = field(default=0.0, metadata=rule(lo=-MAX_SPEED_MPS, hi=MAX_SPEED_MPS))
    landmark_updates: int = 0


@dataclass(slots=True)
class PlanState(_Checked):
    """What the planner has said and concluded (``Planner``): with the navigator's memory,
    the turn detector and the intersections ahead, what a checkpoint carries of the second
    stage."""

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
    landmark_said: dict[str, float] = field(default_factory=dict)
    """Landmark id (as text: JSON's keys) -> message time its name was last said. Message
    times: a restore on another clock forgets them (``Pipeline.restore``)."""


@dataclass(slots=True)
class PipelineState(_Checked):
    """The sequencer's own bookkeeping (``Pipeline``): the prompts said and the inputs the
    driver was warned about. A checkpoint holds the three states' fields side by side
    (``asdict`` out, ``from_snapshot`` back in): nothing is forgotten."""

    prompt_count: int = 0
    warned: list[str] = field(default_factory=list)
    """Inputs the driver has been warned about (by the pipeline or in the driver's words)."""


MAX_NUMBER = 1e12
"""A number field without bounds of its own is at most this large in a checkpoint."""


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
    """What a restart rightly forgets of the first stage (not in a checkpoint): an odometry
    message held back after a gap, the dead reckoning through a gap and the last odometry time
    (``restore`` sets it again from the estimator's time on the same clock)."""

    held_odometry: WheelOdometry | None = None
    dr_to_t: float | None = None
    """Dead reckoning through an odometry gap: the time it has reached (None: no gap)..."""
    dr_m: float = 0.0
    """...and the distance it has moved the estimate."""
    last_odo_t: float | None = None
