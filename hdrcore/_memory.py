"""Allocator settings for the command-line programs (glibc only).

A 24-megapixel bracket goes through buffers of hundreds of megabytes: the decoder's, then the
merge's outputs (28 bytes a pixel). glibc serves each such block with a fresh ``mmap`` and
returns it to the system when freed, so every new buffer is memory the process has never
touched, and touching new memory is slow on virtual machines. :func:`retain_freed_memory` makes
glibc serve large blocks from its heap and keep what is freed, so the merge reuses the pages the
decoder has just released. The cost: memory freed by the process is not given back to the
system until it exits (it is reused by the process itself).

All threads allocate from the one main arena: a bracket's files are decoded on two threads, and
what a thread's own arena holds cannot serve the main thread's merge outputs.

``bench/bench_pipeline.py`` measures both settings (the "glibc defaults" rows, first run in a
new process); the README gives the figures. Only the ``hdrcore`` and ``hdrview`` programs call
it (not ``import hdrcore``): a library must not change its host's allocator.
``HDRCORE_RETAIN_MEMORY=0`` switches it off.
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
