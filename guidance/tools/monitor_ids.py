"""Two publishers behind one vehicle id (issue 41, "one id, one car").

A vehicle id is a zenoh key chunk, so two cars configured with the same id (two simulated
drives before ids were per drive, a fleet with a copied config) publish on the same keys: a
monitor sees one car whose position jumps between the two, and whose liveliness token (zenoh
merges two tokens on one key at a router) goes only when the last of them goes. What does
tell them apart:

* **Zenoh ids.** The project's cars stamp each sample with zenoh's source info (their
  session's id); another program's may too. Samples of one car from two sessions.
* **Sequence numbers.** Every message carries its kind's ``seq``, rising by one per message
  of one publisher. Two publishers' numbers interleave: one goes back, then both go on.

Either alone is not proof: a car that restarts comes back with a new session and ``seq``
from 1, and a message delivered twice (two routes) repeats a number. So the evidence is the
same for both: each source (a zenoh id, or a run of rising ``seq``) is a *track*; a message
that fits no track (a new zenoh id; a ``seq`` no higher than every track's last) starts one;
two publishers are shown when a track older than the newest one goes on after the newest one
began. A restarted car's old track never goes on; a repeated delivery (the same ``seq``,
``t_s`` and position) is not a message. Tracks idle for ``TRACK_IDLE_S`` end, and the alarm
stays until ``ALARM_HOLD_S`` after its last evidence.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from typing import Any

TRACK_IDLE_S = 3.0
"""A source silent this long (monitor clock) has ended: 30 states of a car at 10 Hz, longer
than the monitor's pauses between looks (at most 0.25 s) and a router's restart (about 3 s at
1,000 cars: a car that came back with a new session then starts a new track anyway)."""
ALARM_HOLD_S = 5.0
"""The alarm is shown until this long after its last evidence (two tracks going on)."""
MAX_TRACKS = 8
"""Tracks kept per car and kind of evidence (the oldest go first)."""
RECENT = 16
"""Recent messages remembered per car to recognise a repeated delivery."""


@dataclass(slots=True)
class _Track:
    last: int | str
    born: int
    """Order of birth among the car's tracks of this kind of evidence."""
    seen_s: float


@dataclass(slots=True)
class _Tracks:
    """Tracks of one kind of evidence: ``by_seq`` places a message on the track whose last
    ``seq`` is the highest below it; otherwise a track is a source's name."""

    by_seq: bool
    tracks: list[_Track] = field(default_factory=list)
    births: int = 0

    def see(self, value: int | str, now_s: float) -> bool:
        """Place one message; True when it is evidence of two publishers."""
        if len(self.tracks) == 1:  # the usual case, one publisher: no list built
            only = self.tracks[0]
            fits = int(only.last) < int(value) if self.by_seq else only.last == value
            if fits and now_s - only.seen_s <= TRACK_IDLE_S:
                only.last, only.seen_s = value, now_s
                return False
        self.tracks = [t for t in self.tracks if now_s - t.seen_s <= TRACK_IDLE_S]
        if self.by_seq:
            below = [t for t in self.tracks if isinstance(t.last, int) and t.last < int(value)]
            track = max(below, key=lambda t: int(t.last), default=None)
        else:
            track = next((t for t in self.tracks if t.last == value), None)
        if track is None:
            self.births += 1
            self.tracks.append(_Track(value, self.births, now_s))
            del self.tracks[:-MAX_TRACKS]
            return False
        track.last, track.seen_s = value, now_s
        return track.born < max(t.born for t in self.tracks)


@dataclass(slots=True)
class Publishers:
    """What one car's messages say about who publishes them (see the module)."""

    seqs: dict[str, _Tracks] = field(default_factory=dict)
    """Per message kind: its ``seq`` tracks."""
    sources: _Tracks = field(default_factory=lambda: _Tracks(by_seq=False))
    recent: deque[Hashable] = field(default_factory=lambda: deque(maxlen=RECENT))
    evidence: dict[str, tuple[float, str]] = field(default_factory=dict)
    """Per kind of evidence ("seq", "source"): monitor clock of its last sighting, and what."""

    def see(self, kind: str, message: Mapping[str, Any], source: str, now_s: float) -> str:
        """Take one live message (not a late-join reply); the alarm to show now ("" none)."""
        seq = message.get("seq")
        if type(seq) is int:
            mark = (kind, seq, message.get("t_s"), message.get("x_m"))  # numbers (checked)
            if mark in self.recent:
                return self.alarm(now_s)  # the same message delivered again
            self.recent.append(mark)
            tracks = self.seqs.get(kind)
            if tracks is None:
                tracks = self.seqs[kind] = _Tracks(by_seq=True)
            if tracks.see(seq, now_s):
                self.evidence["seq"] = (now_s, f"{kind} sequence numbers from two runs interleave")
        if source and self.sources.see(source, now_s):
            ids = sorted(str(t.last)[:8] for t in self.sources.tracks)
            self.evidence["source"] = (
                now_s, f"{len(ids)} zenoh sessions publish it ({', '.join(ids)})"
            )  # fmt: skip
        return self.alarm(now_s)

    def alarm(self, now_s: float) -> str:
        why = [text for at, text in self.evidence.values() if now_s - at <= ALARM_HOLD_S]
        return f"TWO PUBLISHERS behind this vehicle id: {'; '.join(why)}" if why else ""
