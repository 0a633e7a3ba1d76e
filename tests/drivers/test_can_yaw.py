"""The stability control's yaw rate from a profile's own frames (``drivers.can_yaw``): each
profile's signal, in its unit and with its sign convention, built with the DBC (cantools) as
the car's ESC would send it."""

from __future__ import annotations

import math

import can
import pytest

from drivers.can_yaw import YawRateDecoder
from drivers.profiles import PROFILES, get_profile, load_dbc


def _frame(profile: str, values: dict[str, float], t: float = 1.0) -> can.Message:
    sig = get_profile(profile).yaw_rate
    assert sig is not None
    msg = load_dbc(get_profile(profile).dbc_file).get_message_by_frame_id(sig.frame_id)
    full = {s.name: 0.0 for s in msg.signals} | values
    return can.Message(arbitration_id=sig.frame_id, data=msg.encode(full, strict=False),
                       is_extended_id=False, timestamp=t)  # fmt: skip


@pytest.mark.parametrize(
    ("profile", "sign_bit"), [("vw_mqb", "ESP_VZ_Gierrate"), ("vw_pq", "BR5_Vorzeichen")]
)
def test_a_magnitude_with_its_sign_bit_decodes_to_a_signed_rate(
    profile: str, sign_bit: str
) -> None:
    """Volkswagen sends an unsigned magnitude and a sign bit: set, the rate is negative (as
    openpilot reads it); without the bit every turn would read as a left turn."""
    sig = get_profile(profile).yaw_rate
    assert sig is not None and sig.sign == sign_bit
    dec = YawRateDecoder(profile)
    left = dec.feed(_frame(profile, {sig.signal: 12.5, sign_bit: 0}))
    right = dec.feed(_frame(profile, {sig.signal: 12.5, sign_bit: 1}))
    assert left is not None and right is not None
    assert math.degrees(left.yaw_rate_rad_s) == pytest.approx(12.5)
    assert math.degrees(right.yaw_rate_rad_s) == pytest.approx(-12.5)


def test_every_profiles_yaw_signal_is_in_its_dbc_with_a_range_an_esc_sensor_has() -> None:
    """Each named signal (and sign bit) exists in its DBC, in a unit the decoder knows, and
    spans what an ESC yaw-rate sensor measures (at least +-40 deg/s, at most +-400) in steps
    finer than the filter's reading noise (0.11 deg/s) or, Toyota's, at most 0.25 deg/s."""
    from drivers.can_yaw import UNIT_TO_RAD_S

    seen = 0
    for name, p in PROFILES.items():
        if p.yaw_rate is None:
            continue
        seen += 1
        msg = load_dbc(p.dbc_file).get_message_by_frame_id(p.yaw_rate.frame_id)
        s = msg.get_signal_by_name(p.yaw_rate.signal)
        if p.yaw_rate.sign is not None:
            msg.get_signal_by_name(p.yaw_rate.sign)
        to_deg = math.degrees(UNIT_TO_RAD_S[p.yaw_rate.unit])
        if s.is_signed:
            lo, hi = -(1 << (s.length - 1)) * s.scale, ((1 << (s.length - 1)) - 1) * s.scale
        else:
            lo, hi = s.offset, s.offset + ((1 << s.length) - 1) * s.scale
        if p.yaw_rate.sign is not None:  # a magnitude: the sign bit gives the other side
            lo = -hi
        reach = min(abs(lo), abs(hi)) * to_deg
        assert 40.0 <= reach and max(abs(lo), abs(hi)) * to_deg <= 1000.0, (name, lo, hi)  # noqa: SIM300
        assert s.scale * to_deg <= 0.25, (name, s.scale * to_deg)
    assert seen >= 8
