"""Security: remote commands off by default, no secret in logs or health messages.

Access control itself (an unauthorised session cannot set a goal, with the example user/password
and mutual-TLS configs of config/zenoh/ on loopback, certificates made by openssl at test time)
is tested in tests/guidance/telemetry/test_telemetry.py:
test_usrpwd_access_control_only_the_operator_sets_a_goal and
test_mtls_access_control_only_the_operator_certificate_sets_a_goal.
"""

from __future__ import annotations

import json
import logging
import time
import tomllib
from pathlib import Path

import pytest
from reliability_helpers import REPO, closed_port, wait_until

from guidance.errors import UserError
from guidance.outputs.messages import health_message
from guidance.telemetry.client import MonitorClient
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.publisher import Telemetry
from guidance.telemetry.redact import REDACTED, is_secret_name, redact_secrets, redact_text

ZENOH_EXAMPLES = REPO / "config" / "zenoh"
SECRET = "s3cret-Pa55-9f1c"
NUMERIC_SECRET = "73105519"


def test_remote_commands_are_off_by_default() -> None:
    assert TelemetryConfig().allow_remote_goal is False
    assert TelemetryConfig.from_mapping({}).allow_remote_goal is False
    example = tomllib.loads((ZENOH_EXAMPLES / "telemetry.example.toml").read_text())
    assert example["telemetry"]["allow_remote_goal"] is False


@pytest.mark.parametrize(
    ("name", "secret"),
    [
        ("password", True),
        ("Password", True),
        ("passwd", True),
        ("api_key", True),
        ("apikey", True),
        ("private_key", True),
        ("listen_private_key", True),
        ("key", True),
        ("token", True),
        ("auth_token", True),
        ("client_secret", True),
        ("credentials", True),
        ("key_exprs", False),
        ("keep_alive", False),
        ("monkey", False),
        ("user", False),
        ("vehicle_id", False),
        ("root_ca_certificate", False),
    ],
)
def test_secret_names(name: str, secret: bool) -> None:
    assert is_secret_name(name) is secret


def test_a_logged_config_shows_no_secret(caplog: pytest.LogCaptureFixture) -> None:
    config = {
        "telemetry": {
            "vehicle_id": "car1",
            "zenoh_config": "/etc/guidance/zenoh/car.json5",
            "tls": {"root_ca_certificate": "/ca.pem", "private_key": SECRET},
        },
        "zenoh": {
            "transport": {"auth": {"usrpwd": {"user": "operator", "password": SECRET}}},
            "access_control": {"rules": [{"key_exprs": ["guidance/*/cmd/goal"]}]},
        },
        "uplink": [{"token": SECRET, "url": "tls/router:7447"}],
    }
    with caplog.at_level(logging.DEBUG):
        logging.getLogger("guidance.test").info("config: %s", redact_secrets(config))
    text = caplog.text
    assert SECRET not in text
    assert text.count(REDACTED) == 3
    assert "guidance/*/cmd/goal" in text and "operator" in text and "/ca.pem" in text


USRPWD = '{\n  transport: { auth: { usrpwd: { user: "op", password: %s } } },\n}\n'
BAD_CONFIGS = {
    # zenoh quotes the offending line of a JSON5 syntax error...
    "syntax": USRPWD % f'"{SECRET}" "x"',
    # ...and the offending value of a badly typed field.
    "type": USRPWD % NUMERIC_SECRET,
}


@pytest.mark.parametrize("kind", sorted(BAD_CONFIGS))
def test_zenoh_errors_never_echo_a_password(
    kind: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "bad.json5"
    path.write_text(BAD_CONFIGS[kind])
    cfg = TelemetryConfig(
        vehicle_id="sec1", listen=(f"tcp/127.0.0.1:{closed_port()}",), zenoh_config=str(path)
    )
    with caplog.at_level(logging.DEBUG):
        tel = Telemetry(cfg)
        tel.start()
        try:
            wait_until(lambda: tel.health().status == "down", what="telemetry down")
            health = tel.health().as_dict()
        finally:
            tel.close()
        with pytest.raises(UserError) as err:
            MonitorClient(["tcp/127.0.0.1:1"], zenoh_config=str(path)).open()
    published = json.dumps(health_message(1.0, {}, vehicle_id="sec1", components={"t": health}))
    for where in (caplog.text, json.dumps(health), published, str(err.value)):
        assert SECRET not in where and NUMERIC_SECRET not in where
    # ...and the message still says what is wrong and where.
    assert "bad zenoh configuration" in health["detail"]
    assert ("2:" in health["detail"]) if kind == "syntax" else ("string" in str(err.value))


def test_redact_text_keeps_what_a_user_needs() -> None:
    assert redact_text("unknown field `passwort`, expected one of `user`, `password`") == (
        "unknown field `passwort`, expected one of `user`, `password`"
    )
    assert redact_text('token=abc key_exprs: ["a/b"]') == 'token=*** key_exprs: ["a/b"]'
    assert redact_text("usrpwd: { user: 'x', password: 'y' }") == (
        "usrpwd: { user: 'x', password: *** }"
    )


def test_logins_with_right_and_wrong_passwords_log_no_password(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The user/password example on loopback: neither password appears in any log record."""
    (tmp_path / "passwords.txt").write_text(f"operator:{SECRET}\nviewer:viewer-{SECRET}\n")
    text = (ZENOH_EXAMPLES / "car-usrpwd-acl.json5").read_text()
    car_json5 = tmp_path / "car.json5"
    car_json5.write_text(text.replace("/etc/guidance/zenoh/", f"{tmp_path}/"))
    monitor_text = (ZENOH_EXAMPLES / "monitor-usrpwd.json5").read_text()
    right = tmp_path / "right.json5"
    right.write_text(monitor_text.replace("change-me-viewer", f"viewer-{SECRET}"))
    wrong = tmp_path / "wrong.json5"
    wrong.write_text(monitor_text.replace("change-me-viewer", f"{SECRET}-guess"))
    port = closed_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    cfg = TelemetryConfig(vehicle_id="sec2", listen=(endpoint,), zenoh_config=str(car_json5))
    with caplog.at_level(logging.DEBUG), Telemetry(cfg) as tel:
        wait_until(lambda: tel.health().status == "up", 10.0, "telemetry up")
        for monitor_cfg, should_connect in ((right, True), (wrong, False)):
            with MonitorClient([endpoint], zenoh_config=str(monitor_cfg)) as mon:
                deadline = time.monotonic() + (5.0 if should_connect else 1.5)
                while mon.peers() == 0 and time.monotonic() < deadline:
                    time.sleep(0.05)
                assert (mon.peers() > 0) is should_connect
        health = json.dumps(tel.health().as_dict())
    assert caplog.records  # the telemetry did log (up, ...)
    assert SECRET not in caplog.text and SECRET not in health
