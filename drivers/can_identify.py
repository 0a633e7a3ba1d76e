"""Which car is this? A vehicle profile from the CAN ids a log (or the live bus) carries.

opendbc 0.3.1 keeps CAN-id fingerprints for two makes only (GM, comma body: openpilot now
identifies cars by firmware versions over UDS, which a passive listener cannot ask), so the
rule here is over the DBCs' own message lists, and it is argued, not fitted:

1. **The wheel-speed messages are there.** A profile is a candidate only if every message
   it decodes wheel speeds from is on one channel of the log with the length its DBC gives
   (a DBC fixes each message's length: a car whose id 0xAA carries 6 bytes is not a Toyota).
2. **Its DBC explains the bus far beyond chance.** Of the distinct standard ids on that
   channel, the share its DBC defines with the length seen ("explained") must be at least
   ``MIN_LIFT`` times the share of the 2,048 standard ids the DBC defines at all: what it
   would explain of a bus whose ids have nothing to do with it (the null model; a
   length that must match too only lowers that). opendbc's DBCs describe only part of a
   real bus (a third to a half of the ids on the logs here), but that part is 7 to 22
   times chance for the right make, and at most 8 for another make's DBC on a channel
   that also has to carry its wheel-speed ids. For a channel of n ids the count explained
   by chance is binomial: with n = 113 and a DBC of 2.8 % of the id space, five times
   chance is 16 ids where 3 are expected, a tail below 1e-6. A log that holds only a few
   ids (a logger that kept the wheel-speed frames) clears the lift at once; there the ids
   themselves and rule 3 carry the evidence.
3. **The wheel speeds decode.** Through the profile's own decoder, at least
   ``MIN_ACCEPTED`` of the wheel-speed frames are accepted (checksums, faults, the
   decoder's plausibility limits: 90 m/s, 2 g): another car's bytes under a profile's id
   read as garbage speeds.

Of the candidates, the one whose DBC explains most is chosen. Profiles whose wheel speeds
decode identically (same messages, bit layouts, scale, checksum: Toyota's four DBCs, Honda's
twelve) are one answer for odometry; if a candidate that decodes differently explains
within ``AMBIGUOUS_WITHIN`` of the best, the rule does not guess. No candidate: an unknown
car. Both are a one-line ``UserError`` (exit 2 at the command line).
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import can

from drivers.opendbc_dbc import load_dbc, message_lengths
from drivers.profiles import PROFILES, VehicleProfile
from guidance.errors import UserError

MIN_LIFT = 5.0
"""How many times its share of the 11-bit id space a DBC must explain of a channel's ids."""
ID_SPACE = 2048
MIN_ACCEPTED = 0.9
"""Share of a profile's wheel-speed frames its decoder must accept."""
AMBIGUOUS_WITHIN = 0.05
"""A differently-decoding candidate explaining within this of the best: no guess."""
MAX_FRAMES = 200_000
"""Frames looked at (the start of a long log: a bus shows its ids within seconds)."""
MAX_DECODED = 2_000
"""Wheel-speed frames decoded per candidate profile."""


@dataclass(frozen=True, slots=True)
class Candidate:
    profile: str
    channel: str
    explained: float
    ids: int
    """Distinct standard ids on the channel."""
    accepted: float
    """Share of the wheel-speed frames the decoder accepted."""


@dataclass(slots=True)
class Identification:
    """What the rule found: the chosen profile, why, and every candidate."""

    profile: str | None
    reason: str
    candidates: list[Candidate] = field(default_factory=list)
    same_wheel_speeds: list[str] = field(default_factory=list)
    """Other candidates that decode the wheel speeds exactly as the chosen one."""

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.profile,
            "reason": self.reason,
            "same_wheel_speeds": self.same_wheel_speeds,
            "candidates": [
                {"profile": c.profile, "channel": c.channel, "explained": round(c.explained, 3),
                 "ids": c.ids, "accepted": round(c.accepted, 3)}
                for c in self.candidates
            ],
        }  # fmt: skip


def decoding_key(profile: VehicleProfile) -> tuple[Any, ...]:
    """What decides the wheel speeds a profile reads from the bus: profiles with equal keys
    give the same distances from the same frames."""
    db = load_dbc(profile.dbc_file)
    layout = []
    for axle in (profile.rear, profile.front):
        msg = db.get_message_by_frame_id(axle.frame_id)
        for name in (axle.left, axle.right, axle.left_direction, axle.right_direction):
            if name is not None:
                s = msg.get_signal_by_name(name)
                layout.append((axle.frame_id, msg.length, s.start, s.length, s.byte_order,
                               s.is_signed, s.scale, s.offset))  # fmt: skip
    return (tuple(layout), profile.unit_to_mps, profile.signed_speeds, profile.checksum,
            profile.reverse_values, profile.fault_direction_values)  # fmt: skip


