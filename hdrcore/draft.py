"""A draft of the pipeline's preview from the bracket binned to about screen size.

A slider change on a 24 MP bracket re-runs registration, the merge, the ghost test and the
colour check at full resolution: seconds of work before the page can show anything. The draft
runs the same pipeline, with the same parameters, on the frames binned ``f x f`` so that their
longer side is about ``max_side`` (1/36 of the pixels for 24 MP and 1024): the page shows its
preview first and the full result when it is ready.

Binning keeps the merge's rules:

* a block holding a sample at or above the saturation level in a channel is at ``max_level`` in
  that channel (clipped, as the merge treats a frame whose Keys support touches a clipped
  sample), so no mean of clipped and valid samples enters the merge as a valid level;
* a block holding a pixel of the excluded colour (``exclude_colour``) is that colour;
* other blocks are the mean of their samples, rounded to the frames' integer levels.

The draft's preview is tone-mapped with ``pixel_size = f`` (a local operator's scale is in
full-resolution pixels). It is a draft: how far it is from the full preview is measured on the
real brackets by ``bench/bench_hdrview.py --draft``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from typing import TYPE_CHECKING, Any

import numpy as np

from ._numba import AVAILABLE, njit
from ._threads import run_row_spans
from .errors import ParameterError, validate_method
from .io import Bracket
from .io.frame import Frame

if TYPE_CHECKING:  # the pipeline imports this module
    from .exposure import BracketExposureResult
    from .merge.colour_check import FrameMeasures
    from .pipeline import PipelineParams, PipelineResult, ProgressCallback
    from .registration import BracketRegistration

__all__ = [
    "DRAFT_MAX_SIDE",
    "BinnedLevels",
    "DraftCache",
    "bin_bracket",
    "bin_frame",
    "bin_levels",
    "draft_bracket",
    "draft_factor",
    "draft_registration",
    "run_draft",
]

DRAFT_MAX_SIDE = 1024
"""Longer side of the draft (about the width the page shows the preview at)."""


def draft_factor(shape: tuple[int, int], max_side: int = DRAFT_MAX_SIDE) -> int:
    """Binning factor that brings the longer side of ``shape`` to at most ``max_side``."""
    if max_side < 16:
        raise ParameterError("the draft's longer side must be >= 16 px", found=str(max_side))
    return max(1, int(np.ceil(max(shape) / float(max_side))))


#: Non-linear frames binned in exposure get levels ``FINE_TOP // max_level`` times finer (12
#: bits for 8-bit frames: a sixteenth of a level). 16 bits made the ratio stage's histograms
#: the draft's largest cost on the Pixel 7 bracket for no gain (profiled; see the README).
FINE_TOP = 4095

#: Sentinel of the block means: a block holding the excluded colour.
_EXCLUDED = -2.0


@njit
def _bin_rows(src, f, tab, ex, has_ex, out, top, r0, r1):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of the block means of ``tab[c][level]`` (float64), or the excluded
    colour's sentinel, and of each block's largest sample per channel (``top``)."""
    c = src.shape[2]
    ww = out.shape[1]
    inv = 1.0 / (f * f)
    acc = np.empty((ww, c), np.float64)
    hi = np.empty((ww, c), np.int64)
    hit = np.empty(ww, np.bool_)
    for y in range(r0, r1):
        acc[:] = 0.0
        hi[:] = 0
        hit[:] = False
        for j in range(f):
            row = src[y * f + j]
            for x in range(ww):
                for i in range(f):
                    px = row[x * f + i]
                    for ch in range(c):
                        v = np.int64(px[ch])
                        acc[x, ch] += tab[ch, v]
                        if v > hi[x, ch]:
                            hi[x, ch] = v
                if has_ex:
                    for i in range(f):
                        px = row[x * f + i]
                        same = True
                        for ch in range(c):
                            if px[ch] != ex[ch]:
                                same = False
                        if same:
                            hit[x] = True
        for x in range(ww):
            for ch in range(c):
                top[y, x, ch] = hi[x, ch]
                if hit[x]:
                    out[y, x, ch] = _EXCLUDED
                else:
                    out[y, x, ch] = acc[x, ch] * inv


