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


def test_the_simulator_never_deletes_a_database_it_did_not_make(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 40, defect 11: ``[sim] devices = true`` deleted the landmark database it names,
    and every file whose name started with it (``landmarks.sqlite.bak``), whenever the file did
    not hold the simulated city, then rebuilt it in place. Now a file it did not make is
    refused with one line and left as it was, with everything beside it."""
    from guidance.core.geo import Origin
    from guidance.errors import UserError
    from hal_sim.sim_camera import facade
    from landmark_db.store import create_db

    xy = np.array([[10.0 * i, 5.0 * i] for i in range(4)])
    path = tmp_path / "landmarks.sqlite"
    theirs = create_db(path, Origin(52.5, 13.4))
    theirs.add("the old mill", facade(5), x_m=1.0, y_m=2.0)
    theirs.close()
    before = path.read_bytes()
    backup = tmp_path / "landmarks.sqlite.bak"
    backup.write_bytes(b"the user's backup")
    for damaged in (False, True):
        if damaged:
            path.write_bytes(before[:3000])  # a damaged file the simulator did not make
            before = path.read_bytes()
        with pytest.raises(UserError, match="move it away or name another"):
            import_sim_landmark_db(path, xy, seed=3)
        assert path.read_bytes() == before and backup.read_bytes() == b"the user's backup"
        assert sorted(p.name for p in tmp_path.iterdir()) == [
            "landmarks.sqlite",
            "landmarks.sqlite.bak",
        ]
    capsys.readouterr()


def test_a_stop_during_the_build_leaves_no_half_built_file_at_the_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The build goes to a temp file beside the path and is renamed over it when complete: a
    stop (here, the import failing half way) leaves the path as it was (absent), no temp."""
    import landmark_db.cli as landmark_cli

    real = landmark_cli.main

    def stops_half_way(argv: list[str]) -> int:
        if argv[0] == "import":
            raise KeyboardInterrupt  # the operator's Ctrl-C, mid-import
        return real(argv)

    monkeypatch.setattr(landmark_cli, "main", stops_half_way)
    xy = np.array([[10.0 * i, 5.0 * i] for i in range(4)])
    path = tmp_path / "landmarks.sqlite"
    with pytest.raises(KeyboardInterrupt):
        import_sim_landmark_db(path, xy, seed=3)
    assert not path.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".landmarks.sqlite")]
    monkeypatch.setattr(landmark_cli, "main", real)
    assert len(import_sim_landmark_db(path, xy, seed=3)) == 4  # the next run builds it


def test_a_database_of_another_city_of_the_same_size_is_rebuilt_not_reused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 40 (noticed): the reuse check compared landmark names only, so a database built
    for another seed (other photos) or another layout (other positions) with as many
    landmarks was reused: the camera then saw the other city's photos at this city's places.
    Each rebuild is checked against the truth: the stored photo of each landmark is this
    city's facade and its position this city's."""
    from hal_sim.sim_camera import facade, photo_seed
    from landmark_db.features import decode_image
    from landmark_db.store import open_db

    path = tmp_path / "landmarks.sqlite"
    xy = np.array([[10.0 * i, 5.0 * i] for i in range(4)])
    import_sim_landmark_db(path, xy, seed=3)
    capsys.readouterr()
    for seed, city in ((4, xy), (4, xy + 7.0)):  # another seed; then another layout
        lms = import_sim_landmark_db(path, city, seed=seed)
        assert "first use: building" in capsys.readouterr().err, (seed, city[0])
        with open_db(path, readonly=True) as db:
            for i, lm in enumerate(lms):
                rec = db.get(lm.id)
                assert rec is not None
                assert (rec.x_m, rec.y_m) == pytest.approx(tuple(city[i]), abs=2e-3)
                _fmt, data = db.image_bytes(lm.id) or ("", b"")
                assert np.array_equal(decode_image(data), facade(photo_seed(seed, i))), (seed, i)
    import_sim_landmark_db(path, xy + 7.0, seed=4)  # this city again: reused, silently
    assert capsys.readouterr().err == ""