def _id_share(dbc: str) -> float:
    """The share of the standard id space the DBC defines (the null model's explained)."""
    return sum(1 for fid in message_lengths(dbc) if fid < ID_SPACE) / ID_SPACE


def _accepted(profile: VehicleProfile, frames: list[can.Message]) -> float:
    from drivers.can_decode import WheelSpeedDecoder

    dec = WheelSpeedDecoder(profile)
    for msg in frames[:MAX_DECODED]:
        dec.feed(msg)
    seen = dec.frames - dec.ignored
    bad = sum(dec.rejected_by_reason[r] for r in ("dlc", "checksum", "decode", "fault",
                                                  "implausible", "spike"))  # fmt: skip
    return 0.0 if seen == 0 else 1.0 - bad / seen


def identify(messages: Iterable[can.Message]) -> Identification:
    """Apply the rule (see the module) to the frames of a log or a bus."""
    ids: dict[str, Counter[tuple[int, int]]] = defaultdict(Counter)
    wheel_ids = {fid for p in PROFILES.values() for fid in (p.rear.frame_id, p.front.frame_id)}
    wheel_frames: dict[tuple[str, int], list[can.Message]] = defaultdict(list)
    for n, msg in enumerate(messages):
        if n >= MAX_FRAMES:
            break
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            continue
        channel = str(msg.channel)
        ids[channel][(msg.arbitration_id, len(msg.data))] += 1
        if msg.arbitration_id in wheel_ids:
            kept = wheel_frames[(channel, msg.arbitration_id)]
            if len(kept) < MAX_DECODED:
                kept.append(msg)
    candidates: list[Candidate] = []
    for name, profile in PROFILES.items():
        lengths = message_lengths(profile.dbc_file)
        best: Candidate | None = None
        for channel, seen in ids.items():
            present = {fid for fid, _ in seen}
            needed = {profile.rear.frame_id, profile.front.frame_id}
            if not all((fid, lengths.get(fid)) in seen for fid in needed):
                continue
            explained = sum(1 for fid, dlc in seen if lengths.get(fid) == dlc) / len(present)
            if best is None or explained > best.explained:
                best = Candidate(name, channel, explained, len(present), math.nan)
        if best is None or best.explained < MIN_LIFT * _id_share(profile.dbc_file):
            continue
        frames = sorted(
            (m for fid in {profile.rear.frame_id, profile.front.frame_id}
             for m in wheel_frames[(best.channel, fid)]),
            key=lambda m: m.timestamp,
        )  # fmt: skip
        accepted = _accepted(profile, frames)
        if accepted >= MIN_ACCEPTED:
            candidates.append(Candidate(name, best.channel, best.explained, best.ids, accepted))
    return _choose(candidates, sum(len(v) for v in ids.values()))


def _choose(candidates: list[Candidate], distinct_ids: int) -> Identification:
    candidates.sort(key=lambda c: (-c.explained, c.profile))
    if not candidates:
        return Identification(
            None,
            f"unknown car: none of the {len(PROFILES)} profiles' wheel-speed messages is on "
            f"the bus with its DBC's length, under a DBC that explains {MIN_LIFT:g} times "
            f"chance of the ids there ({distinct_ids} id/length pairs seen), and decodes to "
            "plausible speeds",
        )
    best = candidates[0]
    key = decoding_key(PROFILES[best.profile])
    same = [c.profile for c in candidates[1:] if decoding_key(PROFILES[c.profile]) == key]
    rivals = [
        c for c in candidates[1:]
        if c.profile not in same and best.explained - c.explained <= AMBIGUOUS_WITHIN
    ]  # fmt: skip
    if rivals:
        names = ", ".join(f"{c.profile} ({c.explained:.0%})" for c in rivals)
        return Identification(
            None,
            f"ambiguous: {best.profile} ({best.explained:.0%} of the ids explained) or {names}"
            ", which read the wheel speeds differently; name one with --profile",
            candidates,
        )
    also = f"; {', '.join(same)} read the wheel speeds the same way" if same else ""
    return Identification(
        best.profile,
        f"{best.profile} ({PROFILES[best.profile].brand}): its wheel-speed messages are on "
        f"channel {best.channel}, its DBC ({PROFILES[best.profile].dbc_file}) defines "
        f"{best.explained:.0%} of the {best.ids} ids there, and {best.accepted:.0%} of the "
        f"wheel-speed frames decode{also}",
        candidates,
        same,
    )


def identify_or_refuse(messages: Iterable[can.Message]) -> Identification:
    """``identify``, with an unknown or ambiguous car as a one-line ``UserError``."""
    found = identify(messages)
    if found.profile is None:
        raise UserError(f"--profile auto: {found.reason}")
    return found
