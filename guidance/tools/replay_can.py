"""The raw CAN side of ``guidance replay`` (issue 38): a car's CAN frames through its own
decoders, frame by frame, routed as ``guidance run``'s CAN driver routes them.

``drivers.can_odometry.CanOdometry`` hands a frame of the profile's yaw-rate id to
``drivers.can_yaw.YawRateDecoder`` (and to nothing else) when the car's ``[vehicle]
yaw_source`` is "gyro" or "both", and every other frame to the wheel-speed decoder
(``drivers.can_decode.WheelSpeedDecoder``). ``CarCanDecoders`` is that routing without the
bus and the thread, for a CAN log (``replay.can_inputs``) and for the ``/can`` frames of a
raw recording (``replay_mcap.mcap_inputs(raw=True)``): one pass in the order the frames came,
so the wheel increments and the yaw rates reach the pipeline in the order the car had them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from guidance.core.messages import WheelOdometry, YawRate

if TYPE_CHECKING:
    from collections.abc import Iterator

    import can


class CarCanDecoders:
    """The car's CAN decoders (the wheel speeds; the yaw rate with ``yaw_rate``), fed frame
    by frame. A profile without a yaw-rate signal is refused with ``yaw_rate`` (``UserError``,
    as ``guidance run`` refuses it)."""

    def __init__(self, profile: str, *, yaw_rate: bool) -> None:
        from drivers.can_decode import WheelSpeedDecoder
        from drivers.can_yaw import YawRateDecoder

        self.wheels = WheelSpeedDecoder(profile)
        self.yaw = YawRateDecoder(profile) if yaw_rate else None

    def feed(self, frame: can.Message) -> WheelOdometry | YawRate | None:
        """What the car makes of one frame: an increment, a yaw rate, or nothing."""
        if self.yaw is not None and frame.arbitration_id == self.yaw.signal.frame_id:
            return self.yaw.feed(frame)
        return self.wheels.feed(frame)


def can_log_inputs(
    path: Path, profile: str, *, yaw_rate: bool
) -> Iterator[WheelOdometry | YawRate]:
    """A CAN log's inputs through the car's decoders (python-can's readers, one pass)."""
    from drivers.can_odometry import LogReadResult, read_can_log

    decoders = CarCanDecoders(profile, yaw_rate=yaw_rate)
    for msg in read_can_log(path, LogReadResult()):
        out = decoders.feed(msg)
        if out is not None:
            yield out
