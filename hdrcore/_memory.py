"""Allocator settings for the command-line programs (glibc only).

A 24-megapixel bracket goes through buffers of hundreds of megabytes: the decoder's, then the
merge's outputs (28 bytes a pixel). glibc serves each such block with a fresh ``mmap`` and
returns it to the system when freed, so every new buffer is memory the process has never
touched, and touching new memory is slow on virtual machines (measured here: about 2 s of
system time per GB). :func:`retain_freed_memory` makes glibc serve large blocks from its heap
and keep what is freed, so the merge reuses the pages the decoder has just released. Measured
with ``bench/bench_pipeline.py`` (first run in a new process, 3 x 24 MP, decode excluded):
merge stage 1.31-1.35 s -> 0.65-0.96 s, whole pipeline 2.75-2.82 s -> 1.81-2.01 s, peak
memory unchanged (1.56 GB -> 1.57 GB). The cost: memory freed by the process is not given
back to the system until it exits (it is reused by the process itself).

All threads allocate from the one main arena: a bracket's files are decoded on two threads, and
what a thread's own arena holds cannot serve the main thread's merge outputs. Measured (3 x 24
MP DNG, first run in a new process): per-thread arenas, decode 3.6-3.7 s, pipeline 2.2-2.6 s,
peak 1.65 GB; one arena, decode 2.7-2.9 s, pipeline 2.0-2.1 s, peak 1.55-1.58 GB (decoding
one file at a time: 3.1 s, 2.0 s, 1.57 GB).

Only the ``hdrcore`` and ``hdrview`` programs call it (not ``import hdrcore``): a library must
not change its host's allocator. ``HDRCORE_RETAIN_MEMORY=0`` switches it off.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

__all__ = ["retain_freed_memory"]

_M_TRIM_THRESHOLD = -1  # glibc mallopt parameters (malloc.h)
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8


def retain_freed_memory() -> bool:
    """Serve large allocations from the heap and keep freed memory (glibc); ``True`` if set."""
    if not sys.platform.startswith("linux") or os.environ.get("HDRCORE_RETAIN_MEMORY") == "0":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # No mmap for large blocks, never trim the heap top (2 GB is mallopt's int limit), one arena
    # for every thread.
    return (
        bool(mallopt(_M_MMAP_MAX, 0))
        and bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
        and bool(mallopt(_M_ARENA_MAX, 1))
    )
