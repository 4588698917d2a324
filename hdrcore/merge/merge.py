"""The HDR merge: a weighted average of linearised frames divided by their exposure times.

``E = sum_k(w_k * g(M_k) / dt_k) / sum_k(w_k)`` (Debevec & Malik 1997, eq. 6, in the linear
domain), where ``g`` linearises output levels to the saturation scale, ``dt_k`` are the (relative)
exposure times estimated after Cerman & Hlavac (2006, eqs. 3-4) and ``w_k`` a weighting function of
:mod:`hdrcore.merge.weights`.

Rules that keep the result free of colour casts and honest about what it could not see:

* A frame is dropped for *all* channels of a pixel when *any* channel of that pixel is at or above
  its saturation level (per-channel white levels allowed) or the warp marked the pixel invalid.
  Merging the unclipped channels of a frame with the clipped ones taken from a darker frame is
  what turns highlights magenta or green when one channel clips first.
* A sample at or below the noise floor gets zero weight in its own channel only.
* A pixel no frame gives weight to takes the darkest valid frame clipped there, a lower bound,
  and is flagged ``clipped``, when every usable frame is a shorter exposure than that frame
  (too short to see the pixel: a frame below the noise floor, or black, says nothing against
  a clip level). Otherwise a channel below the noise floor in every usable frame takes the
  brightest usable frame that gave the pixel weight (any usable one when none did; also where
  a longer exposure saw nothing where a shorter one clipped, data that contradict themselves,
  a marker or a moving object) and the pixel is flagged ``underexposed``. Such a value is that
  frame's ``E_k = g(M) / dt`` exactly as the weighted sums formed it (float32).
* With ``colour=`` (a :class:`~hdrcore.merge.colour.ColourConversion`) the radiance comes out in
  the working space, the pixels clipped in every frame neutral: the kernel converts each block
  while it is in cache, which saves a pass over the map.

Units: for integer frames ``saturation_level`` and ``noise_floor`` are output levels (the frames'
own units, 0..``max_level``); for float frames (already linear, 1.0 = saturation) they are linear
values. The radiance is in the units of ``g(M) / dt``: with times relative to the darkest frame,
``E`` of the darkest frame's unclipped pixels is its linear value.

Hand-held frames need not be warped beforehand: with ``transforms`` the merge resamples them
itself (Keys cubic convolution from the integer levels, see :func:`merge`; ``resample="bilinear"``
is a faster, softer opt-in), so the pipeline passes the bracket's own levels and no warped float
copies exist. The kernel runs the taps and the "any tap clipped" test of pixels whose supports
share their source rows as contiguous SIMD loops (see :mod:`hdrcore.merge._fused`); a support
leaving the frame reads as no data.

One implementation computes all this: the compiled kernel :func:`hdrcore.merge._fused.merge_rows`
(numba), for any channel count (3: RGB; 4 and 1: the RAW mosaic merge's CFA sites), called by
:func:`hdrcore.merge.engine.run_fused`. :mod:`hdrcore.merge.spec` states the same rules as plain
whole-image numpy; the tests hold the kernel to it. The work runs over blocks of rows with
float32 temporaries that stay in cache; the peak memory beyond inputs and outputs is a few
megabytes per worker.

References
----------
J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with hand held
camera", Computer Vision Winter Workshop, 2006.
P. E. Debevec, J. Malik, "Recovering high dynamic range radiance maps from photographs",
SIGGRAPH 1997, eq. 6. doi:10.1145/258734.258884
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from .._once import Once
from .._threads import worker_count
from ..errors import ParameterError, validate_method
from .colour import ColourConversion
from .consistency import GhostRegions, GhostTestParams, consistency_regions
from .deghost import fill_ghost_regions
from .engine import MERGE_ENGINES, default_engine, kernel_engine, run_fused
from .maps import DEFAULT_GHOST_THRESHOLD, DEFAULT_MODEL_ERROR
from .plan import (
    DEFAULT_SATURATION,
    RESAMPLING,
    Plan,
    make_plan,
    new_outputs,
    reused_outputs,
    sample_model,
)
from .result import MergeResult
from .weights import NoiseModel

__all__ = [
    "MergeResult",
    "merge",
    "MERGE_ENGINES",
    "DEFAULT_SATURATION",
    "DEFAULT_CHUNK_PIXELS",
    "RESAMPLING",
    "GHOST_TESTS",
    "default_engine",
]

logger = logging.getLogger(__name__)

GHOST_TESTS = {
    "regions": "blocks that disagree beyond noise, misregistration and the response's own "
    "error, in connected regions (hdrcore.merge.consistency)",
    "pixels": "every pixel whose score exceeds the threshold (hdrcore.merge.maps)",
}
"""How the ``ghost`` map is decided (``merge(..., ghost_test=...)``)."""

FEATHER_FRACTION = 0.02
"""A resampled frame's weight rises over this fraction of the image's shorter side from the
edge of the area it covers (:func:`hdrcore.merge._fused.coverage_feather`; 45 px on an 8 MP
phone frame). Phones tone-map each frame locally, so where a hand-held frame's edge crosses the
image the merge stepped between frames that disagree there: on the real Pixel 7 bracket a band
25-35 % brighter along the right edge and 6-13 % steps along the top and bottom."""


def default_feather(shape: tuple[int, ...]) -> float:
    """The feather width in px for an output grid of ``shape`` (:data:`FEATHER_FRACTION`)."""
    return float(round(FEATHER_FRACTION * min(shape[0], shape[1])))


DEFAULT_CHUNK_PIXELS = 1 << 16
"""Pixels per chunk of rows (at least 1/16 of a worker's share of the rows): the chunks only
balance the worker threads' work (the kernel's scratch is per block of a row)."""


def _merge_one_frame(plan: Plan, k: int, y0: int, y1: int, **kw) -> MergeResult:
    """Frame ``k`` merged alone over output rows ``y0:y1`` with the plan's settings (for
    :func:`hdrcore.merge.deghost.fill_ghost_regions`). A resampled frame is cut to a band of
    rows holding both the output rows and the source rows they map to (its transform shifted
    to the band), so the output grid and the frame share one row offset."""
    h = plan.shape[0]
    t = plan.transforms[k] if plan.transforms else None
    fld = plan.fields[k] if plan.fields else None
    b0, b1 = y0, y1
    if t is not None:
        w = plan.shape[1]
        ys = np.array([y0, y1 - 1], float)
        xs = np.array([0.0, w - 1.0])
        sy = [
            (t[1, 0] * x + t[1, 1] * y + t[1, 2]) / (t[2, 0] * x + t[2, 1] * y + t[2, 2])
            for x in xs
            for y in ys
        ]
        pad = 0 if fld is None else int(np.ceil(float(np.abs(fld.offsets[..., 1]).max())))
        b0 = max(0, min(y0, int(np.floor(min(sy))) - 3 - pad))
        b1 = min(h, max(y1, int(np.ceil(max(sy))) + 4 + pad))
        t = np.array(t, float)
        t[:, 2] += t[:, 1] * b0  # output row y of the band is row y + b0 of the grid
        t[1] -= b0 * t[2]  # ... and the frame's band starts at its row b0
    mask = plan.masks[k]
    res = merge(
        [plan.frames[k][b0:b1]],
        [float(plan.times[k])],
        max_level=plan.max_level,
        masks=None if mask is None else [mask[b0:b1]],
        saturation_level=tuple(float(v) for v in plan.saturation),
        noise_floor=plan.floor,
        weighting=plan.weighting,
        noise=plan.noise,
        transforms=None if t is None else [t],
        fields=None if fld is None else [fld.shifted(0.0, float(b0))],
        resample=plan.resample,
        **kw,
    )
    if (b0, b1) == (y0, y1):
        return res
    rows = slice(y0 - b0, y1 - b0)
    return replace(
        res,
        radiance=res.radiance[rows],
        weight_sum_map=res.weight_sum[rows],
        clipped=res.clipped[rows],
        underexposed=res.underexposed[rows],
    )


def merge(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float],
    *,
    response: np.ndarray | None = None,
    max_level: int | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    saturation_level: float | Sequence[float] | None = None,
    noise_floor: float | None = None,
    weighting: str | None = None,
    noise: NoiseModel | None = None,
    ghost_threshold: float = DEFAULT_GHOST_THRESHOLD,
    model_error: float = DEFAULT_MODEL_ERROR,
    chunk_pixels: int = DEFAULT_CHUNK_PIXELS,
    workers: int | None = None,
    engine: str | None = None,
    transforms: Sequence[np.ndarray | None] | None = None,
    fields: Sequence[Any] | None = None,
    resample: str = "cubic",
    feather: float | None = None,
    reuse: MergeResult | None = None,
    colour: ColourConversion | None = None,
    deghost: bool = False,
    ghost_test: str = "regions",
    ghost_params: GhostTestParams | None = None,
    weight_maps: bool = True,
    progress: Callable[[float, str], None] | None = None,
    defer_ghost_test: bool = False,
) -> MergeResult:
    """Merge aligned frames into one radiance map ``E = sum(w g(M) / dt) / sum(w)``.

    Parameters
    ----------
    frames
        ``N`` aligned frames ``(H, W, C)``, any exposure order: either unsigned integer output
        levels (with ``response`` and/or ``max_level``) or float32 linear values at the saturation
        scale (1.0 = saturation; float64 is converted).
    exposure_times
        ``N`` positive (relative) exposure times.
    response
        float ``(C, L)`` (or ``(L,)`` for all channels) LUT ``g``: level -> linear value at the
        saturation scale, ``L = max_level + 1``. ``None`` means the levels are linear
        (``g(M) = M / max_level``, e.g. RAW after black subtraction).
    max_level
        Largest level of integer frames (255, 4095, ``white - black``...). Defaults to ``L - 1`` of
        the LUT, or 255 for uint8.
    masks
        Optional ``N`` boolean ``(H, W)`` validity masks (``False`` = no data, e.g. the border of a
        warped frame) or ``None`` entries.
    saturation_level
        A sample at or above it is clipped; a number or one per channel (per-channel white
        levels). Integer frames: output levels; float frames: linear values. Default
        ``0.98 * max_level`` (or 0.98).
    noise_floor
        A sample at or below it gets zero weight in its channel; same units as
        ``saturation_level``. Default 0.
    weighting
        A name in :data:`hdrcore.merge.weights.WEIGHTS`; default ``"hat-noise-aware"`` with a
        response LUT (non-linear data; ``"hat"`` before 2026-12-07, see
        :func:`~hdrcore.merge.weights.weight_hat_noise_aware`), else ``"noise-aware"`` (linear
        data).
    noise
        :class:`NoiseModel` for the noise-aware weight and the ghost test.
    ghost_threshold, model_error
        See :mod:`hdrcore.merge.maps`.
    chunk_pixels, workers
        Pixels per chunk of rows and worker threads (the kernel releases the GIL);
        ``workers=None`` uses up to two threads.
    engine
        ``None`` or ``"numba"``: the compiled kernel, the one implementation
        (:data:`MERGE_ENGINES`). ``"numpy"`` named the numpy engine, removed: it is accepted
        for one release as a deprecated alias of the kernel (``DeprecationWarning``).
    transforms
        Optional ``N`` entries, each ``None`` (identity) or a 2x3 affine matrix mapping OUTPUT
        (reference-frame) pixel coordinates to that frame's pixel coordinates (x right, y down,
        origin at the centre of the top-left pixel), i.e.
        ``hdrcore.registration.invert(to_reference[k])``. Such a frame is resampled inside the
        merge, straight from its levels (or floats): Keys cubic convolution (a = -1/2), the 4
        weights per axis shared by the channels; integer levels are interpolated, clamped to
        ``[0, max_level]`` and linearised through the LUT read linearly between entries. The
        frame counts as clipped at a pixel when any of the 16 taps of any channel is at or
        above its saturation level (interpolation never mixes clipped and valid data) and as
        no data (like a ``False`` mask) where the 4x4 support leaves the frame. ``masks`` stay
        in output coordinates. Identity matrices take the direct path (no interpolation).
    resample
        A name in :data:`RESAMPLING`: ``"cubic"`` (above) or ``"bilinear"`` (2x2 taps, the same
        rules with the 2x2 support; about half the cost of a resampled frame, a little softer).
    feather
        Width in px over which a resampled frame's weight rises from the edge of the area it
        covers inside the image (:func:`hdrcore.merge._fused.coverage_feather`); ``None``:
        :func:`default_feather` (2 % of the shorter side), 0: a step. Frames without a
        transform, and the edges a frame shares with the image, are never feathered.
    reuse
        A previous result of the same shape and frame count whose arrays receive this result
        (overwritten: the caller must no longer use it). Writing into pages the process has
        already touched saves the first-touch cost of new output arrays (28 bytes a pixel for
        3 frames), which on a virtual machine can exceed the merge itself.

    colour
        A :class:`hdrcore.merge.colour.ColourConversion` (camera RGB -> working space,
        :func:`~hdrcore.merge.colour.colour_conversion`): the radiance comes out converted, the
        pixels clipped in every frame made neutral, exactly as
        :func:`~hdrcore.merge.colour.camera_to_working` would; the fused kernel does it while
        the block is in cache (one pass less over the map). 3-channel frames only.
    deghost
        Fill each region where the frames disagree (``ghost``, grown by 2 pixels) from one
        frame, the one with the largest share there (a frame not resampled when its share is at
        least half of that), where that frame is usable
        (:mod:`hdrcore.merge.deghost`): a moving object comes out whole instead of doubled.
        Replaced pixels are marked in ``MergeResult.deghosted``; their shares go wholly to
        that frame and ``ghost`` still shows where the frames disagreed.
    ghost_test, ghost_params
        A name in :data:`GHOST_TESTS`: ``"regions"`` (default; the per-pixel test fires on
        JPEG, demosaicing, misregistration and the response's error of static non-linear
        brackets: 5 % of the memorial scans, 14 % of a hand-held phone bracket) or ``"pixels"``;
        ``ghost_params`` the :class:`~hdrcore.merge.consistency.GhostTestParams` of
        ``"regions"``.
    weight_maps
        ``False``: the per-frame shares, the weight sum and the clip count are not kept
        (``MergeResult.share_maps``, ``weight_sum_map`` and ``clip_count_map`` are ``None``;
        ``2 N + 5`` bytes a pixel for ``N`` frames, 712 MiB of a 5-frame 45 MP merge); the
        kernel counts the provenance summary of :meth:`MergeResult.summary` instead, the same
        figures to the last bit. For a caller that reads none of these maps (``hdrcore merge``
        of linear input). ``deghost`` uses them and keeps them.
    progress
        Called as ``progress(0.5, "ghost test")`` when the kernel has written the outputs and
        the region ghost test starts (``hdrcore merge`` gives the heap's free pages back
        there: the test's block sums are its largest new allocation).
    defer_ghost_test
        With the region ghost test and without ``deghost``: the test (which changes no pixel of
        the radiance) is left for later. The result's ``ghost`` is empty and its
        ``ghost_regions`` None; :meth:`MergeResult.with_ghost_test` runs it (once) and returns
        the complete result. A viewer shows the merge a ghost test sooner (24 MP: 1.1 s), a
        command writes its EXR while the test runs.

    Raises
    ------
    ParameterError
        For an empty list, mismatched shapes, non-positive times, out-of-range levels, unknown
        weighting names, a LUT or mask that does not fit the frames, a transform that is not
        a finite 2x3 matrix, a colour conversion of frames that are not RGB and a missing numba.
    """
    t0 = time.perf_counter()
    plan = make_plan(
        frames,
        exposure_times,
        response,
        max_level,
        masks,
        saturation_level,
        noise_floor,
        weighting,
        noise,
        transforms,
        fields,
    )
    resample = validate_method(resample, RESAMPLING, "resampling")
    if resample != plan.resample:
        plan = replace(plan, resample=resample)
    if feather is None:
        feather = default_feather(plan.shape[:2])
    if not np.isfinite(feather) or feather < 0:
        raise ParameterError("feather must be >= 0 px", found=str(feather))
    if plan.warped and feather != plan.feather:
        plan = replace(plan, feather=float(feather))
    if not np.isfinite(ghost_threshold) or ghost_threshold <= 0:
        raise ParameterError("ghost threshold must be positive", found=str(ghost_threshold))
    if not np.isfinite(model_error) or model_error < 0:
        raise ParameterError("model error must be >= 0", found=str(model_error))
    ghost_test = validate_method(ghost_test, GHOST_TESTS, "ghost test")
    if workers is None:
        workers = worker_count(None)
    if int(chunk_pixels) < 1 or int(workers) < 1:
        raise ParameterError(
            "chunk_pixels and workers must be >= 1", found=f"{chunk_pixels}, {workers}"
        )
    engine = kernel_engine(engine)
    h, w, c = plan.shape
    if colour is not None and c != 3:
        raise ParameterError(
            "a colour conversion needs RGB frames", expected="3 channels", found=f"{c} channels"
        )
    n = len(plan.frames)
    t1 = time.perf_counter()
    keep = bool(weight_maps) or bool(deghost)  # deghosting reads and rewrites the shares
    out = (
        new_outputs((h, w, c), n, keep)
        if reuse is None
        else reused_outputs(reuse, (h, w, c), n, keep)
    )
    # no per-chunk scratch: chunks only balance the threads' work
    rows = max(1, int(chunk_pixels) // w, -(-h // (16 * int(workers))))
    spans = [(r, min(h, r + rows)) for r in range(0, h, rows)]
    workers = min(int(workers), len(spans))
    # exp() of the Gaussian weight, vectorised, may differ from numpy's in the last bit:
    # integer levels take it from the per-level tables (numpy's exp, as before), so their
    # results do not depend on the compiler's choice
    provenance = run_fused(
        plan,
        out,
        sample_model(plan, float(ghost_threshold), float(model_error)),
        spans,
        workers,
        force_tables=plan.integer and plan.weighting == "gaussian",
        colour=colour,
    )
    t2 = time.perf_counter()
    ghost_score, ghost = out.ghost_score, out.ghost

    def region_test() -> GhostRegions:
        regions = consistency_regions(
            plan.frames,
            [float(t) for t in plan.times],
            saturation=[float(v) for v in plan.saturation],
            floor=plan.floor,
            lut=plan.response,
            max_level=plan.max_level,
            noise=plan.noise,
            masks=plan.masks,
            transforms=plan.transforms or None,
            candidates=ghost,
            score=ghost_score,
            params=ghost_params,
            workers=workers,
        )
        np.copyto(ghost, regions.ghost)
        return regions

    ghost_regions = None
    deferred = ghost_test == "regions" and bool(defer_ghost_test) and not deghost
    if ghost_test == "regions" and not deferred:
        if progress is not None:
            progress(0.5, "ghost test")
        ghost_regions = region_test()
    t_ghost = time.perf_counter()
    deghosted = None
    if deghost:

        def single(k: int, y0: int, y1: int) -> MergeResult:
            return _merge_one_frame(
                plan,
                k,
                y0,
                y1,
                response=response,
                engine=engine,
                workers=workers,
                ghost_threshold=ghost_threshold,
                model_error=model_error,
                colour=colour,
                ghost_test="pixels",
            )

        # frames not resampled are preferred where nearly as well exposed (no interpolation
        # error in their values)
        prefer = np.array([t is None for t in plan.transforms]) if plan.warped else None
        assert out.weight_sum is not None and out.shares is not None  # (keep)
        deghosted = fill_ghost_regions(
            out.radiance, out.weight_sum, out.shares, ghost, single, prefer=prefer
        )
    t3 = time.perf_counter()

    n_pix = h * w
    n_clipped = int(np.count_nonzero(out.clipped))
    n_under = int(np.count_nonzero(out.underexposed))

    def summary(ghosts: np.ndarray) -> tuple[str, str]:
        notes = []
        if n_clipped:
            notes.append(
                f"{100.0 * n_clipped / n_pix:.2f}% of pixels clipped in every frame "
                "(darkest frame's value, a lower bound)"
            )
        if n_under:
            notes.append(
                f"{100.0 * n_under / n_pix:.2f}% of pixels below the noise floor in every frame "
                "in some channel (brightest frame's value)"
            )
        n_ghost = int(np.count_nonzero(ghosts))
        if n_ghost:
            notes.append(
                f"{100.0 * n_ghost / n_pix:.2f}% of pixels disagree between frames (ghosts)"
            )
        if deghosted is not None and deghosted.any():
            notes.append(
                f"{100.0 * np.count_nonzero(deghosted) / n_pix:.2f}% of pixels filled "
                "from one frame (deghost)"
            )
        return ("warning" if notes else "ok"), ("; ".join(notes) if notes else f"merged {n} frames")

    # deferred: no ghost known yet (the kernel's per-pixel candidates are the test's input,
    # not its answer)
    status, message = summary(np.zeros((0,), bool) if deferred else ghost)
    logger.debug("merge: %s", message)
    result = MergeResult(
        radiance=out.radiance,
        weight_sum_map=out.weight_sum,
        share_maps=out.shares,
        clip_count_map=out.clip_count,
        clipped=out.clipped,
        underexposed=out.underexposed,
        ghost_score=ghost_score,
        ghost=np.zeros(ghost.shape, bool) if deferred else ghost,
        exposure_times=tuple(float(t) for t in plan.times),
        weighting=plan.weighting,
        units="levels" if plan.integer else "linear",
        max_level=plan.max_level,
        saturation_level=tuple(float(v) for v in plan.saturation),
        noise_floor=float(plan.floor),
        noise=plan.noise,
        ghost_threshold=float(ghost_threshold),
        model_error=float(model_error),
        status=status,
        message=message,
        timings={
            "validate": t1 - t0,
            "merge": t2 - t1,
            "ghosts": t_ghost - t2,
            "maps": t3 - t_ghost,
            "total": t3 - t0,
        },
        engine=engine,
        deghosted=deghosted,
        ghost_test=ghost_test,
        ghost_regions=ghost_regions,
        provenance=provenance,
    )
    if not deferred:
        return result

    def finish() -> MergeResult:
        t = time.perf_counter()
        if progress is not None:
            progress(0.5, "ghost test")
        regions = region_test()
        status, message = summary(ghost)
        logger.debug("merge (ghost test done): %s", message)
        timings = dict(result.timings, ghosts=time.perf_counter() - t)
        return replace(
            result,
            ghost=ghost,
            ghost_regions=regions,
            status=status,
            message=message,
            timings=timings,
            pending_ghost_test=None,
        )

    # the test runs once, whoever asks first; later calls return the same result
    return replace(result, pending_ghost_test=Once(finish))
