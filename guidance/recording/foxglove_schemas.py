"""The published Foxglove message schemas as JSON Schemas, for our JSON-encoded MCAP channels.

The definitions come from ``foxglove-schemas-protobuf`` (Foxglove's own package of their
message schemas); neither it nor ``foxglove-sdk`` ships JSON Schema files, so the JSON Schema
of a message is generated here from its protobuf descriptor with Foxglove's JSON conventions
(docs.foxglove.dev, "custom schema encodings"): times and durations are ``{sec, nsec}``
objects, bytes are base64 strings (``contentEncoding``), enums their integer values. Every
field is required except proto3 ``optional`` ones, so a message we write is complete; other
properties are allowed, as in Foxglove's own JSON Schemas (the thumbnail keeps its ``t_s``).

``to_protobuf`` parses a JSON message into the official protobuf class (strict: an unknown
field or a wrong type is an error); the tests use it as an independent check.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from functools import cache
from typing import Any

from google.protobuf import json_format
from google.protobuf.descriptor import Descriptor, FieldDescriptor
from google.protobuf.message import Message

_F = FieldDescriptor
_SCALARS: dict[int, dict[str, Any]] = {
    _F.TYPE_DOUBLE: {"type": "number"},
    _F.TYPE_FLOAT: {"type": "number"},
    _F.TYPE_INT32: {"type": "integer"},
    _F.TYPE_INT64: {"type": "integer"},
    _F.TYPE_SINT32: {"type": "integer"},
    _F.TYPE_SINT64: {"type": "integer"},
    _F.TYPE_SFIXED32: {"type": "integer"},
    _F.TYPE_SFIXED64: {"type": "integer"},
    _F.TYPE_UINT32: {"type": "integer", "minimum": 0},
    _F.TYPE_UINT64: {"type": "integer", "minimum": 0},
    _F.TYPE_FIXED32: {"type": "integer", "minimum": 0},
    _F.TYPE_FIXED64: {"type": "integer", "minimum": 0},
    _F.TYPE_BOOL: {"type": "boolean"},
    _F.TYPE_STRING: {"type": "string"},
    _F.TYPE_BYTES: {"type": "string", "contentEncoding": "base64"},
}
_NSEC = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
_TIME = {
    "type": "object",
    "title": "time",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": _NSEC},
    "required": ["sec", "nsec"],
}
_DURATION = {
    "type": "object",
    "title": "duration",
    "properties": {"sec": {"type": "integer"}, "nsec": _NSEC},
    "required": ["sec", "nsec"],
}


def _is_repeated(fd: FieldDescriptor) -> bool:
    rep = getattr(fd, "is_repeated", None)
    return bool(rep) if rep is not None else fd.label == _F.LABEL_REPEATED


def _field(fd: FieldDescriptor, defs: dict[str, Any]) -> dict[str, Any]:
    if fd.type == _F.TYPE_MESSAGE:
        name = fd.message_type.full_name
        if name == "google.protobuf.Timestamp":
            one: dict[str, Any] = dict(_TIME)
        elif name == "google.protobuf.Duration":
            one = dict(_DURATION)
        else:  # each nested message type is defined once (Foxglove resolves internal $refs)
            if name not in defs:
                defs[name] = {}  # reserve first: a type may refer to itself
                defs[name] = _message(fd.message_type, defs)
            one = {"$ref": f"#/definitions/{name}"}
    elif fd.type == _F.TYPE_ENUM:
        one = {
            "title": fd.enum_type.full_name,
            "type": "integer",
            "oneOf": [{"title": v.name, "const": v.number} for v in fd.enum_type.values],
        }
    else:
        one = dict(_SCALARS[fd.type])
    return {"type": "array", "items": one} if _is_repeated(fd) else one


def _message(desc: Descriptor, defs: dict[str, Any]) -> dict[str, Any]:
    return {
        "type": "object",
        "title": desc.full_name,
        "properties": {fd.name: _field(fd, defs) for fd in desc.fields},
        "required": [fd.name for fd in desc.fields if fd.containing_oneof is None],
    }


def _class(name: str) -> type[Message]:
    """``foxglove.LocationFix`` -> the protobuf class from foxglove-schemas-protobuf."""
    short = name.removeprefix("foxglove.")
    module = importlib.import_module(f"foxglove_schemas_protobuf.{short}_pb2")
    cls: type[Message] = getattr(module, short)
    return cls


@cache
def json_schema(name: str) -> dict[str, Any]:
    """The JSON Schema of a Foxglove message, e.g. ``json_schema("foxglove.LocationFix")``."""
    defs: dict[str, Any] = {}
    schema = _message(_class(name).DESCRIPTOR, defs)
    out = {"$schema": "http://json-schema.org/draft-07/schema#", **schema}
    if defs:
        out["definitions"] = defs
    return out


def _to_proto_json(value: Any, desc: Descriptor) -> Any:
    out: dict[str, Any] = {}
    for key, v in value.items():
        fd = desc.fields_by_name.get(key)
        if fd is None or fd.type != _F.TYPE_MESSAGE:
            out[key] = v
            continue
        items = v if _is_repeated(fd) else [v]
        conv = [_convert_one(x, fd.message_type) for x in items]
        out[key] = conv if _is_repeated(fd) else conv[0]
    return out


def _convert_one(v: Any, desc: Descriptor) -> Any:
    if desc.full_name == "google.protobuf.Timestamp":
        from google.protobuf.timestamp_pb2 import Timestamp

        ts = Timestamp(seconds=v["sec"], nanos=v["nsec"])
        return ts.ToJsonString()
    if desc.full_name == "google.protobuf.Duration":
        from google.protobuf.duration_pb2 import Duration

        return Duration(seconds=v["sec"], nanos=v["nsec"]).ToJsonString()
    return _to_proto_json(v, desc) if isinstance(v, Mapping) else v


def to_protobuf(name: str, message: Mapping[str, Any]) -> Message:
    """Parse a JSON message of Foxglove schema ``name`` into the official protobuf class
    (``json_format.ParseError`` on an unknown field or a wrong type)."""
    cls = _class(name)
    return json_format.ParseDict(_to_proto_json(message, cls.DESCRIPTOR), cls())
