"""A computation made once, whoever asks first: the measurements a run leaves for later (the
merge's region ghost test, a non-linear merge's colour checks) are made by the first caller;
the others wait for it and get the same value."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")

__all__ = ["Once"]


class Once(Generic[T]):
    """``fn()`` computed once, whoever calls first (the others wait for it); ``done`` says
    whether it has been. ``fn`` and what it holds are released once it has run."""

    def __init__(self, fn: Callable[[], T]) -> None:
        self._fn: Callable[[], T] | None = fn
        self._lock = threading.Lock()
        self._value: list[T] = []

    @property
    def done(self) -> bool:
        return bool(self._value)

    def __call__(self) -> T:
        with self._lock:
            if not self._value:
                assert self._fn is not None
                self._value.append(self._fn())
                self._fn = None
            return self._value[0]
