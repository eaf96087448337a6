"""The C allocator told to keep the large blocks the model's numerics free and make again.

Every iteration of a fit makes and frees temporaries of megabytes: a six-zone heat-up's
Jacobian is 18 000 rows by 36 columns, 5 MB, and the simulator's and the sensitivities'
tables are as large. glibc maps a block above its mmap threshold afresh from the kernel,
and hands the free memory at its heap's top back once more of it lies there than its trim
threshold. Its sliding threshold follows the largest block freed but trims at twice that,
so most of one iteration's temporaries go back to the kernel and the next iteration's are
faulted in again page by page, each page zeroed first: more work than the arithmetic done
on them (docs/performance.md, "The closed form in real arithmetic, and the allocator").
Blocks up to `MMAP_THRESHOLD` are served from the heap here and up to `TRIM_THRESHOLD` of
free memory is kept, so those blocks are reused. A process keeps at most what it used at
its peak. The settings hold for the process and the workers it forks; where the C library
is not glibc, nothing changes.
"""

from __future__ import annotations

import contextlib
import ctypes
import sys

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""mallopt's parameter numbers (glibc's malloc.h)."""
MMAP_THRESHOLD = 32 << 20
"""The largest glibc accepts on a 64-bit system."""
TRIM_THRESHOLD = 256 << 20
"""Free memory kept at the heap's top: above what one iteration frees at once (a six-zone
fit's temporaries are tens of MB), below a diagnosis worker's whole peak (some 400 MB)."""

_set = False


def keep_freed_blocks() -> None:
    """Set the allocator's thresholds, once per process."""
    global _set
    if _set:
        return
    _set = True
    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        mallopt = ctypes.CDLL(None).mallopt
        mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)
