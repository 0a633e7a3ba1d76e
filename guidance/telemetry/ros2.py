"""ROS 2 over Zenoh without ROS: the estimate as rmw_zenoh publishes (``[ros2] enabled``).

One more sink of the output table (``guidance.outputs.sink``): the state becomes a
``nav_msgs/Odometry``, a ``geometry_msgs/PoseWithCovarianceStamped`` and a
``sensor_msgs/NavSatFix``; each verified landmark match a ``PoseWithCovarianceStamped``
(``ros2_messages``). On the wire, as rmw_zenoh's design document says (docs/design.md of
ros2/rmw_zenoh, read for this; no ROS installed):

* key ``<domain_id>/<fully qualified topic>/<DDS type name>/<RIHS01 type hash>``;
* payload: CDR with its 4-byte encapsulation header;
* attachment, 33 bytes: sequence number (int64 LE), source time (ns since the epoch, int64
  LE), the GID length (1 byte, 16) and the publisher's 16-byte GID;
* liveliness tokens ``@ros2_lv/<domain>/<session id>/<node id>/<node id>/NN/%/<ns>/<node>``
  for the node and ``@ros2_lv/<domain>/<session id>/<node id>/<entity id>/MP/%/<ns>/<node>/
  <mangled topic>/<type>/<hash>/<qos>`` for each publisher, so ``ros2 topic list`` sees them;
* QoS: reliable over TCP, volatile, keep last 10 (``::,10:,:,:,,``, the defaults in the
  document's examples); a publisher drops rather than blocks (``CongestionControl.DROP``).

Messages are built and put on the caller's thread (CDR of an Odometry: about 11 us), never
waiting: the state comes at 10 Hz.
"""

from __future__ import annotations

import logging
import secrets
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from guidance.errors import UserError
from guidance.outputs.sink import Build, MessageSink
from guidance.telemetry.config import Ros2Config
from guidance.telemetry.ros2_messages import (
    TYPES,
    dds_type_name,
    landmark_to_ros,
    serialize,
    state_to_ros,
    type_hash,
)
from guidance.telemetry.session import _quiet_close, open_session, session_config

log = logging.getLogger(__name__)

QOS = "::,10:,:,:,,"
"""rmw_zenoh's compact QoS of the liveliness token: system defaults, keep last 10."""
ADMIN = "@ros2_lv"
GID_BYTES = 16
RETRY_S = 2.0
"""A session that did not open (client mode, no router yet) is tried again this often."""


def topic_name(config: Ros2Config, topic: str) -> str:
    """The fully qualified topic: ``/guidance/odometry``."""
    return f"{config.namespace.rstrip('/')}/{topic}"


def topic_key(config: Ros2Config, topic: str) -> str:
    """The rmw_zenoh key expression of one of the sink's topics."""
    msgtype = TYPES[topic]
    fq = topic_name(config, topic).lstrip("/")
    return f"{config.domain_id}/{fq}/{dds_type_name(msgtype)}/{type_hash(msgtype)}"


def mangle(name: str) -> str:
    """rmw_zenoh's mangled name: every ``/`` as ``%`` (``%`` alone when empty)."""
    return name.replace("/", "%") or "%"


