"""The help the commands print matches the program (issue 24: it listed two studies of three,
and --decision-distance once gave the studies' 30 m as its default)."""

from __future__ import annotations

import re

from guidance.tools.cli import build_parser
from hal_sim.cli import STUDIES
from hal_sim.drive_options import DriveOptions


def _help(*words: str) -> str:
    parser = build_parser()
    for w in words:
        parser = next(
            a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"
        ).choices[w]  # type: ignore[attr-defined]
    return " ".join(parser.format_help().split())


def test_guidance_help_names_every_study() -> None:
    text = _help()
    line = re.search(r"study run a Monte Carlo study \(([^)]*)\)", text)
    assert line is not None, text
    assert [s.strip() for s in line.group(1).split(",")] == list(STUDIES)


def test_sim_decision_distance_help_gives_the_real_default() -> None:
    text = _help("sim")
    assert f"default {DriveOptions().decision_distance_m:.0f}" in text
