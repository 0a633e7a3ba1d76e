"""``guidance run`` on a ``[sim] devices = true`` config goes through a runner the simulator
registers: the product's ``guidance.app.run`` no longer names ``hal_sim`` (even as a string)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

import guidance.app.run as run_module
from guidance.errors import UserError

REPO = Path(__file__).resolve().parents[3]


def test_the_product_does_not_name_the_simulator() -> None:
    assert "hal_sim" not in Path(run_module.__file__).read_text()


def test_the_cli_registers_the_simulators_runner() -> None:
    from guidance.tools.cli import build_parser

    build_parser()
    runner = run_module.DEVICE_RUNNERS["sim"]
    assert runner.__module__ == "hal_sim.sim_cli"


def test_without_a_registered_runner_a_sim_config_is_one_clear_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(run_module, "DEVICE_RUNNERS", {})
    args = argparse.Namespace(
        config=REPO / "config" / "sim-landmarks.toml", check=False, json=False, fresh=False,
        screen="auto",
    )  # fmt: skip
    with pytest.raises(UserError, match="no simulator registered a runner"):
        run_module._cli_run(args)
