"""The pure core: messages, math, the two stages (``localize``, ``plan``), prompts, pipeline
(no I/O)."""

NUMBA_SOURCES = ("angles.py", "model.py", "law.py")
"""The core's compiled sources, for numba's cache key (``guidance/_numba_cache.py``); angles:
the plain functions model compiles. ``plan`` declares its own (navigator)."""
