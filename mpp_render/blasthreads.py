"""numpy's BLAS held to one thread while a frame renders (no bpy).

The render's own pool (parallel.worker_count) already keeps every core busy with the compiled
kernels.  numpy's OpenBLAS keeps threads of its own that, after each matrix product, spin on
``sched_yield`` waiting for the next one; between our workers they take a core's share
(``perf`` on p_slab_over_ground: 10 % of the CPU in ``blas_thread_server``).  The products the
engine makes (3x3 and 4x4 transforms of point lists, small least squares) are memory-bound
and gain nothing from more threads, so ``one_blas_thread()`` sets OpenBLAS to one thread for
the frame and restores the count it found.

OpenBLAS is found among the loaded libraries (``/proc/self/maps``) or beside numpy (its
wheels' ``numpy.libs`` / ``.dylibs``); its setter is looked up under the names OpenBLAS and
the scipy-openblas wheels export.  Where none is found (another BLAS, or none loaded) this
does nothing: the engine renders the same, only without the saving.
"""
from __future__ import annotations

import contextlib
import ctypes
import glob
import os
from typing import List, Optional, Tuple

# (getter, setter) names: OpenBLAS's own, its 64-bit-integer builds', the scipy-openblas wheels'
_NAMES = [(f"{pre}_get_num_threads{suf}", f"{pre}_set_num_threads{suf}")
          for pre in ("openblas", "scipy_openblas") for suf in ("", "64_")]
_found: Optional[List[Tuple[object, object]]] = None


def _candidates() -> List[str]:
    """Paths of loaded or bundled OpenBLAS libraries, each once."""
    paths = []
    try:
        with open("/proc/self/maps") as f:
            for line in f:
                p = line.rsplit(None, 1)[-1] if "/" in line else ""
                if "openblas" in os.path.basename(p).lower():
                    paths.append(p)
    except OSError:
        pass
    try:
        import numpy
        root = os.path.dirname(os.path.dirname(numpy.__file__))
        for pattern in ("numpy.libs/*openblas*", "numpy/.dylibs/*openblas*",
                        "numpy/_core/*openblas*"):
            paths += glob.glob(os.path.join(root, pattern))
    except ImportError:
        pass
    return list(dict.fromkeys(os.path.realpath(p) for p in paths))   # each file once


def _thread_functions(lib) -> Optional[Tuple[object, object]]:
    """The (get, set) thread-count functions ``lib`` exports, or None."""
    for get_name, set_name in _NAMES:
        getter, setter = getattr(lib, get_name, None), getattr(lib, set_name, None)
        if getter is not None and setter is not None:
            getter.argtypes, getter.restype = [], ctypes.c_int
            setter.argtypes, setter.restype = [ctypes.c_int], None
            return getter, setter
    return None


def _functions() -> List[Tuple[object, object]]:
    """(get, set) thread-count functions of each OpenBLAS found (cached)."""
    global _found
    if _found is None:
        _found = []
        for path in _candidates():
            try:
                pair = _thread_functions(ctypes.CDLL(path))
            except OSError:
                continue
            if pair is not None:
                _found.append(pair)
    return _found


def blas_threads() -> List[int]:
    """The thread count of each OpenBLAS found (empty where none is)."""
    return [int(get()) for get, _ in _functions()]


@contextlib.contextmanager
def one_blas_thread():
    """Within the block, every OpenBLAS found runs on one thread; its count is restored after."""
    funcs = _functions()
    before = [int(get()) for get, _ in funcs]
    for _, put in funcs:
        put(1)
    try:
        yield
    finally:
        for (_, put), n in zip(funcs, before):
            put(n)
