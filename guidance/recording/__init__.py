"""Drive recording to MCAP (SPEC section 6) and the reader that replay uses.

Every run can record its raw inputs (``/can``, ``/nmea``, ``/camera`` with
``/camera/thumbnail``, ``/scene``) and its outputs (``/state``, ``/decision``,
``/prompt``, ``/landmark``, ``/health``) to MCAP files that Foxglove opens:
JSON-encoded channels, each with a JSON Schema (``/camera/thumbnail`` uses
Foxglove's own ``foxglove.CompressedImage`` so the Image panel shows it). The
output messages are exactly the telemetry messages (docs/telemetry.md).

Time: a message's MCAP ``log_time`` is its ``t_s`` (the car's monotonic clock,
or simulated time) in nanoseconds, and the JSON payload keeps the exact float
``t_s``; ``publish_time`` is wall-clock nanoseconds, for people.

Crash safety: messages are grouped in small chunks (``chunk_size_bytes``,
default 64 KiB) and a chunk goes to the operating system the moment it is
closed, also every ``flush_interval_s``; so a crash (even SIGKILL) loses at most
the chunk being filled. A file cut short has no summary; ``Reader`` then reads
it record by record up to the damage.

Files rotate by size and age and the oldest are deleted beyond a total cap.
Writing happens on a thread fed by a bounded queue: ``record*`` never blocks,
and when the queue is full the message is dropped and counted. A full disk
(ENOSPC, EDQUOT, or EFBIG from a file-size limit) stops the recording, sets
``health().status`` to "disk_full" and counts the error; the caller carries on.
"""
