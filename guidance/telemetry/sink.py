"""The one output path: ``MessageSink.publish(kind, t_s, build)`` (no zenoh, no mcap).

Telemetry (``guidance.telemetry.publisher``) and the recorder (``guidance.recording.writer``)
are both sinks: each keeps its own queue policy behind ``publish`` (latest-value slots and short
FIFOs for telemetry, a bounded FIFO for the recorder) and binds its vehicle id and sequence
numbers into ``build``. What each output *is* is written once, here, by ``encode_outputs`` and
the per-kind helpers, on top of the pure encoders of ``guidance.telemetry.messages``. Adding an
output kind is one encoder, one schema and one line in ``encode_outputs``.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import TYPE_CHECKING, Any

from guidance.core.messages import (
    EstimateState,
    ExitTaken,
    Health,
    LandmarkFix,
    Target,
    TurnCompleted,
)
from guidance.telemetry.messages import (
    LandmarkRejection,
    _envelope,
    _num,
    _obj,
    decision_message,
    health_message,
    landmark_message,
    prompt_message,
    state_message,
)

if TYPE_CHECKING:
    from guidance.core.navigator import Decision

Build = Callable[..., dict[str, Any]]
"""Builds one message; the sink passes ``vehicle_id``, ``seq`` and ``wall_time_unix_s``."""


def turn_message(
    turn: TurnCompleted, *, vehicle_id: str, seq: int = 0, wall_time_unix_s: float | None = None
) -> dict[str, Any]:
    """The ``guidance.turn`` message: a turn the driver completed (typed or detected)."""
    msg = _envelope("turn", vehicle_id, seq, turn.t_s, wall_time_unix_s)
    msg.update(
        {
            "heading_change_rad": _num(turn.heading_change_rad),
            "heading_change_deg": _num(math.degrees(turn.heading_change_rad)),
            "source": turn.source,
        }
    )
    return msg


def exit_message(
    taken: ExitTaken, *, vehicle_id: str, seq: int = 0, wall_time_unix_s: float | None = None
) -> dict[str, Any]:
    """The ``guidance.exit`` message: which exit the driver took at a decided intersection,
    and whether it was the advised one (a monitor sees "advice not followed")."""
    d = taken.decision
    msg = _envelope("exit", vehicle_id, seq, taken.t_s, wall_time_unix_s)
    msg.update(
        {
            "intersection_id": int(d.intersection_id),
            "decision_t_s": _num(d.t_s),
            "advised_exit": int(d.exit_index),
            "taken_exit": int(taken.exit_index),
            "followed": bool(taken.followed),
            "source": taken.source,
        }
    )
    return msg


SINK_SCHEMAS: dict[str, dict[str, Any]] = {
    "turn": _obj(
        "guidance.turn",
        {
            "heading_change_rad": {"type": ["number", "null"]},
            "heading_change_deg": {"type": ["number", "null"]},
            "source": {"type": "string"},
        },
    ),
    "exit": _obj(
        "guidance.exit",
        {
            "intersection_id": {"type": "integer"},
            "decision_t_s": {"type": ["number", "null"]},
            "advised_exit": {"type": "integer"},
            "taken_exit": {"type": "integer"},
            "followed": {"type": "boolean"},
            "source": {"type": "string"},
        },
    ),
}
"""Schemas of the output kinds added with the sink (the others: ``MESSAGE_SCHEMAS``)."""


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

    # -- one helper per output kind ------------------------------------------------------------
    def send_state(
        self,
        state: EstimateState,
        *,
        speed_mps: float | None = None,
        target: Target | None = None,
        goal: tuple[float, float] | None = None,
        method: str | None = None,
        mode: str | None = None,
    ) -> bool:
        build = partial(
            state_message, state, speed_mps=speed_mps, target=target, goal=goal, method=method,
            mode=mode, origin_lat_lon_deg=self.origin_lat_lon_deg,
        )  # fmt: skip
        return self.publish("state", state.t_s, build)

    def send_decision(self, decision: Decision) -> bool:
        t = getattr(decision, "t_s", math.nan)  # a bad object fails where it is encoded
        return self.publish("decision", t, partial(decision_message, decision))

    def send_prompt(self, t_s: float, text: str, *, kind: str = "info", priority: int = 0) -> bool:
        return self.publish(
            "prompt", t_s, partial(prompt_message, t_s, text, kind=kind, priority=priority)
        )

    def send_landmark(
        self,
        t_s: float,
        *,
        matches: Sequence[LandmarkFix] = (),
        rejections: Sequence[LandmarkRejection] = (),
        gated: int | None = None,
    ) -> bool:
        build = partial(
            landmark_message, t_s, matches=tuple(matches), rejections=tuple(rejections),
            gated=gated,
        )  # fmt: skip
        return self.publish("landmark", t_s, build)

    def send_health(
        self,
        t_s: float,
        inputs: Mapping[str, Health],
        *,
        components: Mapping[str, Health | Mapping[str, Any]] | None = None,
    ) -> bool:
        comps = dict(components or {})
        own = self.own_health()
        if own is not None:
            comps[own.name] = own
        return self.publish(
            "health", t_s, partial(health_message, t_s, dict(inputs), components=comps)
        )

    def send_turn(self, turn: TurnCompleted) -> bool:
        return self.publish("turn", turn.t_s, partial(turn_message, turn))

    def send_exit(self, taken: ExitTaken) -> bool:
        return self.publish("exit", taken.t_s, partial(exit_message, taken))