def attachment(seq: int, t_ns: int, gid: bytes) -> bytes:
    """The 33-byte rmw_zenoh attachment."""
    if len(gid) != GID_BYTES:
        raise ValueError("a GID is 16 bytes")
    return struct.pack("<qqB", seq, t_ns, GID_BYTES) + gid


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source time ns, GID) from an rmw_zenoh attachment."""
    if len(data) != 33 or data[16] != GID_BYTES:
        raise ValueError(f"an rmw_zenoh attachment is 33 bytes with GID length 16, not {data!r}")
    seq, t_ns, _n = struct.unpack_from("<qqB", data)
    return seq, t_ns, bytes(data[17:])


@dataclass(slots=True)
class _Topic:
    publisher: zenoh.Publisher
    gid: bytes
    seq: int = 0


class Ros2Sink(MessageSink):
    """The sink (see the module). ``publish`` returns False when the kind carries nothing for
    ROS 2 or the session is not open."""

    def __init__(self, config: Ros2Config, clock: Callable[[], float] = time.time) -> None:
        self.config = config
        self._clock = clock
        self._session: zenoh.Session | None = None
        self._topics: dict[str, _Topic] = {}
        self._tokens: list[Any] = []
        self._lock = threading.Lock()
        self.published = 0
        self.errors = 0
        self._stop = threading.Event()
        self._retry: threading.Thread | None = None

    def start(self) -> Ros2Sink:
        """Open the session and declare; a router not there yet (client mode) is not the
        car's failure: logged, and retried every ``RETRY_S`` on a thread of its own."""
        try:
            self._open()
        except UserError as exc:
            log.warning("ROS 2 down (retrying every %.0f s): %s", RETRY_S, exc)
            self._retry = threading.Thread(target=self._keep_trying, name="ros2-open", daemon=True)
            self._retry.start()
        return self

    def _keep_trying(self) -> None:
        while not self._stop.wait(RETRY_S):
            try:
                self._open()
            except UserError:
                continue
            log.warning("ROS 2 up")
            return

    def _open(self) -> None:
        cfg = self.config
        session = open_session(
            session_config(mode=cfg.mode, listen=cfg.listen, connect=cfg.connect)
        )
        if self._stop.is_set():
            _quiet_close(session)
            return
        self._session = session
        zid = str(session.zid())
        ns = mangle(cfg.namespace)
        prefix = f"{ADMIN}/{cfg.domain_id}/{zid}/0"
        self._tokens.append(session.liveliness().declare_token(f"{prefix}/0/NN/%/{ns}/{cfg.node}"))
        for eid, topic in enumerate(TYPES, start=10):
            msgtype = TYPES[topic]
            pub = session.declare_publisher(
                topic_key(cfg, topic),
                encoding=zenoh.Encoding.APPLICATION_CDR,
                congestion_control=zenoh.CongestionControl.DROP,
            )
            self._topics[topic] = _Topic(pub, secrets.token_bytes(GID_BYTES))
            self._tokens.append(session.liveliness().declare_token(
                f"{prefix}/{eid}/MP/%/{ns}/{cfg.node}/{mangle(topic_name(cfg, topic))}/"
                f"{dds_type_name(msgtype)}/{type_hash(msgtype)}/{QOS}"
            ))  # fmt: skip
        names = ", ".join(topic_name(cfg, t) for t in TYPES)
        log.info("ROS 2: %s on domain %d, node %s, zenoh %s", names, cfg.domain_id, cfg.node, zid)

    def close(self) -> None:
        self._stop.set()
        retry, self._retry = self._retry, None
        if retry is not None:
            retry.join(RETRY_S + 5.0)
        session, self._session = self._session, None
        self._topics.clear()
        self._tokens.clear()
        if session is not None:
            _quiet_close(session)

    def publish(self, kind: str, t_s: float, build: Build) -> bool:
        if kind not in ("state", "landmark") or self._session is None:
            return False
        with self._lock:
            self.published += 1
            seq = self.published
        message = build(vehicle_id=self.config.node, seq=seq, wall_time_unix_s=self._clock())
        if kind == "state":
            items = list(state_to_ros(message).items())
        else:
            items = [("landmark_fix", m) for m in landmark_to_ros(message)]
        sent = False
        for topic, ros in items:
            sent = self._put(topic, ros) or sent
        return sent

    def _put(self, topic: str, ros: Any) -> bool:
        entry = self._topics.get(topic)
        if entry is None:
            return False
        stamp = ros.header.stamp
        entry.seq += 1
        att = attachment(entry.seq, stamp.sec * 1_000_000_000 + stamp.nanosec, entry.gid)
        try:
            entry.publisher.put(serialize(ros), attachment=att)
        except Exception as exc:  # a closed session: counted, never raised into the loop
            self.errors += 1
            log.debug("ROS 2: put on %s failed: %s", topic, exc)
            return False
        return True
