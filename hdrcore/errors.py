"""The project's exception types.

Every error raised at a boundary (a file, a parameter, a bracket) names what it is about, what was
expected and what was found, so a user can act on it without reading a traceback. The command line
prints ``str(error)`` on one line and exits non-zero.
"""

from __future__ import annotations

import os

__all__ = [
    "HdrError",
    "InputError",
    "ImageReadError",
    "FrameTooLargeError",
    "BracketError",
    "OutputError",
    "ParameterError",
    "EstimationError",
    "validate_method",
]


class HdrError(Exception):
    """Base class of every error this project raises on purpose."""

    def __init__(
        self,
        message: str,
        *,
        path: str | os.PathLike[str] | None = None,
        expected: str | None = None,
        found: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.expected = expected
        self.found = found
        self.reason = message
        parts = []
        if self.path is not None:
            parts.append(f"{self.path}: ")
        parts.append(message)
        if expected is not None or found is not None:
            detail = []
            if expected is not None:
                detail.append(f"expected {expected}")
            if found is not None:
                detail.append(f"found {found}")
            parts.append(f" ({', '.join(detail)})")
        super().__init__("".join(parts))


class InputError(HdrError):
    """A file given as input does not exist or cannot be used."""


class ImageReadError(InputError):
    """A file exists but is not a readable image (not an image, truncated, unsupported)."""


class FrameTooLargeError(InputError):
    """A frame declares more pixels than the limit; read from its header, before any decoding.

    ``hint`` (e.g. the command-line option that raises the limit) ends the message.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        width: int,
        height: int,
        limit: int,
        hint: str | None = None,
    ) -> None:
        self.width = int(width)
        self.height = int(height)
        self.limit = int(limit)
        self.hint = hint
        message = (
            f"frame is {self.width * self.height / 1e6:.1f} MP ({self.width}x{self.height}), "
            f"more than the limit of {self.limit / 1e6:g} MP"
        )
        if hint:
            message += f"; {hint}"
        super().__init__(message, path=path)


class BracketError(HdrError):
    """The frames cannot form a bracket (one frame, different sizes, ...)."""


class OutputError(HdrError):
    """An output cannot be written (exists without --force, would overwrite an input, ...)."""


class ParameterError(HdrError, ValueError):
    """A parameter is out of range or names an unknown method."""


class EstimationError(HdrError):
    """A numerical stage cannot produce an estimate from its input (all-saturated frame, ...)."""


def validate_method(method: str, methods: dict, what: str) -> str:
    """Return the canonical key of ``method`` in ``methods`` (case-insensitive) or raise.

    The error lists the valid names, in the manner of colour-science's ``validate_method``.
    """
    lowered = {key.lower(): key for key in methods}
    key = lowered.get(str(method).lower())
    if key is None:
        valid = ", ".join(repr(k) for k in methods)
        raise ParameterError(
            f"unknown {what} method {method!r}", expected=f"one of {valid}", found=repr(method)
        )
    return key
