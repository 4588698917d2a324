"""Grouping a folder's shots into brackets.

Methods (:data:`GROUPING_METHODS`, chosen by name through :func:`group_shots`):

``"signals"`` (default)
    Shots are split into *streams* that can never share a bracket (another folder, camera or
    image size), each stream is put in capture order (time with subseconds, then name), and
    the cut points are chosen by dynamic programming over the whole stream so that the number
    of groups is smallest, subject to what a camera's bracket looks like:

    * its exposures (``log2(t x ISO/100 / N^2)``, or the exposure bias when the exposure is
      not recorded) are all different (at least :data:`MIN_STEP_STOPS` apart: a burst of equal
      exposures is not a bracket);
    * they come in a bracketing order: steadily darker, steadily brighter, or centre-out
      (``0, -, +, --, ++``: Nikon's and Canon's default, in either sign);
    * at most ``max_frames`` frames.

    Among the groupings with that smallest cost, time gaps and thumbnails decide: leaving a
    pause inside a group costs ``log2`` of how much longer it is than twice the stream's
    median pause (most pauses are inside brackets; the clock's resolution, 1 s without
    subseconds, is taken off first), so a long pause is where a bracket ends; two
    thumbnails that do not look alike (rank correlation below 0.5) add a little; a two-frame
    group costs half a group more (a lone shot next to a bracket would otherwise pair with
    one of its frames); a group whose steps differ, with an even number of frames, or not
    centred on the metered exposure (the median of the neighbouring shots') costs a little
    more. Shots that carry no exposure at all are grouped by time gap
    (HDRMerge's rule) when they carry times, else the stream is one group.

``"gap"``
    HDRMerge's rule (``Launcher::getBracketedSets``, HDRMerge 0.5): all shots sorted by
    capture time, a new set where the pause from the end of one exposure to the start of the
    next is more than ``gap`` seconds (HDRMerge's default 2 s); shots without a time alone.

``"count"``
    Photomatix's rule: every ``size`` shots in name order (per folder) are one set.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError, validate_method
from .scan import Shot, thumbnail_similarity

__all__ = ["Group", "GROUPING_METHODS", "group_shots", "bracket_order", "HDRMERGE_GAP"]

#: HDRMerge's default batch gap (``LoadOptions::batchGap``), seconds.
HDRMERGE_GAP = 2.0
#: Two exposures closer than this (stops) are the same exposure for the grouping: bracketing
#: steps are 1/3 stop or more; nominal EXIF values round by up to 1/24 stop.
MIN_STEP_STOPS = 1.0 / 6.0
#: Largest bracket the grouping forms by default (HDRI capture uses up to 14 frames per angle).
MAX_FRAMES = 15
#: Extra cost of a two-frame group, in groups.
PAIR_COST = 0.5
#: Cost of unequal steps inside a group (per stop of difference, at most one stop), and of a
#: group of an even number of frames (four or more): tie-breakers only.
STEP_COST = 0.3
EVEN_COST = 0.25
#: Cost of a group whose middle exposure is off the metered one (median of the exposures of
#: the METERED_WINDOW shots either side), per stop, at most one stop: a tie-breaker.
CENTRE_COST = 0.2
METERED_WINDOW = 10
#: Below the gap threshold a pause still costs up to this much (proportionally), so that of
#: two otherwise equal groupings the one that cuts at the longer pause wins.
PAUSE_TIE_COST = 0.1
#: Cost of keeping two shots together whose thumbnails do not look alike (at correlation -1;
#: nothing at 0.5 and above).
THUMB_COST = 0.3


@dataclass(frozen=True, eq=False)
class Group:
    """Shots taken as one bracket (two or more) or a single shot, and why."""

    shots: tuple[Shot, ...]
    reason: str

    @property
    def is_bracket(self) -> bool:
        return len(self.shots) >= 2

    @property
    def paths(self) -> list[str]:
        return [s.path for s in self.shots]


def _order_is_bracketing(ev: Sequence[float]) -> str | None:
    """``"darker"``, ``"brighter"`` or ``"centre-out"`` when ``ev`` (capture order) is a
    bracketing order with distinct steps, else ``None``."""
    n = len(ev)
    srt = sorted(ev)
    if any(b - a < MIN_STEP_STOPS for a, b in zip(srt, srt[1:], strict=False)):
        return None
    diffs = [b - a for a, b in zip(ev, ev[1:], strict=False)]
    if all(d > 0 for d in diffs):
        return "brighter"
    if all(d < 0 for d in diffs):
        return "darker"
    if n >= 3:
        rank = [srt.index(v) for v in ev]
        for mid in {(n - 1) // 2, n // 2}:
            if rank[0] != mid:
                continue
            for first in (-1, 1):
                lo, hi, sign, ok = mid, mid, first, True
                for r in rank[1:]:
                    want = lo - 1 if sign < 0 else hi + 1
                    if r != want:
                        ok = False
                        break
                    lo, hi = min(lo, r), max(hi, r)
                    sign = -sign
                if ok:
                    return "centre-out"
    return None


def _shape_cost(ev: Sequence[float], order: str) -> float:
    """Tie-breakers between groupings of equal count: a camera brackets in equal steps and
    around the metered exposure, so with an odd number of frames (3, 5, 7, 9: the AEB counts
    of most cameras). :data:`STEP_COST` per stop by which the steps differ (at most 1),
    :data:`EVEN_COST` for an even group of four or more."""
    srt = sorted(ev)
    steps = [b - a for a, b in zip(srt, srt[1:], strict=False)]
    cost = STEP_COST * min(1.0, max(steps) - min(steps)) if len(steps) > 1 else 0.0
    if len(ev) >= 4 and len(ev) % 2 == 0:
        cost += EVEN_COST
    return cost


def bracket_order(ev: Sequence[float]) -> str | None:
    """Public form of the order test: the order's name or ``None`` (see the module doc)."""
    return _order_is_bracketing(list(ev))