def _block_means(src, f, tab, ex, has_ex):
    """The block means (:func:`_bin_rows`) and each block's largest sample, on the worker
    threads."""
    shape = (src.shape[0] // f, src.shape[1] // f, src.shape[2])
    out = np.empty(shape, np.float64)
    top = np.empty(shape, src.dtype)
    run_row_spans(
        out.shape[0],
        None,
        lambda r0, r1: _bin_rows(src, f, tab, ex, has_ex, out, top, r0, r1),
    )
    return out, top


@njit
def _levels_rows(tab, means, k, out, r0, r1):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of the block means as levels of ``k`` times finer steps, every channel
    (``tab[c]`` per channel): a binary search (numpy's ``searchsorted(side="right")``) per
    value, then the nearest fine step between the two entries
    (:func:`hdrcore.draft_spec.to_fine_levels` states it in numpy)."""
    n = tab.shape[1]
    for y in range(r0, r1):
        for x in range(means.shape[1]):
            for ch in range(means.shape[2]):
                v = means[y, x, ch]
                a, b = 0, n
                while a < b:
                    mid = (a + b) // 2
                    if tab[ch, mid] <= v:
                        a = mid + 1
                    else:
                        b = mid
                j = min(max(a - 1, 0), n - 2)
                lo, hi = tab[ch, j], tab[ch, j + 1]
                step = hi - lo if hi > lo else 1.0
                frac = min(max((v - lo) / step, 0.0), 1.0)
                out[y, x, ch] = j * k + np.rint(frac * k)


def _all_levels(tab: np.ndarray, means: np.ndarray, k: int) -> np.ndarray:
    """The levels of ``k`` times finer steps (:func:`_levels_rows`) of every channel into
    uint16, on the worker threads."""
    out = np.empty(means.shape, np.uint16)
    run_row_spans(
        means.shape[0],
        None,
        lambda r0, r1: _levels_rows(tab, means, k, out, r0, r1),
    )
    return out


def _check_engine(engine: str) -> None:
    """``"auto"`` and ``"numba"``: the kernels; ``"numpy"``: the same, with a
    ``DeprecationWarning``; anything else, or no numba, a :class:`ParameterError`."""
    if isinstance(engine, str) and engine.strip().lower() == "numpy":
        warnings.warn(
            "bin_levels(engine='numpy') is deprecated: the numpy binning was removed and the "
            "compiled kernels run instead (same results); drop the argument",
            DeprecationWarning,
            stacklevel=3,
        )
        engine = "auto"
    validate_method(engine, {"auto": "the kernels", "numba": "the kernels"}, "binning engine")
    if not AVAILABLE:
        raise ParameterError(
            "the draft's binning needs numba (a dependency of hdrcore)",
            expected="numba installed",
            found="numba not importable",
        )


@dataclass(frozen=True, eq=False)
class BinnedLevels:
    """One frame binned ``f x f`` before the saturation rule (:func:`bin_frame`): what a
    slider step can keep. ``levels``: the block means as levels (the excluded colour's blocks
    that colour); ``block_max``: each block's largest sample per channel, in the frame's
    levels; ``excluded``: the blocks holding the excluded colour (``None`` without one);
    ``top``: the level of a clipped block. :meth:`clipped` applies a saturation level."""

    levels: np.ndarray
    block_max: np.ndarray
    excluded: np.ndarray | None
    top: int

    def clipped(self, saturation: float) -> np.ndarray:
        """The binned levels under ``saturation`` (:func:`bin_levels`): a block whose largest
        sample in a channel is at or above it is ``top`` in that channel, unless it holds the
        excluded colour. A numpy pass over the binned grid (about 10 ms for 1000x666x3)."""
        out = self.levels.copy()
        clip = self.block_max >= saturation
        if self.excluded is not None:
            clip &= ~self.excluded[..., None]
        out[clip] = self.top
        return out


def bin_frame(
    levels: np.ndarray,
    factor: int,
    *,
    max_level: int,
    exclude_colour: tuple[int, int, int] | None = None,
    lut: np.ndarray | None = None,
    engine: str = "auto",
) -> BinnedLevels:
    """:func:`bin_levels` without its saturation rule, which :meth:`BinnedLevels.clipped`
    applies: a slider step bins nothing again (binning the three 24 MP frames of the bench
    bracket took 0.44 s of every draft)."""
    _check_engine(engine)
    src = np.asarray(levels)
    f = int(factor)
    if src.ndim != 3 or not np.issubdtype(src.dtype, np.integer):
        raise ParameterError(
            "draft binning takes integer (H, W, C) levels", found=f"{src.dtype} {src.shape}"
        )
    if f < 1 or src.shape[0] < f or src.shape[1] < f:
        raise ParameterError(
            "binning factor must be >= 1 and fit the frame",
            found=f"{f} for {src.shape[0]}x{src.shape[1]}",
        )
    c = src.shape[2]
    m = int(max_level)
    has_ex = exclude_colour is not None
    ex = np.asarray(exclude_colour if has_ex else (-1,) * c, dtype=np.int64)
    if lut is None:
        tab = np.tile(np.arange(m + 1, dtype=np.float64), (c, 1))
    else:
        tab = np.asarray(lut, dtype=np.float64)
        tab = np.tile(tab, (c, 1)) if tab.ndim == 1 else tab
        if tab.shape != (c, m + 1):
            raise ParameterError(
                "lut must be (C, max_level + 1)", expected=str((c, m + 1)), found=str(tab.shape)
            )
    if int(src.max(initial=0)) > m:
        raise ParameterError(
            "levels above max_level", expected=f"<= {m}", found=str(int(src.max()))
        )
    means, block_max = _block_means(src, f, tab, ex, has_ex)
    excluded = means == _EXCLUDED
    means[excluded] = 0.0  # (a level of the colour below: no negative mean cast to levels)
    if lut is None:
        k = 1
        out = np.floor(means + 0.5).astype(src.dtype)
    else:
        k = max(1, FINE_TOP // m)
        out = _all_levels(np.ascontiguousarray(tab), means, k)
    out[excluded] = (k * np.broadcast_to(ex, means.shape))[excluded]
    return BinnedLevels(
        levels=out,
        block_max=block_max,
        excluded=excluded.any(axis=2) if has_ex else None,
        top=k * m,
    )


def bin_levels(
    levels: np.ndarray,
    factor: int,
    *,
    saturation: float,
    max_level: int,
    exclude_colour: tuple[int, int, int] | None = None,
    lut: np.ndarray | None = None,
    engine: str = "auto",
) -> np.ndarray:
    """Integer ``(H, W, C)`` levels binned ``factor x factor`` by the rules of the module
    docstring (the ragged edge is cropped), by compiled kernels (:mod:`hdrcore.draft_spec`
    states the same in numpy, for the tests): :func:`bin_frame`, then the saturation rule
    (:meth:`BinnedLevels.clipped`). ``engine``: ``"auto"`` or ``"numba"``; ``"numpy"`` (the
    numpy path, removed) is a deprecated alias of the kernels for one release.

    Without ``lut`` the block means are of the levels (linear data), the result in the same
    dtype. With ``lut`` (``(C, max_level + 1)``, increasing: the response ``g``) they are of
    ``g(levels)``: the mean of a non-linear response's levels is not the level of the mean
    exposure (a block spanning an edge or texture would come out darker, 2 % in the median on
    the memorial scans); the result is then uint16 levels of ``k = FINE_TOP // max_level`` times
    the resolution (``k * max_level`` is the top), each the level whose ``g`` (read at
    ``level / k``, linearly between entries) is nearest to the block's mean exposure.
    """
    return bin_frame(
        levels,
        factor,
        max_level=max_level,
        exclude_colour=exclude_colour,
        lut=lut,
        engine=engine,
    ).clipped(saturation)


def bin_bracket(
    bracket: Bracket,
    factor: int,
    *,
    exclude_colour: tuple[int, int, int] | None = None,
    lut: np.ndarray | None = None,
) -> tuple[BinnedLevels, ...]:
    """Every frame of ``bracket`` binned by :func:`bin_frame` (what :func:`draft_bracket`
    takes as ``binned``)."""
    return tuple(
        bin_frame(
            fr.levels,
            factor,
            max_level=bracket.max_level,
            exclude_colour=exclude_colour,
            lut=lut,
        )
        for fr in bracket.frames
    )


def draft_bracket(
    bracket: Bracket,
    factor: int,
    *,
    saturation: float,
    exclude_colour: tuple[int, int, int] | None = None,
    exposure_times: Sequence[float] | None = None,
    lut: np.ndarray | None = None,
    binned: Sequence[BinnedLevels] | None = None,
) -> Bracket:
    """``bracket`` with every frame binned ``factor x factor`` (:func:`bin_levels`); the
    metadata stay (paths, EXIF), the RAW mosaic and its optical-black read noise go (the noise
    is measured again on the binned levels). ``exposure_times``: the frames' times become
    these (a list read from a file: no ISO or aperture term), for a run with
    ``times="exif"``. ``lut``: the response of non-linear frames, binned in exposure into
    uint16 levels of finer steps (their ``max_level`` is then ``k`` times the bracket's, see
    :func:`bin_levels`). ``binned``: :func:`bin_bracket` of this bracket with the same
    ``factor``, ``exclude_colour`` and ``lut`` (kept from an earlier draft), so that only the
    saturation rule runs."""
    m = bracket.max_level
    top = m if lut is None else max(1, FINE_TOP // m) * m
    metas = [replace(fr.meta, read_noise=None, read_noise_source=None) for fr in bracket.frames]
    if lut is not None:
        metas = [
            replace(mt, max_level=top, bit_depth=16, white_level=None, channel_max_levels=None)
            for mt in metas
        ]
    if exposure_times is not None:
        if len(exposure_times) != len(metas):
            raise ParameterError(
                "one exposure time per frame",
                expected=str(len(metas)),
                found=str(len(exposure_times)),
            )
        metas = [
            replace(
                mt,
                exposure_time=Fraction(float(t)),
                exposure_time_source="times-file",
                exposure_time_apex=None,
                exposure_time_sequence=None,
                iso=None,
                f_number=None,
                f_number_apex=None,
            )
            for mt, t in zip(metas, exposure_times, strict=True)
        ]
    if binned is None:
        binned = bin_bracket(bracket, factor, exclude_colour=exclude_colour, lut=lut)
    elif len(binned) != len(bracket) or any(b.top != top for b in binned):
        raise ParameterError(
            "the binned frames are not of this bracket and lut",
            expected=f"{len(bracket)} frames, top {top}",
            found=f"{len(binned)} frames, top {sorted({b.top for b in binned})}",
        )
    frames = tuple(
        Frame(levels=b.clipped(saturation), meta=mt) for b, mt in zip(binned, metas, strict=True)
    )
    return replace(bracket, frames=frames)


def draft_registration(
    registration: BracketRegistration, factor: int, shape: tuple[int, int]
) -> BracketRegistration:
    """A full-resolution run's registration on frames binned ``factor x factor`` of size
    ``shape`` (:func:`hdrcore.pipeline.scale_registration` by ``1 / factor``; a block's centre
    sits at ``factor * (x + 0.5) - 0.5``, the ragged edge cropped at the far side moves no
    origin), without its local refinement (the draft never refines locally: its fields are of
    the full-resolution grid, and a fraction of a binned pixel)."""
    from .pipeline import scale_registration

    return scale_registration(
        replace(registration, local=None),
        1.0 / int(factor),
        shape,
        note=f" (the full-resolution run's motion, scaled to the draft binned {factor}x{factor})",
    )


DRAFT_LUT_TOLERANCE = 1e-4
"""A draft bins its frames again for a new response only when the response moved by more than
this fraction of its top value at some level. A hand-held bracket's response is recovered again
from the registered frames after each registration, so every step that registered again made
the next draft bin anew (0.5-0.6 s of a 0.9-1.1 s draft on the real Xperia bracket) for a curve
that had moved by at most 2.6e-5 of its top (relative 6e-5; saturation steps of 2-10 levels):
the binned levels are the levels whose response is nearest a block's mean exposure, and the
draft's merge reads them through the current curve."""


def _luts_close(a: np.ndarray | None, b: np.ndarray | None, tolerance: float) -> bool:
    """Both ``None``, or tables of one shape within ``tolerance`` of ``b``'s top value."""
    if a is None or b is None:
        return a is None and b is None
    a = np.asarray(a, np.float64)
    if a.shape != b.shape:
        return False
    top = float(np.max(np.abs(b))) if b.size else 0.0
    return bool(np.max(np.abs(a - b), initial=0.0) <= tolerance * top)


class DraftCache:
    """What the drafts of one bracket keep across slider steps (the inspector's
    :class:`hdrview.session.Session` holds one per loaded bracket): the binned frames before
    the saturation rule (:func:`bin_bracket`), keyed by the bracket (the object), the factor,
    the excluded colour and the response's table. A saturation, noise-floor or threshold step
    bins nothing again; a new response or excluded colour bins once more. ``binnings`` counts
    the binnings done (the tests read it)."""

    def __init__(self) -> None:
        self._bracket: Bracket | None = None
        self._key: tuple[Any, ...] | None = None
        self._lut: np.ndarray | None = None
        self._binned: tuple[BinnedLevels, ...] = ()
        self.binnings = 0

    def binned(
        self,
        bracket: Bracket,
        factor: int,
        *,
        exclude_colour: tuple[int, int, int] | None,
        lut: np.ndarray | None,
    ) -> tuple[BinnedLevels, ...]:
        """:func:`bin_bracket` of these arguments, from the last call when they are the same."""
        key = (int(factor), None if exclude_colour is None else tuple(exclude_colour))
        if (
            self._bracket is not bracket
            or self._key != key
            or not _luts_close(lut, self._lut, DRAFT_LUT_TOLERANCE)
        ):
            self._binned = ()  # the old frames go before the new ones are binned
            self._binned = bin_bracket(bracket, factor, exclude_colour=exclude_colour, lut=lut)
            self._bracket, self._key = bracket, key
            self._lut = None if lut is None else np.array(lut, np.float64)
            self.binnings += 1
        return self._binned

    def clear(self) -> None:
        self._bracket, self._key, self._binned = None, None, ()


def run_draft(
    bracket: Bracket,
    params: PipelineParams,
    *,
    max_side: int = DRAFT_MAX_SIDE,
    exposure_times: Sequence[float] | None = None,
    progress: ProgressCallback | None = None,
    registration: BracketRegistration | None = None,
    cache: DraftCache | None = None,
    ratios: BracketExposureResult | None = None,
    frame_measures: FrameMeasures | None = None,
) -> PipelineResult:
    """Run the pipeline on the binned bracket with ``params`` (checked parameters, as a
    :class:`hdrcore.pipeline.PipelineResult` holds them: explicit saturation and noise floor)
    and return its :class:`~hdrcore.pipeline.PipelineResult`; ``result.preview_factor`` is the
    binning factor times the preview's own.

    ``exposure_times``: the times to merge with (those of a full-resolution run); without them
    the draft estimates its own from the binned frames (on the memorial scans 0.3-1.5 % off
    the full run's). With a :class:`~hdrcore.response.ResponseCurve` as ``params.response``
    non-linear frames are binned in exposure (:func:`bin_levels`) and the levels in
    ``params`` (saturation, noise floor, excluded colour) scaled to the finer levels.

    ``registration``: a full-resolution registration of ``bracket`` (the last full run's),
    used scaled (:func:`draft_registration`) in place of registering the binned frames
    (0.47 s of a 24 MP draft, and tenths of a pixel to pixels less exact than the full
    run's motion); ``None``, or a factor of 1 (nothing binned: its own registration is the
    full-resolution one), the draft registers its frames. ``cache``: a :class:`DraftCache`
    that keeps the binned frames across calls. The region ghost test is left pending.

    ``ratios``: with ``exposure_times``, the whole-frame ratios of the full-resolution frames
    for the same parameters (what the draft would only report: its own histogram fit cost
    0.3 s of a 1.7 s draft of the real Xperia bracket, 8 frames at 4096 levels); ignored
    without ``exposure_times`` (the draft then merges with times of its own).

    ``frame_measures``: with ``registration`` and a response curve, the full-resolution
    run's white balance per frame and local tone mapping test
    (:func:`~hdrcore.merge.colour_check.measure_frames` of the same motion and response),
    used in place of measuring the binned frames (0.12 s of the 24 MP sRGB bench bracket's
    draft, 0.27 s of the real Xperia's); ignored otherwise.
    """
    from .pipeline import Pipeline
    from .response import ResponseCurve

    if params.saturation is None or params.noise_floor is None:
        raise ParameterError(
            "the draft needs the saturation and noise floor the full run used",
            found=f"Z={params.saturation}, N={params.noise_floor}",
        )
    f = draft_factor(bracket.shape, max_side)
    m = bracket.max_level
    lut = None
    k = 1
    if isinstance(params.response, ResponseCurve) and not bracket.is_linear:
        lut = params.response.to_lut(m)
        k = max(1, FINE_TOP // m)
    binned = (
        None
        if cache is None
        else cache.binned(bracket, f, exclude_colour=params.exclude_colour, lut=lut)
    )
    small = draft_bracket(
        bracket,
        f,
        saturation=float(params.saturation),
        exclude_colour=params.exclude_colour,
        exposure_times=exposure_times,
        lut=lut,
        binned=binned,
    )
    # At factor 1 the draft's own registration is the full-resolution one for these
    # parameters: current and exact, where the given one may be a step old.
    given = (
        None if registration is None or f == 1 else draft_registration(registration, f, small.shape)
    )
    # Only the draft's picture is shown: its colour is anchored, not measured.
    pipe = Pipeline(
        small,
        progress=progress,
        pixel_size=float(f),
        registration=given,
        colour_report=False,
        ratios=None if exposure_times is None else ratios,
        frame_measures=frame_measures if given is not None and lut is not None else None,
    )
    # What only the verdicts or the inspector's other panels read is left out: local
    # refinement (a fraction of a binned pixel), the registration overlays and, with the
    # times given, the ratios measured again over the registered field of view.
    p = params.replace(
        preview_max_side=None,
        local="off",
        registration_previews=False,
        saturation=float(params.saturation) * k,
        noise_floor=float(params.noise_floor) * k,
        exclude_colour=None
        if params.exclude_colour is None
        else tuple(int(v) * k for v in params.exclude_colour),
    )
    if exposure_times is not None:
        # The ratios are then only reported: the plain estimator, not the refined one.
        p = p.replace(times="exif", refine_ratios="none", exposure_method="Cerman 2006")
    # The region ghost test changes no pixel without deghost: left pending
    # (``result.merge.ghost_test_pending``; 0.09-0.15 s of the bench bracket's draft).
    res = pipe.run(p, checks="later")
    return replace(res, preview_factor=res.preview_factor * f)
