"""OpenBLAS threads of this process (DESIGN §5: pin OpenBLAS to one thread).

NumPy's LAPACK is where ``epipolar_tree`` takes the SVD of its kernel
sample; with OpenBLAS's default of one thread per core it competes with
Dr.Jit's own threads and the timings depend on the machine's load.
:func:`pin_one_thread` sets ``OPENBLAS_NUM_THREADS=1`` (effective when NumPy
has not loaded its BLAS yet) and, if the library is already loaded, sets its
thread count through its C API.  Nothing here imports NumPy.
"""
from __future__ import annotations

import os
from contextlib import contextmanager

ENV_VARIABLE = "OPENBLAS_NUM_THREADS"


def _openblas():
    """(get, set) of the OpenBLAS loaded into this process, via ctypes, or
    None (not loaded, not OpenBLAS, or no ``/proc/self/maps``)."""
    import ctypes

    try:
        with open("/proc/self/maps") as maps:
            libs = {line.split()[-1] for line in maps
                    if "openblas" in line.lower() and line.split()[-1].startswith("/")}
    except OSError:
        return None
    for path in sorted(libs):
        lib = ctypes.CDLL(path)
        for get, put in (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
                         ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
                         ("openblas_get_num_threads", "openblas_set_num_threads")):
            if hasattr(lib, get) and hasattr(lib, put):
                return getattr(lib, get), getattr(lib, put)
    return None


def blas_threads() -> int | None:
    """OpenBLAS's current thread count (None if it is not loaded)."""
    api = _openblas()
    return int(api[0]()) if api else None


@contextmanager
def limit_blas_threads(n: int):
    """Run a block with OpenBLAS limited to ``n`` threads, then restore it
    (a no-op without OpenBLAS)."""
    api = _openblas()
    if api is None:
        yield
        return
    before = int(api[0]())
    api[1](int(n))
    try:
        yield
    finally:
        api[1](before)


def pin_one_thread() -> None:
    """One OpenBLAS thread for this process: the environment variable (unless
    the user set it) for a BLAS loaded later, the C API for one loaded
    already."""
    os.environ.setdefault(ENV_VARIABLE, "1")
    api = _openblas()
    if api is not None and os.environ[ENV_VARIABLE] == "1":
        api[1](1)
