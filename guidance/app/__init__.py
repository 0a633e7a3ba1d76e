"""The in-car application shell: ports, wiring, config, checkpoint, watchdog."""
