"""How many threads the matcher may use: OpenCV's pool and the BLAS libraries' pools.

A matcher worker (``recognise.RecogniserWorker``) is one process working one frame at a time
beside the car's 100 Hz loop on a 2-core laptop. Left alone, three thread pools in it would
each spread a frame over every core: OpenCV's (``cv2.setNumThreads``), numpy's OpenBLAS (the
XFeat cosine matrix, the whole-database search's cosines, the global index's projection)
and the OpenBLAS OpenCV's wheel carries (its DNN, which runs XFeat). ``cap_threads`` caps
all three in the calling process:

* OpenCV: ``cv2.setNumThreads``;
* every OpenBLAS already loaded: its ``*openblas_set_num_threads*`` entry point, found in
  the process's memory map and called through ``ctypes`` (what ``threadpoolctl`` does; it is
  not a dependency), read back through the matching getter;
* libraries loaded later and child processes: ``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``
  and ``MKL_NUM_THREADS`` in the environment (read when such a library starts).

Linux (``/proc/self/maps``); elsewhere only OpenCV and the environment are capped.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

THREAD_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""The environment variables thread pools read when they start."""

_SETTERS = (
    "openblas_set_num_threads",
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
)
_GETTERS = (
    "openblas_get_num_threads",
    "scipy_openblas_get_num_threads64_",
    "scipy_openblas_get_num_threads",
)


def loaded_blas_libraries(maps: Path = Path("/proc/self/maps")) -> list[str]:
    """Paths of the OpenBLAS shared libraries mapped into this process (numpy's and
    OpenCV's wheels each carry one), in the order first mapped."""
    try:
        text = maps.read_text()
    except OSError:
        return []
    out: list[str] = []
    for line in text.splitlines():
        path = line.split(maxsplit=5)[-1] if line.count(" ") >= 5 else ""
        name = os.path.basename(path)
        if "openblas" in name and ".so" in name and path not in out:
            out.append(path)
    return out


def _entry(lib: ctypes.CDLL, names: tuple[str, ...]) -> Iterator[Any]:
    for name in names:
        fn = getattr(lib, name, None)
        if fn is not None:
            yield fn


def blas_threads() -> dict[str, int]:
    """Library file name -> its current thread count, for every loaded OpenBLAS."""
    out: dict[str, int] = {}
    for path in loaded_blas_libraries():
        lib = ctypes.CDLL(path)
        for get in _entry(lib, _GETTERS):
            get.restype = ctypes.c_int
            out[os.path.basename(path)] = int(get())
            break
    return out


def cap_blas_threads(n: int) -> dict[str, int]:
    """Set every loaded OpenBLAS to ``n`` threads; library file name -> the count read back."""
    for path in loaded_blas_libraries():
        lib = ctypes.CDLL(path)
        for put in _entry(lib, _SETTERS):
            put.argtypes = [ctypes.c_int]
            put.restype = None
            put(n)
            break
    return blas_threads()


def cap_threads(n: int) -> dict[str, int]:
    """Cap OpenCV, every loaded OpenBLAS and the environment's thread pools at ``n`` threads
    in this process. Returns what was read back: ``opencv`` and one entry per OpenBLAS."""
    if n < 1:
        raise ValueError("threads must be at least 1")
    import cv2

    for var in THREAD_ENV:
        os.environ[var] = str(n)
    cv2.setNumThreads(n)
    return {"opencv": int(cv2.getNumThreads()), **cap_blas_threads(n)}
