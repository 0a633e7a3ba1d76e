"""One codec for the processed inputs: message <-> record (the recorder, replay, the schemas).

Every input the pipeline takes is recorded on one topic (``TOPICS``) as a JSON object made of
its dataclass fields, and decoded back by the same table: ``to_record`` and ``from_record`` are
inverses by construction (a round-trip property test checks each type), and ``schema`` derives
the topic's JSON Schema from the same fields. The scene topic carries two message types,
told apart by ``kind``; its wire format is pinned by the committed replay recording
(tests/data/replay), so field names never change.
"""

from __future__ import annotations

import dataclasses
import functools
import types
import typing
from collections.abc import Mapping
from typing import Any

from guidance.core.messages import (
    Approach,
    CancelReport,
    CompassHeading,
    GoalUpdate,
    HeadingFix,
    IntersectionScene,
    LandmarkFix,
    TurnCompleted,
    WheelOdometry,
    YawRate,
)
from guidance.errors import checked_number

InputMessage = (
    WheelOdometry
    | CompassHeading
    | HeadingFix
    | LandmarkFix
    | IntersectionScene
    | TurnCompleted
    | CancelReport
    | Approach
    | GoalUpdate
    | YawRate
)

TOPICS: dict[type, str] = {
    WheelOdometry: "/odometry",
    CompassHeading: "/compass",
    HeadingFix: "/heading",
    LandmarkFix: "/landmark_fix",
    IntersectionScene: "/scene",
    TurnCompleted: "/scene",
    CancelReport: "/scene",
    Approach: "/approach",
    GoalUpdate: "/goal",
    YawRate: "/yaw_rate",
}
"""Message type -> the topic it is recorded on (the one table)."""

SCENE_KINDS: dict[str, type] = {
    "intersection": IntersectionScene,
    "turn": TurnCompleted,
    "cancel": CancelReport,
}
_SCENE_EMPTY: dict[str, Any] = {
    "exit_headings_rad": [],
    "distance_m": None,
    "labels": [],
    "heading_change_rad": None,
    "source": "",
}


class CodecError(ValueError):
    """A record that does not decode into its topic's message (a damaged or foreign file)."""


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def to_record(msg: InputMessage) -> tuple[str, dict[str, Any]]:
    """(topic, JSON-able dict) of one input message."""
    topic = TOPICS[type(msg)]
    body: dict[str, Any] = {}
    for f in dataclasses.fields(msg):
        v = getattr(msg, f.name)
        body[f.name] = list(v) if isinstance(v, tuple) else v
    if topic == "/scene":
        kind = next(k for k, c in SCENE_KINDS.items() if c is type(msg))
        fields = {k: v for k, v in body.items() if k != "t_s"}
        body = {"t_s": msg.t_s, "kind": kind, **_SCENE_EMPTY, **fields}
    return topic, body


