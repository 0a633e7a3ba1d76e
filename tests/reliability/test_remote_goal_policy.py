"""Issue 23, items 7 and 15: remote goals.

* Item 7: ``allow_remote_goal = true`` without zenoh access control (no ``zenoh_config``, one
  without ``access_control``, or one whose default is allow) refuses to start with one line:
  the ``Telemetry`` itself, ``guidance run --check`` and ``guidance run``. With access control,
  every accepted goal is logged with its sender where zenoh says it (the sending session's id
  from the sample's source info, which ``guidance monitor --send-goal`` sets) and spoken as a
  remote one; a goal put on a key with wildcards (``guidance/**``: every car) is refused.
* Item 15: in the simulator a remote goal the telemetry accepts is applied: the car says so
  and its state carries the new goal.

Real Zenoh sessions on 127.0.0.1, multicast scouting off.
"""

from __future__ import annotations

import json
import logging
import socket
import threading
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from reliability_helpers import wait_until

from guidance.errors import UserError
from guidance.telemetry.client import MonitorClient
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
from guidance.telemetry.session import open_session, session_config
from guidance.tools.cli import main


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def tcp(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def zenoh_file(tmp_path: Path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def no_acl_configs(tmp_path: Path) -> dict[str, str]:
    def acl(enabled: str, default: str) -> str:
        return f'{{ access_control: {{ enabled: {enabled}, default_permission: "{default}" }} }}'

    return {
        "none": "",
        "no access_control": zenoh_file(tmp_path, "plain.json5", "{ scouting: {} }"),
        "access_control off": zenoh_file(tmp_path, "off.json5", acl("false", "deny")),
        "default allow": zenoh_file(tmp_path, "allow.json5", acl("true", "allow")),
    }


def test_remote_goals_without_access_control_refuse_to_start(tmp_path: Path) -> None:
    for what, zcfg in no_acl_configs(tmp_path).items():
        cfg = TelemetryConfig(listen=(tcp(free_port()),), allow_remote_goal=True, zenoh_config=zcfg)
        with pytest.raises(UserError) as err:
            Telemetry(cfg)
        line = str(err.value)
        assert "allow_remote_goal = true needs zenoh access control" in line, what
        assert "\n" not in line, what
    # off by default, or disabled telemetry: nothing to refuse
    Telemetry(TelemetryConfig(listen=(tcp(free_port()),))).close()
    Telemetry(TelemetryConfig(enabled=False, allow_remote_goal=True)).close()


CAR = """
[vehicle]
id = "rg1"

[start]
x_m = 0.0
y_m = 0.0
heading_deg = 90.0

[goal]
x_m = 400.0
y_m = 0.0

[odometry]
backend = "can"
interface = "virtual"
channel = "rg-check"
profile = "toyota"

[compass]
enabled = false

[estimator]
compass_two_sigma_deg = false

[telemetry]
listen = ["tcp/127.0.0.1:{port}"]
allow_remote_goal = true
{zenoh}

[recording]
enabled = false
"""


@pytest.mark.parametrize("extra", [(), ("--check",)])
def test_guidance_run_refuses_remote_goals_without_access_control_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: tuple[str, ...]
) -> None:
    path = tmp_path / "car.toml"
    path.write_text(CAR.format(port=free_port(), zenoh=""))
    rc = main(["run", "--config", str(path), "--screen", "off", *extra])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert any("allow_remote_goal = true needs zenoh access control" in x for x in lines), err
    assert "Traceback" not in err and "internal error" not in err, err


def test_guidance_run_check_passes_remote_goals_with_access_control(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], loopback_acl: str
) -> None:
    path = tmp_path / "car.toml"
    path.write_text(CAR.format(port=free_port(), zenoh=f'zenoh_config = "{loopback_acl}"'))
    rc = main(["run", "--config", str(path), "--check"])
    assert rc == 0, capsys.readouterr().err


