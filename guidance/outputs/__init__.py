"""What the car publishes and records, written once: the output table (``kinds``), the
encoders (``messages``) and their schemas (``schemas``), and ``MessageSink`` (``sink``), the
path both telemetry and the recorder implement. Pure: no zenoh, no mcap, no numba."""
