"""What ``guidance run --check`` verifies beyond a loadable configuration (issue 14, item 13).

A config can load and still fail at start or silently do the wrong thing: a zenoh config or TLS
file that is not there, a recording folder that cannot be created, and an ``[odometry]`` table
without ``profile`` (the CAN messages differ by car; the default would silently be the GM
reference car's), and remote goals enabled without zenoh access control (issue 23, item 7).
Devices that cannot be opened now (a compass port that does not exist or this user cannot
open, a SocketCAN interface that is missing or down, no SocketCAN at all) are warnings with the
usual fix (issue 24): the drivers keep retrying, a USB adapter may be plugged in later.
``start_problems`` names each in one line; ``--check`` refuses the config on the first.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

from guidance import files

if TYPE_CHECKING:
    from guidance.app.config import AppConfig


def _raw_table(config_path: str | Path, name: str) -> dict[str, object] | None:
    try:
        doc = tomllib.loads(files.read_bytes(config_path, "config").decode("utf-8"))
    except (files.FileRefused, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    t = doc.get(name)
    return t if isinstance(t, dict) else None


def folder_problem(path: Path) -> tuple[str, str]:
    """("", "") when ``path`` can be used as a folder to write in (made when missing);
    ("error", why) when it can never be one (a file on the way, /proc), ("warning", why) when
    this user cannot write there (the service's user may: systemd's StateDirectory)."""
    p = path
    while not p.exists():  # the nearest existing ancestor decides whether it can be made
        if p.parent == p:
            break
        p = p.parent
    if not p.is_dir():
        return "error", f"{p} is not a folder"
    if not os.access(p, os.W_OK | os.X_OK):
        return "warning", f"{p} is not writable by this user"
    return "", ""


SERIAL_FIX = (
    "add this user to the port's group (ls -l PORT shows it, often dialout: "
    "sudo usermod -aG dialout $USER, then log in again)"
)


def serial_problem(port: str) -> str:
    """Why the compass's serial port cannot be opened now, with the usual fix, or ""."""
    if not os.path.exists(port):
        return (
            f"[compass] port {port} does not exist: is the compass plugged in? "
            "(ls /dev/serial/by-id/ names USB serial adapters; the driver keeps retrying)"
        )
    if not os.access(port, os.R_OK | os.W_OK):
        return (
            f"[compass] port {port}: this user cannot open it: {SERIAL_FIX.replace('PORT', port)}"
        )
    return ""


def socketcan_problem(channel: str, net: Path = Path("/sys/class/net")) -> str:
    """Why the SocketCAN interface ``channel`` cannot be used now, with the usual fix, or ""."""
    import socket

    up = f"sudo ip link set {channel} up type can bitrate 500000"
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except (OSError, AttributeError) as exc:
        return (
            f"[odometry] CAN interface {channel}: SocketCAN is not available here ({exc}): load "
            "it (sudo modprobe can can_raw) or run on the car's computer"
        )
    if not (net / channel).exists():
        return (
            f"[odometry] CAN interface {channel} does not exist: plug the CAN adapter in, then "
            f"{up} (for a test bus: sudo modprobe vcan; sudo ip link add dev {channel} type "
            f"vcan; sudo ip link set {channel} up)"
        )
    try:
        state = (net / channel / "operstate").read_text().strip()
        flags = int((net / channel / "flags").read_text().strip(), 16)
    except (OSError, ValueError):
        return ""
    if state == "down" or not flags & 0x1:  # IFF_UP
        return f"[odometry] CAN interface {channel} is down: {up}"
    return ""


def device_problems(cfg: AppConfig) -> list[str]:
    """Each configured device that cannot be opened now (it may be plugged in later: the
    drivers keep retrying, so these are warnings), with the usual fix."""
    out = []
    compass = cfg.compass
    if compass is not None and compass.backend == "nmea_serial":
        port = str(getattr(compass.config, "port", ""))
        if port and (why := serial_problem(port)):
            out.append(why)
    odo = cfg.odometry
    if (
        odo is not None
        and odo.backend == "can"
        and getattr(odo.config, "interface", "") == "socketcan"
    ):
        channel = str(getattr(odo.config, "channel", ""))
        if channel and (why := socketcan_problem(channel)):
            out.append(why)
    return out


def start_problems(config_path: str | Path, cfg: AppConfig) -> tuple[list[str], list[str]]:
    """(errors, warnings): one line for each thing that would make the car start wrong."""
    errors: list[str] = []
    warnings: list[str] = []
    odo = _raw_table(config_path, "odometry")
    can = cfg.odometry is not None and cfg.odometry.backend == "can"
    if can and (odo is None or "profile" not in odo):
        errors.append(
            "[odometry] profile is missing: name the car's CAN profile (gm_global_a, "
            "toyota, honda_civic); the wheel-speed messages differ by car"
        )
    tel = cfg.telemetry
    if tel.enabled:
        files = [("zenoh_config", tel.zenoh_config)]
        if tel.tls is not None:
            files += [
                ("tls.root_ca_certificate", tel.tls.root_ca_certificate),
                ("tls.certificate", tel.tls.certificate),
                ("tls.private_key", tel.tls.private_key),
            ]
        for key, name in files:
            if name and not Path(name).is_file():
                errors.append(f"[telemetry] {key} {name}: no such file")
        if not errors:
            from guidance.telemetry.example_passwords import example_password_problem

            warnings += filter(None, [example_password_problem(tel.zenoh_config)])
        if tel.allow_remote_goal and not errors:
            from guidance.telemetry.session import remote_goal_problem

            problem = remote_goal_problem(tel.zenoh_config)
            if problem is not None:
                errors.append(problem)
    if not cfg.sim.get("devices", False):  # the simulator replaces the ports with its own
        warnings += device_problems(cfg)
    rec = cfg.recording
    if rec.enabled:
        kind, why = folder_problem(Path(rec.directory))
        line = f"[recording] directory {rec.directory} cannot be created: {why}"
        if kind == "error":
            errors.append(line)
        elif kind == "warning":
            warnings.append(line)
    return errors, warnings
