"""Sending a remote goal: to a car that is listening, reliably, or not at all.

A goal is a command, not a stream: a put on ``guidance/<id>/cmd/goal`` from a session whose
link to the car is a few milliseconds old reaches nobody if the car's subscription has not
reached the sender yet (zenoh routes a put only to the subscriptions it knows at that moment),
and a put with the default ``CongestionControl.DROP`` may be dropped under load. So the sender
declares a publisher on the car's goal key (``Reliability.RELIABLE``,
``CongestionControl.BLOCK``, ``Priority.INTERACTIVE_HIGH``), waits until zenoh reports a
matching subscriber (``Publisher.matching_status``: a car declares one only when it allows
remote goals) and only then puts. Whether the car applies the goal is still the car's decision
(its config, range check and access control); the sender learns that it was delivered to a
subscriber, which is all pub/sub can tell it.
"""

from __future__ import annotations

import contextlib
import time

import zenoh

from guidance.outputs.messages import encode
from guidance.telemetry.keys import GOAL_SCHEMA, goal_key, validate_vehicle_id

MATCH_POLL_S = 0.02


def _matching(publisher: zenoh.Publisher) -> bool:
    """Whether a subscriber matches (zenoh 1.x returns a ``MatchingStatus``; its stub says
    ``bool``)."""
    status: object = publisher.matching_status
    return bool(getattr(status, "matching", status))


def send_goal(
    session: zenoh.Session, vehicle_id: str, x_m: float, y_m: float, sn: int, wait_s: float
) -> bool:
    """Put one goal for ``vehicle_id`` once a subscriber for it is known, waiting up to
    ``wait_s``; True if it was put to a matching subscriber, False (nothing put) if none came.
    ``sn`` numbers this sender's goals in the sample's source info (the car logs who sent it)."""
    validate_vehicle_id(vehicle_id)
    body = {"schema": GOAL_SCHEMA, "x_m": float(x_m), "y_m": float(y_m)}
    publisher = session.declare_publisher(
        goal_key(vehicle_id),
        encoding=zenoh.Encoding.APPLICATION_JSON,
        congestion_control=zenoh.CongestionControl.BLOCK,
        priority=zenoh.Priority.INTERACTIVE_HIGH,
        reliability=zenoh.Reliability.RELIABLE,
    )
    try:
        deadline = time.monotonic() + max(0.0, wait_s)
        while not _matching(publisher):
            if time.monotonic() >= deadline:
                return False
            time.sleep(MATCH_POLL_S)
        publisher.put(encode(body), source_info=zenoh.SourceInfo(session.id, sn))
        return True
    finally:
        with contextlib.suppress(zenoh.ZError):
            publisher.undeclare()
