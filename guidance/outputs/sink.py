"""The one output path: ``MessageSink.publish(kind, t_s, build)`` (no zenoh, no mcap).

Telemetry (``guidance.telemetry.publisher``) and the recorder (``guidance.recording.writer``)
are both sinks: each keeps its own queue policy behind ``publish`` (latest-value slots and short
FIFOs for telemetry, a bounded FIFO for the recorder) and binds its vehicle id and sequence
numbers into ``build``. What each output *is* is one row of ``guidance.outputs.kinds.OUTPUTS``;
``send`` encodes any of them the same way.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import replace
from functools import partial
from typing import Any

from guidance.core.messages import Health
from guidance.outputs.kinds import HEALTH, HealthReport, OutputContext, OutputKind

Build = Callable[..., Mapping[str, Any]]
"""Builds one message; the sink passes ``vehicle_id``, ``seq`` and ``wall_time_unix_s``."""
NO_CONTEXT = OutputContext()


class MessageSink(ABC):
    """Where outputs go. Subclasses implement ``publish`` (and may report ``own_health``)."""

    origin_lat_lon_deg: tuple[float, float] | None = None
    """WGS-84 origin of the local frame: state messages then carry latitude/longitude."""

    @abstractmethod
    def publish(self, kind: str, t_s: float, build: Build) -> bool:
        """Queue one message of ``kind``; never blocks; False when it was refused or dropped."""

    def own_health(self) -> Health | None:
        """This sink's own health, added (under its name) to the health messages it carries."""
        return None

    def send(self, kind: OutputKind, item: Any, context: OutputContext = NO_CONTEXT) -> bool:
        """One output of ``kind`` (a row of ``OUTPUTS``), encoded when the sink builds it; a
        health report also carries this sink's own health."""
        if kind is HEALTH and isinstance(item, HealthReport):
            own = self.own_health()
            if own is not None:
                item = replace(item, components={**item.components, own.name: own})
        if context.origin_lat_lon_deg is None and self.origin_lat_lon_deg is not None:
            context = replace(context, origin_lat_lon_deg=self.origin_lat_lon_deg)
        return self.publish(kind.name, kind.t_s(item), partial(kind.encode, item, context))
