"""What ``guidance run --check`` verifies beyond a loadable configuration (issue 14, item 13).

A config can load and still fail at start or silently do the wrong thing: a zenoh config or TLS
file that is not there, a recording folder that cannot be created, and an ``[odometry]`` table
without ``profile`` (the CAN messages differ by car; the default would silently be the GM
reference car's), and remote goals enabled without zenoh access control (issue 23, item 7).
``start_problems`` names each in one line; ``--check`` refuses the config on the first.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from guidance.app.config import AppConfig


def _raw_table(config_path: str | Path, name: str) -> dict[str, object] | None:
    try:
        with open(config_path, "rb") as f:
            doc = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError):
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
        if tel.allow_remote_goal and not errors:
            from guidance.telemetry.session import remote_goal_problem

            problem = remote_goal_problem(tel.zenoh_config)
            if problem is not None:
                errors.append(problem)
    rec = cfg.recording
    if rec.enabled:
        kind, why = folder_problem(Path(rec.directory))
        line = f"[recording] directory {rec.directory} cannot be created: {why}"
        if kind == "error":
            errors.append(line)
        elif kind == "warning":
            warnings.append(line)
    return errors, warnings
