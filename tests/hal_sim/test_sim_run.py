"""``guidance run --config config/sim-landmarks.toml`` on first use says what it is doing while
it builds the simulated city's landmark database, with progress, instead of a blank screen."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hal_sim.sim_run import import_sim_landmark_db


def test_the_first_build_of_the_landmark_database_says_so_with_progress(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    xy = np.array([[10.0 * i, 5.0 * i] for i in range(12)])
    path = tmp_path / "landmarks.sqlite"
    lms = import_sim_landmark_db(path, xy, seed=3)
    err = capsys.readouterr().err
    assert len(lms) == 12 and path.is_file()
    assert "first use: building the landmark database of the simulated city" in err
    assert "12 landmarks" in err and "once" in err
    assert "writing photos: 12/12 (100 %)" in err and "importing photos: 12/12 (100 %)" in err
    assert "landmark database built in" in err
    # later runs reuse it, silently
    assert [lm.id for lm in import_sim_landmark_db(path, xy, seed=3)] == [lm.id for lm in lms]
    assert capsys.readouterr().err == ""