def _gaps(shots: Sequence[Shot]) -> list[float | None]:
    """Pause from the end of each exposure to the start of the next (seconds, >= 0)."""
    out: list[float | None] = []
    for a, b in zip(shots, shots[1:], strict=False):
        if a.time is None or b.time is None:
            out.append(None)
        else:
            out.append(max(0.0, b.time - (a.time + (a.exposure_time or 0.0))))
    return out


def _shot_ev(s: Shot) -> float | None:
    ev = s.exposure_ev
    return ev if ev is not None else s.exposure_bias


def _boundary_costs(shots: Sequence[Shot], thumbnails: bool) -> list[float]:
    """Cost of keeping shot k and k+1 in one group (time gap, then thumbnail likeness)."""
    fine = all(s.subsec for s in shots)
    resolution = 0.05 if fine else 1.0  # whole-second clocks: a gap is known to a second
    # the shortest pause the clock allows: a 1 s tick on a whole-second clock may be 0 s
    gaps = [None if g is None else max(0.0, g - resolution) for g in _gaps(shots)]
    known = [g for g in gaps if g is not None]
    # most pauses of a stream are inside brackets (3 to 9 frames each): a pause costs nothing
    # up to twice the median, then log2 of how much longer it is
    typical = 2.0 * (float(np.median(known)) + resolution) if known else 1.0
    costs = []
    for k, g in enumerate(gaps):
        c = 0.0
        if g is not None:
            c += max(0.0, math.log2((g + resolution) / typical))
            c += PAUSE_TIE_COST * min(1.0, (g + resolution) / typical)
        if thumbnails:
            sim = thumbnail_similarity(shots[k].thumbnail, shots[k + 1].thumbnail)
            if sim is not None and sim < 0.5:
                c += THUMB_COST * (0.5 - sim) / 1.5
        costs.append(c)
    return costs


