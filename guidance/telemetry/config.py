"""The ``[telemetry]`` table: endpoints, mode, TLS (no zenoh)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from guidance.config_tables import from_table, rule
from guidance.core.geo import Origin
from guidance.errors import UserError
from guidance.telemetry.keys import (
    _ENDPOINT_RE,
    _MODES,
    DEFAULT_CONNECT,
    DEFAULT_LISTEN,
    validate_vehicle_id,
)


# -- configuration --------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TlsConfig:
    """TLS for ``tls/`` endpoints: this node's certificate and the CA that signs its peers.

    ``certificate``/``private_key`` are presented when listening and, with
    ``mutual`` (mTLS), also when connecting; mTLS is what lets an access-control
    policy name peers by certificate common name.
    """

    root_ca_certificate: str = field(metadata=rule(path=True))
    certificate: str = field(default="", metadata=rule(path=True))
    private_key: str = field(default="", metadata=rule(path=True))
    mutual: bool = False
    verify_name_on_connect: bool = True

    def as_zenoh(self) -> dict[str, Any]:
        tls: dict[str, Any] = {
            "root_ca_certificate": self.root_ca_certificate,
            "enable_mtls": self.mutual,
            "verify_name_on_connect": self.verify_name_on_connect,
        }
        if self.certificate:
            tls["listen_certificate"] = self.certificate
            tls["listen_private_key"] = self.private_key
            if self.mutual:
                tls["connect_certificate"] = self.certificate
                tls["connect_private_key"] = self.private_key
        return tls


@dataclass(frozen=True, slots=True)
class TelemetryConfig:
    """The ``[telemetry]`` table of the car's TOML config (docs/telemetry.md).

    ``mode="peer"`` (default) listens on ``listen`` (loopback) and monitors
    connect to it; ``mode="client"`` connects to a zenoh router at ``connect``.
    ``zenoh_config`` names an optional zenoh JSON5 file loaded first, for what
    this table does not cover (``access_control``, ``transport/auth``); the keys
    of this table then override mode, endpoints, scouting and TLS.
    """

    enabled: bool = True
    vehicle_id: str = "car1"
    mode: str = field(default="peer", metadata=rule(choices=_MODES))
    listen: tuple[str, ...] = (DEFAULT_LISTEN,)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    zenoh_config: str = field(default="", metadata=rule(path=True))
    tls: TlsConfig | None = None
    allow_remote_goal: bool = False
    max_goal_range_m: float = 50_000.0
    """Goals farther than this from the origin (the start) are refused."""
    retry_period_s: float = 2.0
    fifo_size: int = 32
    """Decisions and prompts waiting to be sent, per kind; the oldest is dropped beyond."""
    join_if_taken: bool = field(default=False, metadata=rule(read=False))
    """Peer mode: when another process holds the listen endpoint, join it as a peer from a
    free port instead of staying down (``publisher.join_taken``). Not a ``[telemetry]`` key:
    the simulator sets it, so drives side by side are all seen; a car keeps its endpoint."""
    origin_lat_lon_deg: tuple[float, float] | None = field(default=None, metadata=rule(read=False))
    """WGS-84 origin of the local frame, for the state's ``lat_deg``/``lon_deg``. Not a
    ``[telemetry]`` key: the app's config sets it from ``[start]`` (the simulator from its
    city)."""

    def __post_init__(self) -> None:
        validate_vehicle_id(self.vehicle_id)
        if self.origin_lat_lon_deg is not None:  # a place on Earth
            Origin.checked(self.origin_lat_lon_deg)
        if self.mode not in _MODES:
            raise UserError(f"telemetry mode must be one of {_MODES}, not {self.mode!r}")
        for ep in (*self.listen, *self.connect):
            check_endpoint(ep)
        if self.mode == "client" and not self.connect:
            raise UserError("telemetry mode 'client' needs connect endpoints (the router)")
        if not (self.retry_period_s > 0 and self.max_goal_range_m > 0 and self.fifo_size > 0):
            raise UserError("telemetry retry_period_s, max_goal_range_m, fifo_size must be > 0")

    @classmethod
    def from_mapping(
        cls, table: Mapping[str, Any], base_dir: Path | None = None
    ) -> TelemetryConfig:
        """Build from a parsed ``[telemetry]`` TOML table (``guidance.config_tables``): unknown
        keys and bad types are errors; relative file paths are taken from ``base_dir`` (the TOML
        file's folder); ``listen``/``connect`` may be one string."""
        return from_table(cls, table, "telemetry", base_dir)


def check_endpoint(endpoint: str) -> str:
    """A zenoh endpoint looks like ``tcp/127.0.0.1:7447``; say so clearly if it does not."""
    if not _ENDPOINT_RE.match(endpoint):
        raise UserError(
            f"bad zenoh endpoint {endpoint!r}: expected <protocol>/<address>, "
            "e.g. tcp/127.0.0.1:7447 or tls/localhost:7447"
        )
    return endpoint


_ROS_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True, slots=True)
class Ros2Config:
    """The ``[ros2]`` table (off by default): where and under which names the car speaks
    ROS 2. ``connect`` is rmw_zenoh's default router; ``mode`` peer or client."""

    enabled: bool = False
    domain_id: int = 0
    namespace: str = "/guidance"
    node: str = "guidance"
    mode: str = field(default="peer", metadata=rule(choices=_MODES))
    connect: tuple[str, ...] = (DEFAULT_CONNECT,)
    listen: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not 0 <= self.domain_id <= 232:
            raise UserError(f"domain_id must be 0-232 (ROS_DOMAIN_ID), not {self.domain_id}")
        parts = [p for p in self.namespace.split("/") if p]
        if not self.namespace.startswith("/") or not all(_ROS_NAME.match(p) for p in parts):
            raise UserError(f"namespace {self.namespace!r} is not a ROS namespace (/a/b)")
        if not _ROS_NAME.match(self.node):
            raise UserError(f"node {self.node!r} is not a ROS node name")
        for ep in (*self.connect, *self.listen):
            if not _ENDPOINT_RE.match(ep):
                raise UserError(f"bad zenoh endpoint {ep!r}")
