"""glibc's malloc tuned for a render's large temporaries, in the rendering process and its workers.

A render allocates and frees arrays of a sample batch's size (an (n, 3) float64 array of 65k
rays is 1.5 MB) thousands of times.  With glibc's defaults a freed block at the top of the heap
is given back to the system as soon as 128 KB-32 MB lie free there, and the next allocation of
the same size page-faults it back in: moving_sphere on one thread took 70-140k page faults and
12-20% more CPU time than with the tuning below (docs/speed.md); in one worker process
16-53k faults a render against 3.6k, and 4-15% more CPU.  (The 11x11 bars' 64-px tiles fault
~460 times a render either way: glibc's own sliding thresholds already keep arrays that small.)
Keeping up to 256 MB free lets the next batch reuse the same pages.  The top pad measured neither
faster nor slower (it only sizes the heap's growth steps), nor did huge pages for the heap
(``glibc.malloc.hugetlb``).  Worker processes get it from their environment (it
holds from their start); the process that renders in its own threads sets it when it renders
(:func:`tune`), for good (the memory it keeps is at most the trim threshold).  Elsewhere than glibc
(macOS, Windows, musl, or a Blender whose own allocator replaces malloc) nothing is changed.
"""

from __future__ import annotations

import ctypes
import os

# (environment variable, mallopt parameter, value): glibc's names and numbers (malloc.h)
TUNING = (
    ("MALLOC_MMAP_THRESHOLD_", -3, 256 << 20),  # M_MMAP_THRESHOLD: blocks below it come from the heap
    ("MALLOC_TRIM_THRESHOLD_", -1, 256 << 20),  # M_TRIM_THRESHOLD: free memory the heap's top keeps
    ("MALLOC_TOP_PAD_", -2, 64 << 20),  # M_TOP_PAD: extra memory taken per heap growth
)
ENVIRONMENT = {name: str(value) for name, _, value in TUNING}  # for a process started with the tuning

_tuned = False


def is_glibc() -> bool:
    """Whether this process runs on GNU libc (whose malloc :data:`TUNING` is written for)."""
    try:
        return (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc")
    except (AttributeError, ValueError, OSError):  # no confstr (Windows), or no such name (musl, macOS)
        return False


def tune() -> bool:
    """Apply :data:`TUNING` to this process's malloc (once; later calls and non-glibc systems do
    nothing); whether it holds now."""
    global _tuned
    if not _tuned and is_glibc():
        mallopt = ctypes.CDLL(None).mallopt
        mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
        _tuned = all([mallopt(parameter, value) == 1 for _, parameter, value in TUNING])
    return _tuned
