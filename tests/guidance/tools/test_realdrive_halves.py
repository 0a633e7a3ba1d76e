"""Issue 21, item 3 on real drives: the drive split in two halves (``benchmarks/
realdrive_halves.py``): the first half learns with two landmark fixes from the truth, the second
starts from the learned file (through ``guidance replay --learned`` and ``guidance evaluate``)
at the operator's start heading and +-1 degree: a smaller ellipse, still honest."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[3]


def _halves() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "realdrive_halves", REPO / "benchmarks" / "realdrive_halves.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize(
    "drive", ["comma2k19", pytest.param("berlin", marks=pytest.mark.shared_data)]
)
def test_the_second_half_from_the_learned_file_is_smaller_and_still_honest(
    tmp_path: Path, drive: str
) -> None:
    halves = _halves()
    if not halves.DRIVES[drive][0].is_file():
        pytest.skip(f"{halves.DRIVES[drive][0]} not present (smartLoc is CC BY-SA: ../shared)")
    res = halves.run(drive, tmp_path)
    assert res["learned"]["fixes_used"] == 2
    assert res["learned"]["scale_sigma"] < 0.02  # the fixes taught the scale something
    assert len(res["second"]) == 3  # the operator's heading and a degree either way
    for hdg, row in res["second"].items():
        learned, priors = row["learned"], row["priors"]
        assert learned["inside_2sigma_frac"] >= 0.80, (hdg, row)
        assert learned["final_major_axis_m"] < 0.9 * priors["final_major_axis_m"], (hdg, row)