def _coerce(value: Any, hint: Any, where: str) -> Any:
    """A JSON value as the field's type: finite floats, ints, bools, strings, tuples, optional."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _coerce(value, inner, where)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise CodecError(f"{where}: expected a list, got {type(value).__name__}")
        return tuple(_coerce(v, args[0], where) for v in value)
    if hint is bool:
        if not isinstance(value, bool):
            raise CodecError(f"{where}: expected true/false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise CodecError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is float:
        return checked_number(value, where, error=CodecError)
    if hint is str:
        if not isinstance(value, str):
            raise CodecError(f"{where}: expected a string, got {value!r}")
        return value
    raise CodecError(f"{where}: no decoder for {hint!r}")  # pragma: no cover - table is fixed


def message_type(topic: str, data: Mapping[str, Any]) -> type | None:
    """The message type a record of ``topic`` holds (None: not an input topic)."""
    if topic == "/scene":
        cls = SCENE_KINDS.get(str(data.get("kind")))
        if cls is None:
            raise CodecError(f"/scene: unknown kind {data.get('kind')!r}")
        return cls
    return next((c for c, t in TOPICS.items() if t == topic), None)


def from_record(topic: str, data: Mapping[str, Any]) -> InputMessage | None:
    """The message a record holds; None for a topic that is not a processed input.

    Raises ``CodecError`` (a ValueError) for a record that is missing fields or holds values
    of the wrong type, NaN or infinity: replay reports it instead of feeding it on."""
    if not isinstance(data, Mapping):
        raise CodecError(f"{topic}: a record must be an object, not {type(data).__name__}")
    cls = message_type(topic, data)
    if cls is None:
        return None
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        where = f"{topic}.{f.name}"
        if f.name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise CodecError(f"{where}: missing")
            continue
        kwargs[f.name] = _coerce(data[f.name], hints[f.name], where)
    msg: InputMessage = cls(**kwargs)
    return msg


_JSON_TYPES = {float: "number", int: "integer", bool: "boolean", str: "string"}


@dataclasses.dataclass(frozen=True, slots=True)
class Doc:
    """JSON Schema keywords a type cannot say, beside it: ``Annotated[float, doc(minimum=0)]``."""

    keywords: Mapping[str, Any]


def doc(**keywords: Any) -> Doc:
    return Doc(keywords)


def json_schema(hint: Any) -> dict[str, Any]:
    """The JSON Schema of a type: numbers, integers, booleans, strings, ``X | None``, lists and
    tuples, tables (``dict[str, X]``), ``Literal`` strings, ``TypedDict`` objects (their
    required keys required) and ``Annotated[X, doc(...)]``. The one generator of the inputs'
    schemas (``schema``) and the outputs' (``guidance.outputs.schemas``)."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Annotated:
        out = json_schema(args[0])
        for meta in args[1:]:
            if isinstance(meta, Doc):
                out.update(meta.keywords)
        return out
    if origin in (typing.Union, types.UnionType) and type(None) in args:
        (inner,) = [a for a in args if a is not type(None)]
        s = json_schema(inner)
        return {**s, "type": [s["type"], "null"]}
    if origin in (tuple, list):
        return {"type": "array", "items": json_schema(args[0])}
    if origin in (dict, Mapping):
        if args[1] is Any:
            return {"type": "object"}
        return {"type": "object", "additionalProperties": json_schema(args[1])}
    if origin is typing.Literal:
        return {"type": "string", "enum": list(args)}
    if typing.is_typeddict(hint):
        hints = typing.get_type_hints(hint, include_extras=True)
        props = {k: json_schema(_required_arg(h)) for k, h in hints.items()}
        out = {"type": "object", "properties": props}
        required = [k for k in hints if k in hint.__required_keys__]
        return {**out, "required": required} if required else out
    return {"type": _JSON_TYPES[hint]}


def _required_arg(hint: Any) -> Any:
    """``NotRequired[X]``/``Required[X]`` as ``X`` (the TypedDict says which keys are)."""
    if typing.get_origin(hint) in (typing.NotRequired, typing.Required):
        return typing.get_args(hint)[0]
    return hint


_field_schema = json_schema


def schema(topic: str) -> dict[str, Any]:
    """The JSON Schema of a processed-input topic, from the message fields."""
    classes = [c for c, t in TOPICS.items() if t == topic]
    if not classes:
        raise KeyError(topic)
    props: dict[str, Any] = {}
    required: list[str] = ["t_s"]
    for cls in classes:
        hints = _hints(cls)
        for f in dataclasses.fields(cls):
            props[f.name] = {**_field_schema(hints[f.name]), "description": _describe(f.name)}
            if len(classes) == 1 and f.default is dataclasses.MISSING:
                required.append(f.name)
    if topic == "/scene":
        props["kind"] = {"type": "string", "enum": list(SCENE_KINDS)}
        required.append("kind")
    title = "guidance." + topic.strip("/").replace("/", ".")
    return {
        "$schema": "http://json-schema.org/draft-07/schema#",
        "title": title,
        "type": "object",
        "properties": props,
        "required": sorted(set(required), key=required.index),
    }


def _describe(name: str) -> str:
    if name == "t_s":
        return "car monotonic clock (or simulated time), s"
    unit = name.rsplit("_", 1)[-1] if "_" in name else ""
    units = {"m": "metres", "rad": "radians", "deg": "degrees", "s": "seconds"}
    return units.get(unit, name.replace("_", " "))
