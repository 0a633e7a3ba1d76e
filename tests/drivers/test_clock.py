"""Device timestamps onto the monotonic clock: steps followed, glitches ignored (issue 14)."""

from __future__ import annotations

import pytest

from drivers.clock import CONFIRM_AHEAD, WINDOW, ClockMapper

WALL0 = 1_700_000_000.0


def _drive(mapper: ClockMapper, n: int, *, t0: float, wall_shift: float, latency: float = 0.004):
    """n frames at 80 Hz received at monotonic t0 + k/80, stamped with the wall clock."""
    out = []
    for k in range(n):
        recv = t0 + k / 80.0
        out.append(mapper.map(recv, WALL0 + recv - latency + wall_shift))
    return out


@pytest.mark.parametrize("shift", [-0.5, +0.5, -3600.0, +3600.0, -0.08])
def test_a_wall_clock_step_is_followed_and_reported(shift: float) -> None:
    m = ClockMapper()
    _drive(m, 100, t0=10.0, wall_shift=0.0)
    after = _drive(m, 100, t0=10.0 + 100 / 80.0, wall_shift=shift)
    steps = [s for _, s in after if s is not None]
    assert len(steps) == 1 and steps[0].step_s == pytest.approx(shift, abs=0.01)
    recv_last = 10.0 + 199 / 80.0
    assert after[-1][0] == pytest.approx(recv_last - 0.004, abs=0.01)  # monotonic again
    times = [t for t, _ in after]
    assert all(t <= 10.0 + (100 + k) / 80.0 + 1e-6 for k, t in enumerate(times))  # never ahead
    assert sum(1 for _, s in after if s is None) >= 100 - max(WINDOW, CONFIRM_AHEAD) - 1


def test_two_frames_stamped_an_hour_ahead_move_nothing() -> None:
    m = ClockMapper()
    _drive(m, 50, t0=0.0, wall_shift=0.0)
    glitch = [m.map(50 / 80.0 + k / 80.0, WALL0 + 3600.0 + k / 80.0) for k in range(2)]
    assert [t for t, _ in glitch] == pytest.approx([50 / 80.0, 51 / 80.0])  # at receive time
    later = _drive(m, 50, t0=52 / 80.0, wall_shift=0.0)
    assert m.steps == [] and m.clamped == 2
    assert later[-1][0] == pytest.approx(101 / 80.0, abs=1e-6)  # the first frame's anchor


def test_latency_jitter_is_not_a_step() -> None:
    import random

    m = ClockMapper()
    rng = random.Random(1)
    for k in range(2000):
        recv = k / 80.0
        m.map(recv, WALL0 + recv - 0.002 - rng.uniform(0.0, 0.03))
    assert m.steps == []
