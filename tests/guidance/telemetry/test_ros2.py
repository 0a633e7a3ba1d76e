"""ROS 2 over Zenoh without ROS (issue 41): the rmw_zenoh wire format against the examples of
rmw_zenoh's design document, and a subscriber written only from that document (key,
attachment, liveliness tokens; rosbags deserialising the CDR) receiving the car's estimate
through a real router on loopback, checked against the state it came from."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from guidance.core.messages import Ellipse, EstimateState
from guidance.outputs.kinds import STATE, OutputContext
from guidance.outputs.messages import state_message
from guidance.telemetry.config import Ros2Config
from guidance.telemetry.ros2 import (
    Ros2Sink,
    attachment,
    mangle,
    parse_attachment,
)
from guidance.telemetry.ros2_messages import dds_type_name, type_hash, typestore

ORIGIN = (42.444, -76.5019)


def test_keys_hashes_and_attachment_match_the_design_document() -> None:
    # design.md: "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c74...1a18"
    hash_ = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    assert f"0/chatter/{dds_type_name('std_msgs/msg/String')}/{type_hash('std_msgs/msg/String')}" \
        == f"0/chatter/std_msgs::msg::dds_::String_/{hash_}"  # fmt: skip
    assert mangle("/chatter") == "%chatter" and mangle("") == "%"
    gid = bytes(range(16))
    att = attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(att) == 33 and att[:8] == (7).to_bytes(8, "little") and att[16] == 16
    assert parse_attachment(att) == (7, 1_700_000_000_123_456_789, gid)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _conf(mode: str, key: str, endpoint: str) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("transport/shared_memory/enabled", "false")
    c.insert_json5(key, json.dumps([endpoint]))
    return c


def _state(i: int) -> EstimateState:
    a = 3.0 + 0.1 * i
    cov = ((a * a / 4, 0.3, 0.01), (0.3, 1.5, -0.02), (0.01, -0.02, 0.004))
    return EstimateState(0.1 * i, 10.0 + i, -4.0 + 0.5 * i, 0.3, cov, Ellipse(a, 1.0, 0.2, 2 * a),
                         False, True)  # fmt: skip


def test_a_subscriber_from_the_document_receives_the_estimate_at_10_hz() -> None:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = zenoh.open(_conf("router", "listen/endpoints", endpoint))
    sink = Ros2Sink(Ros2Config(enabled=True, mode="client", connect=(endpoint,)))
    sub_session = zenoh.open(_conf("client", "connect/endpoints", endpoint))
    try:
        sink.origin_lat_lon_deg = ORIGIN
        sink.start()
        # the subscriber: the document's key format, any type hash
        odo_sub = sub_session.declare_subscriber(
            "0/guidance/odometry/nav_msgs::msg::dds_::Odometry_/*", zenoh.handlers.FifoChannel(256)
        )
        pose_sub = sub_session.declare_subscriber(
            "0/guidance/pose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/*",
            zenoh.handlers.FifoChannel(256),
        )
        fix_sub = sub_session.declare_subscriber(
            "0/guidance/fix/sensor_msgs::msg::dds_::NavSatFix_/*", zenoh.handlers.FifoChannel(256)
        )
        deadline = time.monotonic() + 10.0
        while not all(
            sink._topics[t].publisher.matching_status.matching for t in ("odometry", "pose", "fix")
        ):
            assert time.monotonic() < deadline
            time.sleep(0.05)
        tokens = [str(r.ok.key_expr) for r in sub_session.liveliness().get("@ros2_lv/0/**")
                  if r.ok is not None]  # fmt: skip
        sent: list[dict[str, Any]] = []
        t0 = time.monotonic()
        for i in range(20):
            time.sleep(max(0.0, t0 + 0.1 * i - time.monotonic()))
            st = _state(i)
            ctx = OutputContext(speed_mps=8.5)
            sink.send(STATE, st, ctx)
            sent.append(state_message(st, vehicle_id="x", seq=i, speed_mps=8.5,
                                      origin_lat_lon_deg=ORIGIN))  # fmt: skip
        time.sleep(0.5)
        odos = [odo_sub.handler.recv() for _ in range(20)]
        fixes = [fix_sub.handler.recv() for _ in range(20)]
        poses = [pose_sub.handler.recv() for _ in range(20)]
    finally:
        sink.close()
        sub_session.close()
        router.close()
    # liveliness: a node and a publisher of each type, with the type's hash
    odo_hash = type_hash("nav_msgs/msg/Odometry")
    assert any("/NN/%/%guidance/guidance" in k for k in tokens), tokens
    assert any(k.endswith(f"/MP/%/%guidance/guidance/%guidance%odometry/"
                          f"nav_msgs::msg::dds_::Odometry_/{odo_hash}/::,10:,:,:,,")
               for k in tokens), tokens  # fmt: skip
    ts = typestore()
    seqs, stamps = [], []
    for sample, state in zip(odos, sent, strict=True):
        payload = sample.payload.to_bytes()
        assert payload[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation header
        msg = ts.deserialize_cdr(payload, "nav_msgs/msg/Odometry")
        seq, t_ns, gid = parse_attachment(sample.attachment.to_bytes())
        seqs.append(seq)
        stamps.append(t_ns)
        assert len(gid) == 16
        cov = np.array(msg.pose.covariance).reshape(6, 6)
        c3 = np.array(state["covariance"])
        assert cov[np.ix_([0, 1, 5], [0, 1, 5])] == pytest.approx(c3)
        assert (msg.pose.pose.position.x, msg.pose.pose.position.y) == pytest.approx(
            (state["x_m"], state["y_m"])
        )
        yaw = 2 * np.arctan2(msg.pose.pose.orientation.z, msg.pose.pose.orientation.w)
        assert yaw == pytest.approx(state["heading_rad"])
        assert msg.twist.twist.linear.x == pytest.approx(8.5)
        assert msg.header.frame_id == "map" and msg.child_frame_id == "base_link"
    assert seqs == list(range(1, 21))
    period = np.diff(stamps) / 1e9
    assert np.median(period) == pytest.approx(0.1, abs=0.02)
    for sample, state in zip(poses, sent, strict=True):
        pose = ts.deserialize_cdr(
            sample.payload.to_bytes(), "geometry_msgs/msg/PoseWithCovarianceStamped"
        )
        cov = np.array(pose.pose.covariance).reshape(6, 6)
        assert cov[np.ix_([0, 1, 5], [0, 1, 5])] == pytest.approx(np.array(state["covariance"]))
        assert len(sample.attachment.to_bytes()) == 33
    for sample, state in zip(fixes, sent, strict=True):
        fix = ts.deserialize_cdr(sample.payload.to_bytes(), "sensor_msgs/msg/NavSatFix")
        assert (fix.latitude, fix.longitude) == pytest.approx((state["lat_deg"], state["lon_deg"]))
        enu = np.array(fix.position_covariance).reshape(3, 3)
        assert enu[:2, :2] == pytest.approx(np.array(state["covariance"])[:2, :2])
        assert fix.position_covariance_type == 3


def test_the_rosbag2_export_reads_back_with_rosbags(tmp_path: Path) -> None:
    from rosbags.rosbag2 import Reader as BagReader

    from guidance.recording.reader import Reader

    rec = Path(__file__).resolve().parents[2] / "data" / "replay" / "sim_seed3_landmarks.mcap"
    out = tmp_path / "bag"
    run = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "recording", "ros2", str(rec), str(out)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "on /guidance/odometry" in run.stdout
    states = [m.data for m in Reader(rec, topics=("/state",))]
    ts = typestore()
    with BagReader(out) as bag:
        types = {c.topic: c.msgtype for c in bag.connections}
        odo = [ts.deserialize_cdr(raw, c.msgtype) for c, _t, raw in bag.messages()
               if c.topic == "/guidance/odometry"]  # fmt: skip
        fixes = sum(1 for c, _t, _raw in bag.messages() if c.topic == "/guidance/landmark_fix")
    assert types["/guidance/odometry"] == "nav_msgs/msg/Odometry"
    assert types["/guidance/fix"] == "sensor_msgs/msg/NavSatFix"
    assert len(odo) == len(states) and fixes > 0
    for msg, state in zip(odo, states, strict=True):
        cov = np.array(msg.pose.covariance).reshape(6, 6)
        assert cov[np.ix_([0, 1, 5], [0, 1, 5])] == pytest.approx(np.array(state["covariance"]))
        assert msg.pose.pose.position.x == pytest.approx(state["x_m"])


def test_the_ros2_table_is_off_by_default_and_read_from_the_config(tmp_path: Path) -> None:
    from guidance.app.config import load_config
    from guidance.errors import UserError

    repo = Path(__file__).resolve().parents[3]
    base = (repo / "config" / "sim.toml").read_text()
    cfg = tmp_path / "sim.toml"
    cfg.write_text(base)
    assert load_config(str(cfg), require_goal=False).ros2.enabled is False
    cfg.write_text(base + '\n[ros2]\nenabled = true\ndomain_id = 3\nnamespace = "/car7"\n')
    ros2 = load_config(str(cfg), require_goal=False).ros2
    assert (ros2.enabled, ros2.domain_id, ros2.namespace) == (True, 3, "/car7")
    cfg.write_text(base + '\n[ros2]\nnamespace = "car 7"\n')
    with pytest.raises(UserError, match="ROS namespace"):
        load_config(str(cfg), require_goal=False)


def test_the_simulator_with_ros2_enabled_publishes_the_estimate(tmp_path: Path) -> None:
    """``[ros2] enabled = true`` in the simulator's config: its Odometry reaches a subscriber
    through a router (the sink wired into the output table, not a second path)."""
    repo = Path(__file__).resolve().parents[3]
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    cfg = tmp_path / "sim.toml"
    cfg.write_text(
        (repo / "config" / "sim.toml")
        .read_text()
        .replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{_free_port()}")
        + f'\n[ros2]\nenabled = true\nmode = "client"\nconnect = ["{endpoint}"]\n'
    )
    router = zenoh.open(_conf("router", "listen/endpoints", endpoint))
    sub_session = zenoh.open(_conf("client", "connect/endpoints", endpoint))
    sim = None
    try:
        sub = sub_session.declare_subscriber(
            "0/guidance/odometry/nav_msgs::msg::dds_::Odometry_/*", zenoh.handlers.FifoChannel(64)
        )
        sim = subprocess.Popen(
            [sys.executable, "-m", "guidance.tools.cli", "sim", "--config", str(cfg), "--speed",
             "2", "--no-voice", "--no-record", "--no-png", "--out", str(tmp_path / "out")],
            cwd=repo, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        got = []
        deadline = time.monotonic() + 40.0
        while len(got) < 5 and time.monotonic() < deadline and sim.poll() is None:
            sample = sub.handler.try_recv()
            if sample is None:
                time.sleep(0.05)
                continue
            got.append(typestore().deserialize_cdr(sample.payload.to_bytes(),
                                                   "nav_msgs/msg/Odometry"))  # fmt: skip
    finally:
        if sim is not None:
            sim.terminate()
            err = sim.communicate(timeout=30)[1]
        sub_session.close()
        router.close()
    assert len(got) == 5, err[-800:]
    assert all(np.array(m.pose.covariance)[0] > 0 for m in got)


def test_no_router_yet_is_not_the_cars_failure() -> None:
    """Client mode with the router not up: the sink logs and retries; the car runs on."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    sink = Ros2Sink(Ros2Config(enabled=True, mode="client", connect=(endpoint,))).start()
    router = None
    try:
        assert sink.publish("state", 0.0, lambda **_kw: {}) is False
        router = zenoh.open(_conf("router", "listen/endpoints", endpoint))
        deadline = time.monotonic() + 10.0
        while sink._session is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert sink._session is not None, "the sink opened once the router was there"
    finally:
        sink.close()
        if router is not None:
            router.close()
