"""A compass mounted at any angle (issue 38, item 4): its offset learned and kept, drive after
drive; one whose offset moves between drives flagged at the start and by ``calibrate``."""

from __future__ import annotations

import math
from argparse import Namespace
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from guidance.app.learned_file import save_learned, start_from_learned
from guidance.core.localize import compass_mount
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.localize.learned import LearnedParams
from guidance.core.localize.localizer import Localizer, LocalizerConfig
from hal_sim.car_errors import draw_car
from hal_sim.population import drive_car


def test_the_flag_is_a_chi_square_of_the_drives_against_their_mean() -> None:
    assert compass_mount.moving([(88.0, 2.0)]) is None  # one drive says nothing
    assert compass_mount.moving([(88.0, 2.0), (93.0, 2.0)]) is None  # 5 / 2.83 = 1.8 sigma
    flagged = compass_mount.moving([(88.0, 1.0), (93.5, 1.0)])  # 3.9 sigma
    assert flagged is not None and flagged[0] == pytest.approx(5.5**2 / 2) and flagged[1] > 10
    assert compass_mount.moving([(179.0, 1.0), (-179.0, 1.0)]) is None  # 2 degrees apart
    rng = np.random.default_rng(1)  # honest drives: about one flag in a thousand cars
    honest = [[(88.0 + rng.normal() * s, s) for s in rng.uniform(1, 8, 5)] for _ in range(4000)]
    rate = sum(compass_mount.moving(d) is not None for d in honest) / len(honest)
    assert rate < 0.004
    assert len(compass_mount.with_drive([(1.0, 1.0)] * 5, 2.0, 1.0)) == compass_mount.KEPT


def test_a_compass_mounted_at_88_degrees_is_learned_and_one_that_moves_is_flagged(
    tmp_path: Path,
) -> None:
    """The simulated car's compass sits 88 degrees off (no setting, no card: the filter's
    uncalibrated prior of 60 degrees); three drives of 1.5 km with landmark fixes (10 per
    km²) each start from the last one's learned file; then the compass is knocked to 118
    degrees for a fourth."""
    car = replace(draw_car(np.random.default_rng(3)), compass_offset_deg=88.0)
    learned: LearnedParams | None = None
    for i, offset in enumerate((88.0, 88.0, 88.0, 118.0)):
        res = drive_car(100 + i, replace(car, compass_offset_deg=offset), compass=True,
                        learned=learned, landmarks_per_km2=10.0)  # fmt: skip
        learned = res.learned
        assert learned is not None and learned.compass_bias_deg is not None
        assert learned.compass_bias_sigma_deg is not None
        assert abs(learned.compass_bias_deg - offset) < 3 * learned.compass_bias_sigma_deg
        if i < 3:
            assert compass_mount.moving(learned.compass_drives) is None, learned.compass_drives
    assert learned is not None and len(learned.compass_drives) == 4
    assert compass_mount.moving(learned.compass_drives) is not None
    # kept in the learned file, said when the car starts from it
    path = tmp_path / "learned.json"
    save_learned(path, replace(learned, vehicle_id="car1"))
    cfg = car_model(EstimatorConfig(compass_two_sigma_deg=30.0), calibrated=False)
    loc = Localizer(LocalizerConfig(cfg, start_xy_m=(0.0, 0.0)))
    used, note = start_from_learned(loc, path, "car1", learned.saved_unix_s + 60)
    assert used is not None and used.compass_drives == learned.compass_drives
    assert "COMPASS OFFSET MOVES BETWEEN DRIVES" in note
    assert math.isclose(used.compass_bias_deg or 0.0, learned.compass_bias_deg or 1.0)
    # and guidance calibrate says so, from the car's config and its learned file
    from guidance.tools.calibrate import compass_mount_note

    toml = tmp_path / "car.toml"
    toml.write_text(
        '[vehicle]\nid = "car1"\n[start]\nx_m = 0.0\ny_m = 0.0\nheading_deg = 0.0\n'
        '[odometry]\nbackend = "can"\ninterface = "virtual"\nchannel = "replay"\n'
        'profile = "toyota"\n[compass]\ndeclination_deg = 0.0\n'
        '[checkpoint]\nlearned_path = "learned.json"\n'
    )
    assert "COMPASS OFFSET MOVES" in compass_mount_note(Namespace(config=str(toml), learned=None))
    steady = learned.compass_drives[:3]  # the three drives before the knock
    save_learned(path, replace(learned, vehicle_id="car1", compass_drives=steady))
    assert compass_mount_note(Namespace(config=str(toml), learned=path)) == ""


def test_a_damaged_history_is_refused() -> None:
    good = LearnedParams("car1", 1.0, 0.0, 0.0, 0.01, 0.0, 0.0003, 88.0, 2.0,
                         compass_drives=((88.0, 2.0),))  # fmt: skip
    doc = good.to_dict()
    assert LearnedParams.from_dict(doc) == good
    for bad in ([[88.0]], [[400.0, 1.0]], [[88.0, 2.0]] * 6, "88", [[88.0, True]]):
        with pytest.raises(ValueError, match="compass_drives"):
            LearnedParams.from_dict(dict(doc, compass_drives=bad))