def test_every_accepted_goal_is_logged_with_its_sender_and_wildcard_goals_are_refused(
    loopback_acl: str, caplog: pytest.LogCaptureFixture
) -> None:
    port = free_port()
    goals: list[tuple[float, float]] = []
    cfg = TelemetryConfig(
        vehicle_id="rg2", listen=(tcp(port),), allow_remote_goal=True, zenoh_config=loopback_acl
    )
    caplog.set_level(logging.INFO, logger="guidance.telemetry")
    with Telemetry(cfg, on_goal=lambda x, y: goals.append((x, y))) as tel:
        wait_until(lambda: tel.health().status == "up")
        conf = session_config(mode="peer", connect=[tcp(port)], zenoh_config=loopback_acl)
        with MonitorClient([tcp(port)], zenoh_config=loopback_acl) as mon:
            raw = open_session(conf)
            try:
                wait_until(lambda: mon.peers() > 0 and bool(raw.info.peers_zid()))
                assert mon.send_goal("rg2", 120.0, -40.0)  # once the car's subscription is known
                time.sleep(0.3)  # the car's goal subscription reaches the raw session too
                body = json.dumps({"x_m": 10.0, "y_m": 20.0})
                raw.put("guidance/rg2/cmd/goal", body)  # no source info
                raw.put("guidance/**", json.dumps({"x_m": 1.0, "y_m": 2.0}))  # every car
                wait_until(lambda: len(goals) >= 2 and tel.health().counters["goals_refused"] > 0)
                zid = str(mon._session.id.zid)  # type: ignore[union-attr]
            finally:
                raw.close()
    assert sorted(goals) == [(10.0, 20.0), (120.0, -40.0)]
    accepted = [r.getMessage() for r in caplog.records if "remote goal accepted" in r.getMessage()]
    assert len(accepted) == 2 and all(r.levelno >= logging.WARNING for r in caplog.records
                                      if "remote goal accepted" in r.getMessage())  # fmt: skip
    assert any(f"from zenoh session {zid}: x 120.0 m, y -40.0 m" in m for m in accepted), accepted
    assert any("a sender zenoh does not name" in m and "x 10.0 m" in m for m in accepted), accepted
    refused = [r.getMessage() for r in caplog.records if "remote goal refused" in r.getMessage()]
    assert any("wildcards" in m for m in refused), refused


def test_the_simulator_applies_the_remote_goal_it_accepts(loopback_acl: str) -> None:
    """A drive with telemetry on loopback: a monitor sends a goal; the car says it and its
    state carries it (before: logged "accepted", never applied)."""
    from hal_sim.drive import run_drive
    from hal_sim.drive_options import DriveOptions

    port = free_port()
    tcfg = TelemetryConfig(
        vehicle_id="simgoal", listen=(tcp(port),), allow_remote_goal=True, zenoh_config=loopback_acl
    )
    app_config = SimpleNamespace(
        telemetry=tcfg, recording=None, origin_lat_lon_deg=None, pipeline=None,
        vehicle_id="simgoal", ros2=None,
    )  # fmt: skip
    opts = DriveOptions(seed=7, voice="none", telemetry=True, record=False, png=False)
    opts = replace(opts, speed=10.0, duration_s=150.0, vehicle_id="simgoal")
    seen: dict[str, Any] = {}

    def remote() -> None:
        with MonitorClient([tcp(port)], zenoh_config=loopback_acl) as mon:
            deadline = time.monotonic() + 20.0
            while time.monotonic() < deadline:  # the car is driving: its states arrive
                e = mon.get(0.1)
                if e is not None and e.kind == "state" and not e.late_join:
                    break
            seen["sent"] = mon.send_goal("simgoal", 350.0, -120.0)
            while time.monotonic() < deadline + 10.0:
                e = mon.get(0.1)
                if e is not None and e.kind == "state" and e.message:
                    goal = e.message.get("goal") or {}
                    if (goal.get("x_m"), goal.get("y_m")) == (350.0, -120.0):
                        seen["state_goal"] = True
                        return

    t = threading.Thread(target=remote, name="remote-monitor", daemon=True)
    t.start()
    r = run_drive(opts, None, app_config)  # main thread: the drive's signal handlers
    t.join(30)
    assert seen.get("sent"), "the monitor never saw the simulated car"
    assert any(text == "New destination set remotely" for _, text in r.prompt_log), r.prompt_log
    assert seen.get("state_goal"), "the car's state never carried the remote goal"
