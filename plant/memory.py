"""Keep the plant's freed memory for its next tick instead of handing it back to the kernel.

Every tick the sensors allocate and free the same large temporaries (a camera frame's
depth, shape-id and shading buffers, the noise, the encoded message: 50-250 KB each).
With glibc's defaults, blocks above the mmap threshold are mapped and unmapped each time
and the top of the heap is trimmed whenever 128 KB lie free there, so each tick touches
fresh pages again: in a ``follow`` run the camera's render took ~33 page faults a frame
(2.5 in a loop on its own), ~0.15 ms of CPU. Raising the thresholds keeps those pages
(a few MB at most); a non-glibc system is left as it is.
"""
from __future__ import annotations

import ctypes

#: mallopt parameters (malloc.h)
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
MMAP_THRESHOLD_B = 32 << 20
TRIM_THRESHOLD_B = 64 << 20
TOP_PAD_B = 16 << 20


def keep_freed_memory() -> bool:
    """Tune glibc's malloc for a process that reallocates the same large buffers every
    tick; True if it took. Values do not change, only where the bytes live."""
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return all(mallopt(param, value) == 1 for param, value in (
        (M_MMAP_THRESHOLD, MMAP_THRESHOLD_B), (M_TRIM_THRESHOLD, TRIM_THRESHOLD_B),
        (M_TOP_PAD, TOP_PAD_B)))
