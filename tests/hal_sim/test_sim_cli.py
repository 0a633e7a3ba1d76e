"""``guidance sim``'s options: a sim TOML's ``[sim]`` through the one table loader, and the
command line over it (explicit precedence, no peeking at sys.argv)."""

from __future__ import annotations

import argparse
import os
from dataclasses import replace
from pathlib import Path

import pytest

from guidance.config_tables import plain
from guidance.core import law
from guidance.errors import UserError
from hal_sim.drive_options import METHODS, DriveOptions, options_from_config, sim_vehicle_id
from hal_sim.sim_cli import register

REPO = Path(__file__).resolve().parents[2]


def _config(tmp_path: Path, sim: str, estimator: str = "") -> Path:
    text = (REPO / "config" / "sim.toml").read_text()
    text = text.replace("[sim]\nseed = 7\n", f"[sim]\n{sim}\n", 1)  # seed: the default
    if estimator:
        text = text.replace("[estimator]\n", f"[estimator]\n{estimator}\n", 1)
    path = tmp_path / "conf" / "sim.toml"
    path.parent.mkdir()
    path.write_text(text)
    return path


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    return parser.parse_args(["sim", *argv])


def test_the_method_names_are_the_laws() -> None:
    assert METHODS == law.METHOD_NAMES


def test_sim_table_values_paths_and_the_config_s_defaults(tmp_path: Path) -> None:
    path = _config(tmp_path, 'out = "drives"\ncan_silent = [10, 5]')
    opts, cfg = options_from_config(str(path), DriveOptions())
    assert opts.seed == 7 and opts.can_silent == (10.0, 5.0)
    assert opts.out == str(path.parent / "drives")  # from the config's folder, not the cwd
    assert opts.method == cfg.pipeline.navigator.method.value
    assert opts.compass_deg == cfg.pipeline.estimator.compass_two_sigma_deg
    # config/sim.toml names no [vehicle] id: each drive is a car of its own (issue 41)
    assert opts.vehicle_id == "" and sim_vehicle_id(opts) == f"sim7-{os.getpid()}"
    named = tmp_path / "named.toml"
    named.write_text(path.read_text().replace("[vehicle]\n", '[vehicle]\nid = "car9"\n', 1))
    assert options_from_config(str(named), DriveOptions())[0].vehicle_id == "car9"


def test_the_simulator_runs_the_configured_car(tmp_path: Path) -> None:
    """Issue 25: ``guidance sim --config`` drives the car of the TOML: its [navigation] and
    [health] (not only the method), on the world's sensors, and records them for replay."""
    from guidance.core.health import HealthConfig
    from hal_sim.drive import SimDrive

    path = _config(tmp_path, "")
    text = path.read_text().replace(
        'method = "hybrid"\n', 'method = "hybrid"\nlookahead_m = 15.0\n'
    )
    path.write_text(text + "\n[health]\nsilence_periods = 3.0\n")
    opts, cfg = options_from_config(str(path), DriveOptions())
    drive = SimDrive(replace(opts, voice="none", out=str(tmp_path / "out")), None, cfg)
    pc = drive.pipeline_config
    assert pc.health == HealthConfig(silence_periods=3.0)
    assert pc.navigator.lookahead_m == 15.0 and drive.world.nav.lookahead_m == 15.0
    assert pc.estimator == drive.world.est  # the filter matches the simulated sensors
    assert pc.describe()["health"] == {**plain(HealthConfig()), "silence_periods": 3.0}


@pytest.mark.parametrize(
    ("sim", "message"),
    [
        ("seed = true", r"sim\.toml: \[sim\] seed must be an integer, not True"),
        ("sead = 3", r"sim\.toml: \[sim\] unknown key\(s\): sead \(known: "),
        ('method = "fastest"', r"\[sim\] method must be one of straight_to_goal, "),
        ('vehicle_id = "x"', r"unknown key\(s\): vehicle_id "),  # [vehicle] id says it
    ],
)
def test_a_bad_sim_table_is_one_line_naming_the_file(
    tmp_path: Path, sim: str, message: str
) -> None:
    with pytest.raises(UserError, match=message):
        options_from_config(str(_config(tmp_path, sim)), DriveOptions())


def test_the_compass_flag_is_given_or_not_no_argv_peeking() -> None:
    assert "compass_deg" not in vars(_parse())
    assert _parse("--compass-deg", "none").compass_deg is None
    assert _parse("--compass-deg", "30").compass_deg == 30.0


def test_a_lost_car_finds_itself_again_and_arrives_unless_told_not_to(tmp_path: Path) -> None:
    """Issue 36, the full ``guidance sim`` stack (CAN frames, the pty compass): a 90 s CAN gap
    loses the car; with landmarks it drives on, is found again at one and arrives; the JSON
    summary counts it. ``--no-relocalise`` keeps the paper's definition: the trip ends lost."""
    import json
    import subprocess
    import sys

    def sim(*extra: str) -> dict[str, object]:
        out = subprocess.run(
            [sys.executable, "-m", "guidance.tools.cli", "sim", "--seed", "509", "--compass-deg",
             "20", "--density", "3", "--can-silent", "30:90", "--json", "--no-voice", "--no-png",
             "--no-record", "--no-telemetry", "--out", str(tmp_path), *extra],
            capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
        doc: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
        return doc

    found = sim()
    assert found["outcome"] == "arrived" and found["lost_episodes"] == 1
    assert isinstance(found["relocalisations"], int) and found["relocalisations"] >= 1
    stopped = sim("--no-relocalise")
    assert stopped["outcome"] == "lost" and stopped["relocalisations"] == 0
