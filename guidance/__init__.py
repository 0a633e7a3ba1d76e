"""Urban driver guidance without GPS or a road map: the brain (no hardware in here)."""

from guidance import _numba_cache

_numba_cache.configure()
