"""The pipeline's own bookkeeping as a dataclass, so a checkpoint is mechanical (``asdict`` out,
field by field back in), and the descriptor that keeps ``pipeline.odometer_m`` and friends as
plain attributes for their readers (ARCHITECTURE.md change 5)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Generic, TypeVar, overload

from guidance.core.snapshot_check import (
    MAX_ODOMETER_M,
    MAX_SPEED_MPS,
    SnapshotError,
    integer,
    number,
)

if TYPE_CHECKING:
    from guidance.core.pipeline import Pipeline


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
            if isinstance(default, bool):
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


V = TypeVar("V")


class _InState(Generic[V]):
    """A public Pipeline attribute kept in its ``PipelineState`` (``pipeline.odometer_m``)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, objtype: type | None = None) -> _InState[V]: ...
    @overload
    def __get__(self, obj: Pipeline, objtype: type | None = None) -> V: ...
    def __get__(self, obj: Pipeline | None, objtype: type | None = None) -> V | _InState[V]:
        if obj is None:
            return self
        value: V = getattr(obj.st, self.name)
        return value

    def __set__(self, obj: Pipeline, value: V) -> None:
        setattr(obj.st, self.name, value)
