"""Stage 2 of the core, "plannerd": the estimate and the scene in, decisions and prompts out.

The navigator (the decision law's bookkeeping), the guide (the intersections reported ahead,
announcements, the exit taken), the road ahead, the turn detector, announcement timing and the
chance of reaching the goal. Nothing here imports ``guidance.core.localize``: it reads the
estimate as a value (``tests/test_layers.py``).
"""

NUMBA_SOURCES = ("navigator.py",)
"""The planner's sources numba compiles in, for its cache key (``guidance/_numba_cache.py``):
navigator, the engine's memory size."""
