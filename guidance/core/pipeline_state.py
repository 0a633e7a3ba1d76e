"""The pipeline's own bookkeeping as a dataclass, so a checkpoint is mechanical (``asdict`` out,
field by field back in), and the descriptor that keeps ``pipeline.odometer_m`` and friends as
plain attributes for their readers (ARCHITECTURE.md change 5)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Generic, TypeVar, overload

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

    @classmethod
    def from_snapshot(cls, snap: Mapping[str, object]) -> PipelineState:
        """Each field from ``snap`` (checked by ``check_snapshot`` first) as its own type."""
        out = cls()
        for f in fields(cls):
            if f.name in snap:
                kind = type(getattr(out, f.name))
                setattr(out, f.name, kind(snap[f.name]))
        return out


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