def _segment_stream(shots: Sequence[Shot], max_frames: int, thumbnails: bool) -> list[Group]:
    n = len(shots)
    evs = [_shot_ev(s) for s in shots]
    costs = _boundary_costs(shots, thumbnails)
    inner = np.concatenate([[0.0], np.cumsum(costs)]) if costs else np.zeros(1)
    # the metered exposure near each shot: the median of its neighbours' (a bracket is
    # centred on it, single shots are taken at it)
    known_ev = np.array([np.nan if v is None else v for v in evs], dtype=float)
    metered_at = [
        float(np.nanmedian(known_ev[max(0, k - METERED_WINDOW) : k + METERED_WINDOW + 1]))
        if np.isfinite(known_ev[max(0, k - METERED_WINDOW) : k + METERED_WINDOW + 1]).any()
        else 0.0
        for k in range(n)
    ]
    best = [0.0] + [math.inf] * n
    back = [0] * (n + 1)
    orders: dict[tuple[int, int], str] = {}
    for j in range(1, n + 1):
        for i in range(max(0, j - max_frames), j):
            size = j - i
            if size == 1:
                cost = 1.0
            else:
                if any(v is None for v in evs[i:j]):
                    continue
                ev = [v for v in evs[i:j] if v is not None]
                order = _order_is_bracketing(ev)
                if order is None:
                    continue
                orders[(i, j)] = order
                centre = 0.5 * (max(ev) + min(ev))
                metered = metered_at[(i + j - 1) // 2]
                cost = (
                    1.0
                    + (PAIR_COST if size == 2 else 0.0)
                    + _shape_cost(ev, order)
                    + CENTRE_COST * min(1.0, abs(centre - metered))
                    + float(inner[j - 1] - inner[i])
                )
            if best[i] + cost < best[j] - 1e-12:
                best[j], back[j] = best[i] + cost, i
    groups: list[Group] = []
    j = n
    while j > 0:
        i = back[j]
        if j - i == 1:
            groups.append(Group((shots[i],), "single shot"))
        else:
            evs_g = [e for k in range(i, j) if (e := evs[k]) is not None]
            span = max(evs_g) - min(evs_g)
            groups.append(
                Group(
                    tuple(shots[i:j]), f"{j - i} exposures {orders[(i, j)]} over {span:.1f} stops"
                )
            )
        j = i
    return groups[::-1]


def _by_time_gap(shots: Sequence[Shot], gap: float, why: str) -> list[Group]:
    timed = sorted((s for s in shots if s.time is not None), key=lambda s: (s.time, s.path))
    groups: list[list[Shot]] = []
    for s, g in zip(timed, [None, *_gaps(timed)], strict=False):
        if g is None or g > gap:
            groups.append([s])
        else:
            groups[-1].append(s)
    out = [Group(tuple(g), why if len(g) > 1 else "single shot") for g in groups]
    out += [Group((s,), "single shot (no capture time)") for s in shots if s.time is None]
    return out


def _streams(shots: Sequence[Shot]) -> list[list[Shot]]:
    by: dict[tuple, list[Shot]] = {}
    for s in shots:
        by.setdefault(s.stream, []).append(s)
    return [
        sorted(v, key=lambda s: (s.time is None, s.time or 0.0, s.path))
        for _, v in sorted(by.items(), key=lambda kv: str(kv[0]))
    ]


def group_by_signals(
    shots: Sequence[Shot], *, max_frames: int = MAX_FRAMES, thumbnails: bool = True, **_: object
) -> list[Group]:
    out: list[Group] = []
    for stream in _streams(shots):
        with_ev = [s for s in stream if _shot_ev(s) is not None]
        if len(with_ev) == len(stream):
            out += _segment_stream(stream, max_frames, thumbnails)
        elif not with_ev and all(s.time is not None for s in stream) and len(stream) > 1:
            out += _by_time_gap(
                stream, HDRMERGE_GAP, f"no exposures recorded: time gaps <= {HDRMERGE_GAP:g} s"
            )
        elif not with_ev:
            out.append(
                Group(
                    tuple(stream),
                    "no exposures or times recorded: the whole folder (same camera and size)",
                )
                if len(stream) > 1
                else Group(tuple(stream), "single shot")
            )
        else:
            out += _segment_stream(with_ev, max_frames, thumbnails)
            out += [
                Group((s,), "single shot (no exposure recorded)")
                for s in stream
                if _shot_ev(s) is None
            ]
    return out


def group_by_gap(shots: Sequence[Shot], *, gap: float | None = None, **_: object) -> list[Group]:
    g = HDRMERGE_GAP if gap is None else float(gap)
    if not (g >= 0 and math.isfinite(g)):
        raise ParameterError(
            "the time gap must be a non-negative number of seconds", found=repr(gap)
        )
    return _by_time_gap(shots, g, f"time gaps <= {g:g} s")


def group_by_count(shots: Sequence[Shot], *, size: int | None = None, **_: object) -> list[Group]:
    if size is None or int(size) < 1:
        raise ParameterError("a group size of at least 1 is needed", found=repr(size))
    n = int(size)
    out: list[Group] = []
    by_folder: dict[str, list[Shot]] = {}
    for s in shots:
        by_folder.setdefault(s.folder, []).append(s)
    for folder in sorted(by_folder):
        items = sorted(by_folder[folder], key=lambda s: s.path)
        for k in range(0, len(items), n):
            part = tuple(items[k : k + n])
            why = f"every {n} files" if len(part) == n else f"last {len(part)} of every {n}"
            out.append(Group(part, why if len(part) > 1 else "single shot"))
    return out


GROUPING_METHODS: dict[str, Callable[..., list[Group]]] = {
    "signals": group_by_signals,
    "gap": group_by_gap,
    "count": group_by_count,
}


def group_shots(shots: Sequence[Shot], method: str = "signals", **kwargs: Any) -> list[Group]:
    """Group ``shots`` with one of :data:`GROUPING_METHODS`, in capture order."""
    fn = GROUPING_METHODS[validate_method(method, GROUPING_METHODS, "grouping")]
    groups = fn(list(shots), **kwargs)
    return sorted(
        groups, key=lambda g: (g.shots[0].time is None, g.shots[0].time or 0.0, g.shots[0].path)
    )
