"""What a registration reads again when it runs again on the same frames.

An interactive caller (the inspector) registers the same frames again whenever the threshold
``t``, the noise floor or the saturation level moves. Much of what a pair's search and its
residual check compute does not depend on those: the residual check's block means of each frame
(saturation only), its structure image of the fixed frame (saturation and noise floor), the
search's pyramids (saturation and noise floor, not ``t``). :class:`RunMemo` keeps them from one
run to the next, keyed by the content they are made from: a frame by where its pixels lie (data
address, shape, strides, type; the memo keeps the frame alive, so the address cannot be taken by
another array), a table by a digest of its values, numbers by value. A run keeps only what it
used: :meth:`RunMemo.new_run` before it, :meth:`RunMemo.end_run` after.
"""

from __future__ import annotations

import hashlib
import threading
from typing import Any

import numpy as np

__all__ = ["RunMemo", "array_key", "table_key"]


def array_key(a: np.ndarray) -> tuple:
    """Where ``a``'s pixels lie: two views of the same pixels have one key (the frames are never
    changed in place)."""
    return (
        int(a.__array_interface__["data"][0]),
        tuple(a.shape),
        tuple(a.strides),
        a.dtype.str,
    )


def table_key(table: np.ndarray | None) -> Any:
    """A digest of a (small) table's values, ``None`` for none."""
    if table is None:
        return None
    t = np.ascontiguousarray(table)
    return (t.dtype.str, t.shape, hashlib.blake2b(t.view(np.uint8).data, digest_size=16).digest())


class RunMemo:
    """A mapping (``get``, ``memo[key] = value``) that keeps what the last run used for the next
    one; thread-safe (a bracket's pairs register side by side). Values should hold the arrays
    their key names (``array_key`` is an address)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._kept: dict[Any, Any] = {}
        self._used: dict[Any, Any] = {}

    def get(self, key: Any, default: Any = None) -> Any:
        with self._lock:
            value = self._used.get(key)
            if value is None:
                value = self._kept.get(key)
                if value is not None:
                    self._used[key] = value
            return default if value is None else value

    def __setitem__(self, key: Any, value: Any) -> None:
        with self._lock:
            self._used[key] = value

    def __len__(self) -> int:
        with self._lock:
            return len(self._kept.keys() | self._used.keys())

    def new_run(self) -> None:
        """Before a run: what the last run used may be read again."""
        with self._lock:
            self._kept = {**self._kept, **self._used}
            self._used = {}

    def end_run(self) -> None:
        """After a run: only what it used is kept."""
        with self._lock:
            self._kept = {}
