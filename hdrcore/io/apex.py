"""Nominal EXIF exposure times and f-numbers snapped to the camera's APEX sequence.

Cameras step shutter speeds and apertures in 1/3 or 1/2 stops of the APEX scale (Additive System
of Photographic Exposure, ASA PH2.5-1960; the EXIF ``ShutterSpeedValue`` ``Tv`` and
``ApertureValue`` ``Av`` are its values): the actual time is ``t = 2^-Tv`` and the actual
f-number ``N = 2^(Av / 2)``, with ``Tv`` and ``Av`` on a grid of 1/3 or 1/2. The
``ExposureTime`` and ``FNumber`` tags hold the rounded *nominal* value printed on the dial:
1/640 s is really ``2^(-28/3)`` s (1/645), 1/15 s is ``2^-4`` (1/16), 1/125 s is ``2^-7``
(1/128), f/5.6 is ``2^(5/2)`` (5.657) and f/11 is ``2^(7/2)`` (11.31). Taken as exact, the
nominal values put up to 7 % of error into an exposure ratio (1/6 -> 1/8 s: 1.333 nominal,
``2^(1/3)`` = 1.260 actual).

:func:`snap_exposure_time` maps a nominal time to the actual one and names the sequence it
belongs to (``"1/3-stop"`` or ``"1/2-stop"``); a time that is not a nominal value of either
table (phones such as the Pixel 7 write exact times like 1/802.8 s) is returned unchanged with
sequence ``None``. Some nominal values exist in both sequences with different actual values
(1/6 s is ``2^(-8/3)`` in 1/3 stops and ``2^(-5/2)`` in 1/2 stops; also 1/10, 1/20, 0.3, 6, 10,
20 s): :func:`bracket_sequence` picks the sequence the bracket's other frames support (values
nominal in one table only), and the snapping takes it as its preference.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from fractions import Fraction

__all__ = [
    "SEQUENCES",
    "THIRD_STOP",
    "HALF_STOP",
    "nominal_exposure_times",
    "nominal_f_numbers",
    "snap_exposure_time",
    "snap_f_number",
    "bracket_sequence",
]

THIRD_STOP = "1/3-stop"
HALF_STOP = "1/2-stop"
#: The sequences, in the order of preference when nothing else decides (1/3 stop is the default
#: exposure increment of most cameras).
SEQUENCES: tuple[str, ...] = (THIRD_STOP, HALF_STOP)
_STEPS = {THIRD_STOP: 3, HALF_STOP: 2}


def _fractions(text: str) -> tuple[Fraction, ...]:
    return tuple(Fraction(v) for v in text.split())


# Nominal shutter speeds (seconds) as cameras write them, with the common alternative spellings
# (Nikon's 1/1.3 s = 10/13, 1/1.6 s = 5/8, 1/3 s; Canon's 0.3"). Each is the rounded
# 2^(-k/3) or 2^(-k/2) of the nearest grid point (checked by the tests).
_TIMES = {
    THIRD_STOP: _fractions(
        "60 50 40 30 25 20 15 13 10 8 6 5 4 3.2 2.5 2 1.6 1.3 1 0.8 0.6 5/8 10/13 0.5 0.4 0.3 1/3 "
        "1/4 1/5 1/6 1/8 1/10 1/13 1/15 1/20 1/25 1/30 1/40 1/50 1/60 1/80 1/100 1/125 1/160 "
        "1/200 1/250 1/320 1/400 1/500 1/640 1/800 1/1000 1/1250 1/1600 1/2000 1/2500 1/3200 "
        "1/4000 1/5000 1/6400 1/8000 1/10000 1/12800 1/16000 1/20000 1/25600 1/32000"
    ),
    HALF_STOP: _fractions(
        "30 20 15 10 8 6 4 3 2 1.5 1 0.7 2/3 0.5 0.3 1/3 1/4 1/6 1/8 1/10 1/15 1/20 1/30 1/45 "
        "1/60 1/90 1/125 1/180 1/250 1/350 1/500 1/750 1/1000 1/1500 1/2000 1/3000 1/4000 "
        "1/6000 1/8000"
    ),
}

# Nominal f-numbers: N = 2^(Av/2) with Av on a 1/3- or 1/2-stop grid.
_F_NUMBERS = {
    THIRD_STOP: _fractions(
        "1 1.1 1.2 1.4 1.6 1.8 2 2.2 2.5 2.8 3.2 3.5 4 4.5 5 5.6 6.3 7.1 8 9 10 11 13 14 16 18 "
        "20 22 25 29 32 36 40 45 51 57 64"
    ),
    HALF_STOP: _fractions(
        "1 1.2 1.4 1.7 2 2.4 2.8 3.3 4 4.8 5.6 6.7 8 9.5 11 13 16 19 22 27 32 38 45 54 64"
    ),
}


def _check_sequence(sequence: str | None) -> None:
    if sequence is not None and sequence not in _STEPS:
        raise ValueError(f"unknown APEX sequence {sequence!r}; expected one of {SEQUENCES}")


def _grid_time(t: Fraction, sequence: str) -> float:
    """``2^(-Tv)`` with ``Tv`` the grid point of ``sequence`` nearest to ``-log2(t)``."""
    steps = _STEPS[sequence]
    k = round(-math.log2(t) * steps)
    return 2.0 ** (-k / steps)


def _grid_f_number(n: Fraction, sequence: str) -> float:
    """``2^(Av/2)`` with ``Av`` the grid point of ``sequence`` nearest to ``2 log2(N)``."""
    steps = _STEPS[sequence]
    k = round(2.0 * math.log2(n) * steps)
    return 2.0 ** (k / steps / 2.0)


def nominal_exposure_times(sequence: str) -> tuple[Fraction, ...]:
    """The nominal shutter speeds (seconds) of ``sequence`` as cameras write them."""
    _check_sequence(sequence)
    return _TIMES[sequence]


def nominal_f_numbers(sequence: str) -> tuple[Fraction, ...]:
    """The nominal f-numbers of ``sequence`` as cameras write them."""
    _check_sequence(sequence)
    return _F_NUMBERS[sequence]


def _snap(
    value: Fraction, tables: dict[str, tuple[Fraction, ...]], grid, prefer: str | None
) -> tuple[float, str | None]:
    _check_sequence(prefer)
    order = SEQUENCES if prefer is None else (prefer, *(s for s in SEQUENCES if s != prefer))
    for seq in order:
        if value in tables[seq]:
            return grid(value, seq), seq
    return float(value), None


def snap_exposure_time(t: Fraction, prefer: str | None = None) -> tuple[float, str | None]:
    """The camera's actual exposure time for the EXIF time ``t`` and its sequence.

    ``t`` nominal in the 1/3-stop table gives ``(2^(-k/3), "1/3-stop")``, in the 1/2-stop table
    ``(2^(-k/2), "1/2-stop")``; a value nominal in both takes ``prefer`` (default: 1/3 stop).
    Any other value (an exact time) comes back unchanged as ``(float(t), None)``.
    """
    if not isinstance(t, Fraction):
        t = Fraction(str(t))
    if t <= 0:
        raise ValueError(f"exposure time must be positive, got {t}")
    return _snap(t, _TIMES, _grid_time, prefer)


def snap_f_number(n: Fraction, prefer: str | None = None) -> tuple[float, str | None]:
    """The actual f-number ``2^(Av/2)`` for the nominal EXIF f-number ``n`` (as
    :func:`snap_exposure_time`: f/5.6 -> 5.657, f/11 -> 11.31; other values unchanged)."""
    if not isinstance(n, Fraction):
        n = Fraction(str(n))
    if n <= 0:
        raise ValueError(f"f-number must be positive, got {n}")
    return _snap(n, _F_NUMBERS, _grid_f_number, prefer)


def _evidence(value: Fraction, tables: dict[str, tuple[Fraction, ...]], grid) -> str | None:
    """The one sequence ``value`` is nominal in, when the sequences disagree about it."""
    inside = [s for s in SEQUENCES if value in tables[s]]
    if len(inside) == 1:
        return inside[0]
    if len(inside) == 2:
        a, b = (grid(value, s) for s in inside)
        if math.isclose(a, b, rel_tol=1e-12):
            return None  # a full stop: the same actual value in both, no evidence
    return None  # in both with different values (1/6, 1/10, ...) or in neither


def bracket_sequence(times: Iterable[Fraction | None]) -> str | None:
    """The APEX sequence a bracket's nominal exposure times support, or ``None`` if none is.

    Each time that is nominal in one sequence only is a vote for it (1/5, 1/13, 1/640 s for
    1/3 stops; 1/45, 1/90, 1/750 s for 1/2 stops); full stops and values nominal in both
    sequences give no evidence. With no vote (or a tie) the bracket gets the 1/3-stop sequence
    when any of its times is nominal at all. F-numbers do not vote: a phone's fixed f/1.7 is a
    property of its lens, not a setting on a dial.
    """
    votes = dict.fromkeys(SEQUENCES, 0)
    any_nominal = False
    for t in times:
        if t is None or t <= 0:
            continue
        if any(t in _TIMES[s] for s in SEQUENCES):
            any_nominal = True
        seq = _evidence(t, _TIMES, _grid_time)
        if seq is not None:
            votes[seq] += 1
    if not any_nominal:
        return None
    return HALF_STOP if votes[HALF_STOP] > votes[THIRD_STOP] else THIRD_STOP
