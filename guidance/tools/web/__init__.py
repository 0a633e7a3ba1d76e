"""The web monitor (``guidance monitor --web``): server and static assets (package data)."""
