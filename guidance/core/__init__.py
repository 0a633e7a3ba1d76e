"""The pure core: messages, math, estimator, navigator, prompts, pipeline (no I/O)."""

NUMBA_SOURCES = ("angles.py", "model.py", "law.py", "navigator.py")
"""The core's compiled sources, for numba's cache key (``guidance/_numba_cache.py``); angles:
the plain functions model compiles; navigator: the engine's memory size."""
