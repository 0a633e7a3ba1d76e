"""``guidance run`` on a ``[sim] devices = true`` config goes through the ``guidance``
command's table of device runners (``guidance.tools.cli.DEVICE_RUNNERS``, ``module:function``
imported on first use): the product's ``guidance.app.run`` never names ``hal_sim`` (even as a
string), and nothing registers itself at run time."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

import guidance.app.run as run_module
from guidance.app.backends import import_backend
from guidance.errors import UserError
from guidance.tools.cli import DEVICE_RUNNERS, build_parser

REPO = Path(__file__).resolve().parents[3]


def test_the_product_does_not_name_the_simulator() -> None:
    assert "hal_sim" not in Path(run_module.__file__).read_text()
    assert not hasattr(run_module, "DEVICE_RUNNERS")  # no run-time registry


def test_the_commands_table_names_the_simulators_runner() -> None:
    runner = import_backend(DEVICE_RUNNERS["sim"])
    assert runner.__module__ == "hal_sim.sim_cli" and callable(runner)
    args = build_parser().parse_args(["run", "--config", "x.toml"])
    assert args.device_runners is DEVICE_RUNNERS  # what `guidance run` reads


def test_without_a_runner_in_the_table_a_sim_config_is_one_clear_error() -> None:
    args = argparse.Namespace(
        config=REPO / "config" / "sim-landmarks.toml", check=False, json=False, fresh=False,
        screen="auto", device_runners={},
    )  # fmt: skip
    with pytest.raises(UserError, match="names no runner for simulated devices"):
        run_module._cli_run(args)
