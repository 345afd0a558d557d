"""numpy's BLAS kept on one thread while RESTframe renders.

OpenBLAS (the BLAS of numpy's PyPI wheels, which Blender ships too) splits a large matrix
product over every core.  RESTframe's products are thin -- (n, 3) arrays against 3-vectors or
a few cone axes -- and its own render threads already fill the cores: two render threads whose
products each start OpenBLAS's threads oversubscribe the cores and mostly wait on each other
(measured on 2 cores: two render threads 0.9x one thread with OpenBLAS threading, 1.4-1.55x
without; one render thread is also 5% faster without).  threadpoolctl does this for any BLAS;
this does it for OpenBLAS only, without a dependency.  Where no OpenBLAS is found it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import sys
import threading

_lock = threading.Lock()
_users = 0  # renders running: the thread count is restored when the last one ends
_saved = None
_controls = None  # (set, get) once looked up; False when there is no OpenBLAS


def _library_paths() -> list[str]:
    """Shared libraries of this process that may be OpenBLAS: those mapped (Linux) and those
    shipped inside numpy's wheel (``numpy.libs`` on Linux and Windows, ``numpy/.dylibs`` on macOS)."""
    paths = []
    if sys.platform.startswith("linux"):
        try:
            with open("/proc/self/maps") as maps:
                paths += [line.split()[-1] for line in maps if "openblas" in line.lower()]
        except OSError:
            pass
    import numpy

    root = os.path.dirname(numpy.__file__)
    for folder in (os.path.join(root, os.pardir, "numpy.libs"), os.path.join(root, ".dylibs")):
        paths += glob.glob(os.path.join(folder, "*openblas*"))
    return list(dict.fromkeys(paths))


def _openblas():
    """(set_num_threads, get_num_threads) of the OpenBLAS numpy loaded, or None."""
    global _controls
    if _controls is None:
        _controls = False
        for path in _library_paths():
            try:
                library = ctypes.CDLL(path)
            except OSError:
                continue
            for suffix in ("64_", ""):  # numpy's wheels build OpenBLAS with 64-bit integers, suffixed
                set_threads = getattr(library, "openblas_set_num_threads" + suffix, None)
                get_threads = getattr(library, "openblas_get_num_threads" + suffix, None)
                if set_threads is not None and get_threads is not None:
                    set_threads.argtypes, set_threads.restype = [ctypes.c_int], None
                    get_threads.argtypes, get_threads.restype = [], ctypes.c_int
                    _controls = (set_threads, get_threads)
                    break
            if _controls:
                break
    return _controls or None


@contextlib.contextmanager
def single_threaded():
    """One BLAS thread while the block runs; the previous count comes back after the last
    overlapping block ends."""
    global _users, _saved
    controls = _openblas()
    if controls is None:
        yield
        return
    set_threads, get_threads = controls
    with _lock:
        if _users == 0:
            _saved = get_threads()
            set_threads(1)
        _users += 1
    try:
        yield
    finally:
        with _lock:
            _users -= 1
            if _users == 0:
                set_threads(_saved)
