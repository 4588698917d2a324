"""Exposure times from a text file: one ``name seconds`` pair per line.

``seconds`` may be a decimal (``0.125``) or a fraction (``1/3049``); ``#`` starts a comment. This is
the format of ``../shared/data/*/exposure_times.txt`` and of the simulator's output.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

from ..errors import InputError

__all__ = ["read_exposure_times", "parse_seconds"]


def parse_seconds(text: str) -> Fraction:
    """``"1/3049"`` -> ``Fraction(1, 3049)``; ``"0.125"`` -> ``Fraction(1, 8)``; must be > 0."""
    t = Fraction(text.strip())
    if t <= 0:
        raise ValueError("exposure time must be positive")
    return t


def read_exposure_times(path: str | Path) -> dict[str, Fraction]:
    """Map of file name (no directory) to exposure time in seconds."""
    p = Path(path)
    if not p.is_file():
        raise InputError("exposure-times file not found", path=p)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read exposure-times file ({exc})", path=p) from exc
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
        except (ValueError, ZeroDivisionError) as exc:
            raise InputError(
                f"line {number}: bad exposure time", path=p,
                expected="seconds > 0 such as 0.125 or 1/8", found=repr(value),
            ) from exc
    if not times:
        raise InputError("exposure-times file lists no frames", path=p)
    return times
