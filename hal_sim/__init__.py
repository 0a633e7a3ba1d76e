"""The simulated world: the city, the car and its sensors, the Monte Carlo study engine."""

NUMBA_SOURCES = (
    "params.py",
    "city.py",
    "world.py",
    "ekf.py",
    "engine.py",
    "trial.py",
    "field.py",
    "rng.py",
    "car.py",
)
"""hal_sim's compiled sources, for numba's cache key (``guidance/_numba_cache.py``): every
module with ``@njit`` functions and every module whose constants they compile in."""
