"""Zenoh key expressions, schema tags and vehicle ids."""

from __future__ import annotations

import re

from guidance.errors import UserError
from guidance.outputs.kinds import OUTPUTS
from guidance.outputs.messages import SCHEMA_VERSION

KEY_PREFIX = "guidance"
KINDS = tuple(k.name for k in OUTPUTS)
"""Message kinds published under ``guidance/<vehicle_id>/<kind>`` (the output table's)."""
LATEST_KINDS = frozenset(k.name for k in OUTPUTS if k.policy == "latest")
"""Kinds held in a latest-value slot; the others go through a short FIFO."""
GOAL_SCHEMA = f"guidance.goal/{SCHEMA_VERSION}"
DEFAULT_PORT = 7447
DEFAULT_LISTEN = f"tcp/127.0.0.1:{DEFAULT_PORT}"
DEFAULT_CONNECT = DEFAULT_LISTEN

_VEHICLE_ID_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
_ENDPOINT_RE = re.compile(r"^[a-z][a-z0-9-]*/\S+$")
_MODES = ("peer", "client")


# -- keys and schema tags ---------------------------------------------------------------------
def key_for(vehicle_id: str, kind: str) -> str:
    """The zenoh key of one message kind of one vehicle."""
    return f"{KEY_PREFIX}/{vehicle_id}/{kind}"


def goal_key(vehicle_id: str) -> str:
    return f"{KEY_PREFIX}/{vehicle_id}/cmd/goal"


def liveliness_key(vehicle_id: str) -> str:
    return f"{KEY_PREFIX}/{vehicle_id}"


def parse_key(key: str) -> tuple[str, str] | None:
    """``guidance/<vehicle_id>/<kind>`` -> (vehicle_id, kind); None for any other key."""
    parts = key.split("/")
    if len(parts) != 3 or parts[0] != KEY_PREFIX:
        return None
    return parts[1], parts[2]


def is_vehicle_id(text: str) -> bool:
    """Whether ``text`` is a valid vehicle id (for ids that come from the network: a bad one
    is dropped and counted there, not an error)."""
    return _VEHICLE_ID_RE.fullmatch(text) is not None


def validate_vehicle_id(vehicle_id: str) -> str:
    if not is_vehicle_id(vehicle_id):
        raise UserError(
            f"vehicle id {vehicle_id!r} must be 1-64 characters from A-Z a-z 0-9 _ . - "
            "(it becomes one chunk of a zenoh key)"
        )
    return vehicle_id
