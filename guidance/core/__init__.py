"""The pure core: messages, math, estimator, navigator, prompts, pipeline (no I/O)."""
