"""Exposure times from a text file: one ``name seconds`` pair per line.

``seconds`` may be a decimal (``0.125``) or a fraction (``1/3049``); ``#`` starts a comment. This is
the format of ``../shared/data/*/exposure_times.txt`` and of the simulator's output. A time must
lie between :data:`MIN_EXPOSURE_TIME` and :data:`MAX_EXPOSURE_TIME`: a value outside (``1e400``,
``1e-400``) is a typing mistake, and it would overflow or vanish once turned into a float.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from fractions import Fraction
from pathlib import Path

from ..errors import InputError
from ._paths import input_file

__all__ = [
    "MIN_EXPOSURE_TIME",
    "MAX_EXPOSURE_TIME",
    "EXPOSURE_TIME_RANGE",
    "read_exposure_times",
    "parse_seconds",
    "check_seconds",
]

#: Shortest exposure time accepted, in seconds: 1/10 000 000 s, far below the 1/32 000 s of the
#: fastest mechanical and electronic shutters.
MIN_EXPOSURE_TIME = Fraction(1, 10_000_000)
#: Longest exposure time accepted, in seconds: 100 000 s (27.8 hours).
MAX_EXPOSURE_TIME = Fraction(100_000)
#: The accepted range in words, for error messages.
EXPOSURE_TIME_RANGE = "seconds from 1e-7 to 1e5 (27.8 hours), such as 0.125 or 1/8"


def check_seconds(t: Fraction) -> Fraction:
    """``t`` when it is a usable exposure time, else :class:`ValueError` saying why."""
    if t <= 0:
        raise ValueError("zero or negative")
    if t < MIN_EXPOSURE_TIME:
        raise ValueError("shorter than 1e-7 s")
    if t > MAX_EXPOSURE_TIME:
        raise ValueError("longer than 1e5 s")
    return t


def parse_seconds(text: str) -> Fraction:
    """``"1/3049"`` -> ``Fraction(1, 3049)``; ``"0.125"`` -> ``Fraction(1, 8)``.

    Raises :class:`ValueError` (saying why) unless the value is a number of seconds between
    :data:`MIN_EXPOSURE_TIME` and :data:`MAX_EXPOSURE_TIME` (``inf``, ``nan``, zero and
    negative values included).
    """
    try:
        t = Fraction(text.strip())
    except (ValueError, ZeroDivisionError):
        raise ValueError("not a number") from None
    return check_seconds(t)


def times_from_mapping(times: Mapping[str, Fraction | float | str]) -> dict[str, Fraction]:
    """A ``name -> seconds`` mapping given in code, checked like a times file's lines."""
    out: dict[str, Fraction] = {}
    for name, value in times.items():
        try:
            t = value if isinstance(value, Fraction) else parse_seconds(str(value))
            out[Path(name).name] = check_seconds(t)
        except ValueError as exc:
            raise InputError(
                f"bad exposure time for {Path(name).name}, {exc}",
                expected=EXPOSURE_TIME_RANGE,
                found=repr(value),
            ) from None
    return out


def read_exposure_times(path: str | os.PathLike) -> dict[str, Fraction]:
    """Map of file name (no directory) to exposure time in seconds."""
    p = input_file(path, "exposure-times file")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read exposure-times file ({exc.strerror})", path=p) from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        bad_line = data[: exc.start].count(b"\n") + 1
        raise InputError(
            f"line {bad_line} is not UTF-8 text",
            path=p,
            expected="a plain text file",
            found=f"byte 0x{data[exc.start]:02x}",
        ) from None
    times: dict[str, Fraction] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        content = line.split("#", 1)[0].strip()
        if not content:
            continue
        parts = content.split()
        if len(parts) != 2:
            raise InputError(
                f"line {number} is not 'name seconds'", path=p, found=repr(line.strip())
            )
        name, value = parts
        try:
            times[Path(name).name] = parse_seconds(value)
        except ValueError as exc:
            raise InputError(
                f"line {number}: bad exposure time, {exc}",
                path=p,
                expected=EXPOSURE_TIME_RANGE,
                found=repr(value),
            ) from None
    if not times:
        raise InputError("exposure-times file lists no frames", path=p)
    return times
