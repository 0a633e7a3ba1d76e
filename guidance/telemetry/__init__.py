"""Zenoh telemetry (SPEC section 6): the car's state for remote monitors, and the monitor's side.

zenoh is wrapped here and nowhere else (HOUSE_STYLE). One ``Telemetry`` per car
process owns one zenoh session and publishes, under ``guidance/<vehicle_id>/``:

every kind of the output table (``guidance.outputs.kinds.OUTPUTS``: ``state``, ``decision``,
``prompt``, ``landmark``, ``health``, ``turn``, ``exit``),

as JSON objects carrying ``schema`` ("guidance.<kind>/<version>"), ``t_s`` (the
car's monotonic clock, the same time base as the estimator) and
``wall_time_unix_s`` (for logs only). The message schemas are in
docs/telemetry.md and in ``guidance.outputs.schemas`` (JSON Schema, also used by the MCAP
recorder). The car also holds the liveliness token ``guidance/<vehicle_id>`` and
answers queries on ``guidance/<vehicle_id>/<kind>`` with the latest message, so
a monitor that joins late sees the current state at once.

Publishing never blocks the caller: ``publish`` (through ``MessageSink.send``) stores the
message in a latest-value slot or a short bounded FIFO (the kind's ``policy``), and a publisher
thread encodes and sends it with zenoh's ``CongestionControl.DROP`` and ``express``. Everything
overwritten or pushed out before it was sent is counted as a drop, by reason, in ``health()``.
The session is opened by that thread too: if zenoh is unreachable (client mode with no router,
port taken, bad certificate) the car keeps running, telemetry health reports ``down`` and the
session is retried in the background. No zenoh error is
ever raised into the application after construction.

A remote goal (``guidance/<vehicle_id>/cmd/goal``, JSON ``{"x_m": .., "y_m": ..}``)
is subscribed to only when ``allow_remote_goal`` is set (off by default); who may
send one is then a matter for zenoh's access control (config/zenoh/). Malformed
or out-of-range goals are refused, counted and logged.

``MonitorClient`` is the receiving side used by ``guidance monitor``, the tests
and the latency benchmark.
"""
