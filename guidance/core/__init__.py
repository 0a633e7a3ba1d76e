"""The pure core: messages, math, estimator, navigator, prompts, pipeline (no I/O)."""

NUMBA_SOURCES = ("model.py", "law.py", "navigator.py")  # navigator: the engine's memory size
"""The core's compiled sources, for numba's cache key (``guidance/_numba_cache.py``)."""
