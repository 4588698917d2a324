"""Decoded brackets shared by every page of one inspector.

Each page (browser client) has its own bracket choice, parameters and pipeline; decoding is the
slow part they can share. :class:`BracketCache` keeps the last few decoded brackets, keyed by the
resolved files, the exposure-times list and each file's size and modification time (a file
changed on disk is decoded again). Two pages asking for the same bracket at once decode it once:
the second waits for the first. A :class:`~hdrcore.io.Bracket` is immutable, so sharing it is safe.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path

from hdrcore.io import Bracket, load_bracket

__all__ = ["BracketCache"]

Key = tuple


def _stamp(p: str | os.PathLike) -> tuple[str, int, int]:
    st = Path(p).stat()
    return (str(p), st.st_size, st.st_mtime_ns)


class BracketCache:
    """At most ``size`` decoded brackets, least recently used dropped first."""

    def __init__(self, size: int = 2, loader: Callable[..., Bracket] = load_bracket) -> None:
        self.size = size
        self._loader = loader
        self._lock = threading.Lock()
        self._items: OrderedDict[Key, Bracket] = OrderedDict()
        self._loading: dict[Key, threading.Event] = {}
        self.loads = 0  # decodes done (for tests and the bench)

    def key(self, files: Sequence[str | os.PathLike], times: str | os.PathLike | None) -> Key:
        stamps = tuple(_stamp(f) for f in files)
        return (stamps, None if times is None else _stamp(times))

    def get(
        self, files: Sequence[str | os.PathLike], times: str | os.PathLike | None = None
    ) -> Bracket:
        """The decoded bracket of these files (decoded now, or shared with another page)."""
        try:
            key = self.key(files, times)
        except OSError:  # a file vanished: let the loader say which, in its words
            return self._loader(list(files), exposure_times=times)
        while True:
            with self._lock:
                if key in self._items:
                    self._items.move_to_end(key)
                    return self._items[key]
                event = self._loading.get(key)
                if event is None:
                    event = self._loading[key] = threading.Event()
                    break
            event.wait()  # another page is decoding it; then look again
        try:
            bracket = self._loader(list(files), exposure_times=times)
            with self._lock:
                self.loads += 1
                self._items[key] = bracket
                while len(self._items) > self.size:
                    self._items.popitem(last=False)
            return bracket
        finally:
            with self._lock:
                self._loading.pop(key, None)
            event.set()

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
