"""Simulated wheel-speed sensors that speak the car's CAN protocol (SPEC section 4, 6).

``SimCanWheels`` encodes wheel speeds with the vehicle's DBC (cantools, through the same profile
the real driver uses) and sends them on a python-can bus, ``virtual`` by default, so the
application decodes them with the real ``drivers.can_odometry`` code. It can run on its own
thread at the car's message rate (absolute monotonic deadlines), or be stepped by an
accelerated simulation with explicit timestamps (pair it with ``CanOdometryConfig(clock="frame")``).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import can

from drivers.can_decode import MAX_SPEED_MPS
from drivers.profiles import (
    VehicleProfile,
    WheelSignals,
    get_profile,
    honda_checksum,
    load_dbc,
)
from hal_sim._periodic import PeriodicThread

log = logging.getLogger(__name__)

# GM Global A direction field (VAL_ 842): 0 Stationary, 1 Forward, 2 Reverse.
_DIR_STATIONARY, _DIR_FORWARD, _DIR_REVERSE = 0, 1, 2


class SimCanWheels:
    """Wheel speeds (m/s, signed: negative is reverse) -> DBC-encoded frames on a bus."""

    def __init__(
        self,
        channel: str = "sim_can0",
        *,
        interface: str = "virtual",
        profile: VehicleProfile | str = "gm_global_a",
        period_s: float | None = None,
        bus_options: dict[str, Any] | None = None,
        name: str = "sim_can",
    ) -> None:
        self.profile = get_profile(profile) if isinstance(profile, str) else profile
        self.channel = channel
        self.interface = interface
        self.period_s = period_s or self.profile.message_period_s
        self.name = name
        self._bus_options = dict(bus_options or {})
        db = load_dbc(self.profile.dbc_file)
        self._rear = db.get_message_by_frame_id(self.profile.rear.frame_id)
        self._front = db.get_message_by_frame_id(self.profile.front.frame_id)
        self._lock = threading.Lock()
        self._speeds = (0.0, 0.0, 0.0, 0.0)  # rear left, rear right, front left, front right
        self._bus: can.BusABC | None = None
        self._tx: PeriodicThread | None = None
        self.frames_sent = 0
        self.send_errors = 0

    # lifecycle -------------------------------------------------------------------------------

    def open(self) -> SimCanWheels:
        if self._bus is None:
            options = dict(self._bus_options)
            if self.interface == "virtual":
                options.setdefault("preserve_timestamps", True)  # frames carry our clock
            self._bus = can.Bus(interface=self.interface, channel=self.channel, **options)
        return self

    def close(self) -> None:
        self.stop()
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    def __enter__(self) -> SimCanWheels:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # speeds ----------------------------------------------------------------------------------

    def set_speeds(
        self,
        rear_left_mps: float,
        rear_right_mps: float,
        front_left_mps: float | None = None,
        front_right_mps: float | None = None,
    ) -> None:
        """Wheel speeds from now on; fronts default to the rears (straight driving)."""
        fl = rear_left_mps if front_left_mps is None else front_left_mps
        fr = rear_right_mps if front_right_mps is None else front_right_mps
        with self._lock:
            self._speeds = (rear_left_mps, rear_right_mps, fl, fr)

    def encode(self) -> list[can.Message]:
        """The frames for the current speeds, in the car's order, without timestamps."""
        with self._lock:
            rl, rr, fl, fr = self._speeds
        p = self.profile
        if p.rear.frame_id == p.front.frame_id:
            values = self._values(self._rear, p.rear, rl, rr)
            values.update(self._values(self._rear, p.front, fl, fr))
            return [self._frame(self._rear, values)]
        # Front first, as the GM car sends them (0x348 then 0x34A, 0.3 ms apart).
        return [
            self._frame(self._front, self._values(self._front, p.front, fl, fr)),
            self._frame(self._rear, self._values(self._rear, p.rear, rl, rr)),
        ]

    def send(self, t_s: float | None = None) -> None:
        """Send one set of frames now, stamped ``t_s`` (default: ``time.time()``, like a bus)."""
        stamp = time.time() if t_s is None else t_s
        frames = self.encode()
        for msg in frames:
            msg.timestamp = stamp
        self.send_frames(frames)

    def send_frames(self, frames: list[can.Message]) -> None:
        """Send frames as they are (stamped by the caller: ``hal_sim.car_inputs.DeviceWire``)."""
        bus = self.open()._bus
        assert bus is not None
        for msg in frames:
            try:
                bus.send(msg)
                self.frames_sent += 1
            except can.CanError as exc:
                self.send_errors += 1
                log.debug("%s: send failed: %s", self.name, exc)

    # own thread at the car's rate ------------------------------------------------------------

    def start(self) -> None:
        """Send at the profile's message rate on a thread until ``stop``."""
        self.open()
        if self._tx is None:
            self._tx = PeriodicThread(f"{self.name}-tx", self.period_s, self.send)
            self._tx.start()

    def stop(self) -> None:
        if self._tx is not None:
            self._tx.stop()
            self._tx = None

    # encoding ----------------------------------------------------------------------------------

    def _values(self, spec: Any, sig: WheelSignals, left: float, right: float) -> dict[str, float]:
        """Physical signal values for one axle: speeds in the DBC unit, directions, no faults."""
        p = self.profile
        to_unit = 1.0 / (p.unit_to_mps * p.speed_scale)
        values: dict[str, float] = {}
        for name, speed in ((sig.left, left), (sig.right, right)):
            raw = speed * to_unit if p.signed_speeds else abs(speed) * to_unit
            lo, hi = physical_range(spec.get_signal_by_name(name))
            top = 0.99 * MAX_SPEED_MPS * to_unit  # never what the decoder calls implausible
            values[name] = min(max(raw, lo, -top), hi, top)
        for dir_name, speed in ((sig.left_direction, left), (sig.right_direction, right)):
            if dir_name is not None:
                values[dir_name] = (
                    _DIR_FORWARD if speed > 0 else _DIR_REVERSE if speed < 0 else _DIR_STATIONARY
                )
        for fault_name in (sig.left_fault, sig.right_fault):
            if fault_name is not None:
                values[fault_name] = 0
        return values

    def _frame(self, spec: Any, values: dict[str, float]) -> can.Message:
        full: dict[str, float] = {s.name: 0.0 for s in spec.signals}
        full.update(values)
        data = bytearray(spec.encode(full, strict=False))
        if self.profile.checksum == "honda":
            data[-1] = (data[-1] & 0xF0) | honda_checksum(spec.frame_id, bytes(data))
        return can.Message(arbitration_id=spec.frame_id, data=data, is_extended_id=False)


def physical_range(signal: Any) -> tuple[float, float]:
    """What the signal's bits can carry (a cantools signal; also the simulated yaw rate's,
    ``hal_sim.car_inputs``). opendbc's declared [min|max] are not used: they are
    not reliable for wheel speeds (Mazda's says 0-15 km/h; Toyota's 0-250 though its offset
    carries reverse speeds)."""
    if signal.is_signed:
        raw_lo, raw_hi = -(2 ** (signal.length - 1)), 2 ** (signal.length - 1) - 1
    else:
        raw_lo, raw_hi = 0, 2**signal.length - 1
    a = raw_lo * signal.scale + signal.offset
    b = raw_hi * signal.scale + signal.offset
    return min(a, b), max(a, b)
