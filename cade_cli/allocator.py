"""Keep freed memory in the process, so large temporary arrays do not page-fault anew.

glibc's ``malloc`` serves a block above its mmap threshold (128 KiB at start, raised
as blocks are freed, up to 32 MiB) straight from the kernel and unmaps it on ``free``;
below it, freed memory beyond the trim threshold at the top of the heap goes back to
the kernel too. The matchers make many image-sized temporaries (a 0.36-megapixel
float64 plane is 2.8 MiB), so without tuning most of them are fresh pages whose first
touch is a page fault: on a virtual machine a simple NumPy expression such as
``np.minimum(np.maximum(a, 0), 1)`` on such a plane then takes several times its
arithmetic. Serving blocks up to 32 MiB
from the heap and keeping up to 256 MiB of freed memory makes the next temporary reuse
pages that are already mapped.

The ``cade`` command calls :func:`retain_freed_memory` at start (as do the benchmark
scripts, so that their figures are the command's); a program using the library may
call it too. It is a no-op where the C library is not glibc.
"""

from __future__ import annotations

import ctypes
import functools
import platform

MMAP_THRESHOLD = 32 * 1024 * 1024
"""Blocks up to this size come from the heap (glibc's own ceiling for its dynamic threshold)."""
TRIM_THRESHOLD = 256 * 1024 * 1024
"""Freed memory kept at the top of the heap before any is returned to the kernel."""
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt parameter numbers, <malloc.h>


@functools.cache
def retain_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds (once per process); True if they were set."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    mmap_set = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
    trim_set = mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    return bool(mmap_set and trim_set)
