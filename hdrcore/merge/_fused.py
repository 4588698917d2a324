"""The merge kernel: one pass over blocks of pixels, every frame and channel.

The merge's one implementation (:func:`hdrcore.merge.merge` runs it through
:func:`hdrcore.merge.engine.run_fused`); :mod:`hdrcore.merge.spec` states its rules as plain
whole-image numpy, and the tests hold the kernel to that specification.

One kernel, :func:`merge_rows`, for every input: any channel count ``C`` (3: RGB; 4: the RAW
mosaic merge's CFA sites; 1: one site plane), frames with a transform (resampled inside the
merge, Keys cubic convolution (Keys 1981, a = -1/2) or bilinear, see :func:`hdrcore.merge.merge`)
and frames read in place (float; integer levels, linear or through per-level tables). The
channel loops are written once; ``C`` is the length of a tuple argument (the clip thresholds,
``FusedModel.tap_thr``), a compile-time constant: numba compiles one specialisation per channel
count and unrolls those loops as if written for it. A new weighting needs no change here: it is
one scalar function in :mod:`hdrcore.merge.weights` (inlined when built in, else called through
its compiled pointer ``wfn``). It is laid out for SIMD: per block of a row each frame's values
form one interleaved run (element ``C x + ch``), so the sums, the weights and the finish are
straight loops over elements with no per-channel branch. A resampled frame's coordinates and
Keys weights are computed for the whole block in one loop (float64), then the
block is cut into runs of pixels whose 4 x 4 supports share their source rows and column offset
(under a small rotation a run is about ``1 / sin(angle)`` pixels long): over a run the taps of
each source row are contiguous, so the 16 taps are 16 multiply-adds over contiguous memory
instead of 48 scattered loads per pixel. The "any tap clipped" test is made per run too: each
source column of the run once, then ``ntap`` columns per support (:func:`_clipped_supports`).
Integer frames read in place with a response LUT (or with the Gaussian weight, whose ``exp`` is
then numpy's to the last bit) go through per-level tables built with the kernel's float32
arithmetic (:func:`hdrcore.merge.engine.level_tables`: the linearisation and the
weighting applied to every level of every frame and channel:
``E_k = g(M) / dt``, ``w`` with the noise floor applied and ``w var(E_k)``; ``w E_k`` and
``w E_k**2`` are made from the first two, the same float32 products), three loads and five
adds a sample: the compiler does not vectorise table loads on this CPU (gathers are not used
on AMD), so those loops run scalar.

Fallback values (pixels clipped in every frame, channels below the noise floor in every
usable frame) are candidates tracked in the sums (the first valid frame's ``E_k``, the last
frame not dropped's), so the finish fills them in one straight pass.

Vectorisation rules learnt here (LLVM through numba, measured): an array load inside a
conditional expression (``a[e] if c else b[e]``) keeps a whole loop scalar, so loads are
hoisted and the selects take values; slices starting at 0 avoid negative-index checks; int32
rather than int64 per-pixel arrays keep loops at the float32 width.

The kernels are compiled by numba with ``nogil=True`` and run over row blocks on the caller's
thread pool rather than numba's own ``prange``: numba's default (workqueue) threading layer
aborts the process when two Python threads launch parallel kernels at once, and the inspector
merges on a background thread; a ``nogil`` kernel has no such restriction and keeps the
``workers`` parameter meaning what it says. ``cache=True`` stores the machine code next to this
file (``__pycache__``), so only the first call on a machine pays the compilation; see
:func:`warm_up`.

References
----------
R. G. Keys, "Cubic convolution interpolation for digital image processing", IEEE Trans.
Acoustics, Speech and Signal Processing 29(6), 1981. doi:10.1109/TASSP.1981.1163711
P. E. Debevec, J. Malik, "Recovering high dynamic range radiance maps from photographs",
SIGGRAPH 1997, eq. 6. doi:10.1145/258734.258884
"""

from __future__ import annotations

import logging
import time
from typing import Any, NamedTuple

import numpy as np

from .._numba import AVAILABLE  # without numba the merge refuses to run (engine.kernel_engine)
from .._numba import inline as _inline
from .._numba import njit as _njit
from ..geometry import keys4
from .colour import convert_pixels
from .weights import weight_by_code

logger = logging.getLogger(__name__)

TUPLE_SLOTS = 16
"""The frame tuples handed to the kernel are padded to a multiple of this many entries (with
the first frame; ``len(order)`` is the frame count): numba compiles one kernel per tuple length,
so a bracket of 5, 7 or 16 frames reuses the one compiled (and cached) for 3 instead of spending
seconds compiling its own."""


class FusedFrames(NamedTuple):
    """The frames (tuples padded to :data:`TUPLE_SLOTS`) and their exposures."""

    frames: tuple[np.ndarray, ...]  # (H, W, C) each
    flats: tuple[np.ndarray, ...]  # the same as (H, W * C)
    masks: tuple[np.ndarray, ...]  # (H, W) validity, or a dummy where not has_mask
    has_mask: np.ndarray  # bool (N,)
    order: np.ndarray  # int64 (N,): frame indices, shortest exposure first (unpadded)
    inv_t: np.ndarray  # float32 (N,) 1 / dt
    inv_t2: np.ndarray  # float32 (N,) 1 / dt**2
    t2: np.ndarray  # float32 (N,) dt**2


class FusedWarp(NamedTuple):
    """How frames with a transform are resampled."""

    mats: np.ndarray  # float64 (N, 3, 3): output -> frame pixel coordinates
    has_mat: np.ndarray  # bool (N,): resampled
    ntap: int  # 4: Keys cubic, 2: bilinear
    oor: np.ndarray  # bool (N,): resampled frame with levels past the LUT
    flds: np.ndarray  # float64 (N, gh, gw, 2): displacement fields on one node grid
    has_fld: np.ndarray  # bool (N,)
    fgeo: np.ndarray  # float64 (3,): 1 / step, origin x, origin y of the fields' grid
    feather: float  # width in px over which a resampled frame's weight rises from its edge


class FusedModel(NamedTuple):
    """Linearisation, noise, weighting and clipping of the samples."""

    wcode: int  # a built-in weighting's code (weights.weight_by_code), -1: the pointer
    shot: Any  # float32: variance per unit of linear signal
    const_var: Any  # float32: signal-independent variance
    floor_norm: Any  # float32: noise floor, normalised level
    inv_max: Any  # float32: 1 / max_level (1 for float frames)
    hi: Any  # float32: largest interpolated value (max_level or 1)
    has_lut: bool
    lut: np.ndarray  # float32 (C, L): level -> linear value (a dummy without a LUT)
    lut_var: np.ndarray  # float32 (C, L): level-noise variance through g'
    # C clip thresholds in the frames' dtype (tap_thresholds), a tuple: its length, the
    # channel count, is a compile-time constant (one specialisation per count)
    tap_thr: tuple[Any, ...]
    use_tab: bool  # integer frames read in place through the per-level tables
    tabs: np.ndarray  # float32 (N, C L, 4): engine.level_tables


class FusedFinish(NamedTuple):
    """The ghost test's constants and the colour conversion of finished blocks."""

    me2: Any  # float32: squared relative model error
    thr: Any  # float32: ghost threshold
    has_colour: bool
    cm: np.ndarray  # float64 (3, 3) camera -> working space
    cwb: np.ndarray  # float64 (3,)
    cneu: np.ndarray  # float64 (3,)


class FusedOutputs(NamedTuple):
    """The arrays the kernel writes (float16 maps as their uint16 bits). Without ``maps``
    the weight sum, the shares and the clip count are not kept (``wsum``, ``shares`` and
    ``clip_count`` are unused placeholders; each worker finishes a block in a scratch row)
    and the provenance summary
    is counted instead, per output row: ``prov_count[y, k]`` the pixels frame ``k`` dominates
    (the largest float16 share, the first on a tie), ``prov_units[y, k]`` the sum of its
    float16 shares in units of 2**-24 (every float16 value is a whole number of them, so the
    sums are exact in any order: :func:`hdrcore.merge.maps.provenance_summary`'s figures to
    the last bit). With ``maps`` both are unused placeholders."""

    rad: np.ndarray
    wsum: np.ndarray
    shares: np.ndarray
    clip_count: np.ndarray
    clipped: np.ndarray
    under: np.ndarray
    gscore: np.ndarray
    ghost: np.ndarray
    maps: bool
    prov_count: np.ndarray  # int64 (H, N), or (1, N) with maps
    prov_units: np.ndarray  # int64 (H, N), or (1, N) with maps


_F16_MAX = np.float32(65504.0)
_TINY = np.float32(1e-30)
_ONE_F16 = np.uint16(0x3C00)  # 1.0 as float16 bits
_WBLOCK = 2048  # merge_rows (6000 px rows: 2048 beats 512..1536 and 3072..6000)


@_njit
def _f16_bits(v):
    """float16 bits of a non-negative float32, as :func:`maps.to_float16_nonnegative`."""
    if v > _F16_MAX:
        v = _F16_MAX
    s = (np.float32(v).view(np.int32) + np.int32(0x1000)) >> np.int32(13)
    s -= np.int32(112 << 10)
    if s < 0:
        s = np.int32(0)
    return np.uint16(s)


@_njit
def _f16_units(b):
    """The non-negative float16 of bits ``b`` as a whole number of 2**-24 (exact: the
    smallest subnormal), int64."""
    e = (np.int64(b) >> 10) & 31
    m = np.int64(b) & 1023
    return m if e == 0 else (m + 1024) << (e - 1)


def warm_up() -> float:
    """Compile (or load from the on-disk cache) the kernels for 3 frames of uint16, uint8 and
    float32 (3 channels; uint16 with 4 and 1 channels: the RAW mosaic merge); returns the
    seconds it took. Call it on a background thread at start-up to keep the first merge fast.
    The frame tuples are padded to :data:`TUPLE_SLOTS`, so these serve brackets of up to 16
    frames."""
    if not AVAILABLE:
        return 0.0
    from .merge import merge

    t0 = time.perf_counter()
    for dtype in (np.uint16, np.uint8):
        frames = [np.full((2, 3, 3), 10 * (k + 1), dtype) for k in range(3)]
        merge(frames, (1.0, 2.0, 4.0), max_level=255, engine="numba", workers=1)
        merge(frames, (1.0, 2.0, 4.0), response=np.linspace(0, 1, 256), engine="numba", workers=1)
    frames = [np.full((2, 3, 3), 0.1 * (k + 1), np.float32) for k in range(3)]
    merge(frames, (1.0, 2.0, 4.0), engine="numba", workers=1)
    mask = np.ones((2, 3), bool)
    merge(frames, (1.0, 2.0, 4.0), masks=[None, mask, mask], engine="numba", workers=1)
    tf = [np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.25]]), None, None]  # resampling kernel
    merge(frames, (1.0, 2.0, 4.0), transforms=tf, engine="numba", workers=1)
    for dtype in (np.uint16, np.uint8):
        frames = [np.full((2, 3, 3), 10 * (k + 1), dtype) for k in range(3)]
        merge(frames, (1.0, 2.0, 4.0), max_level=255, transforms=tf, engine="numba", workers=1)
        merge(
            frames,
            (1.0, 2.0, 4.0),
            response=np.linspace(0, 1, 256),
            transforms=tf,
            engine="numba",
            workers=1,
        )
        merge(
            frames,
            (1.0, 2.0, 4.0),
            max_level=255,
            transforms=tf,
            engine="numba",
            workers=1,
            resample="bilinear",
        )
        # read-only frames (a decoded bracket's levels) are another type to numba
        for f in frames:
            f.setflags(write=False)
        merge(frames, (1.0, 2.0, 4.0), max_level=255, engine="numba", workers=1)
        merge(frames, (1.0, 2.0, 4.0), max_level=255, transforms=tf, engine="numba", workers=1)
    # the RAW mosaic merge: 4 CFA sites as channels (tripod), 1 site plane (hand-held)
    frames = [np.full((2, 3, 4), 10 * (k + 1), np.uint16) for k in range(3)]
    merge(frames, (1.0, 2.0, 4.0), max_level=255, engine="numba", workers=1)
    frames = [np.full((2, 3, 1), 10 * (k + 1), np.uint16) for k in range(3)]
    merge(frames, (1.0, 2.0, 4.0), max_level=255, transforms=tf, engine="numba", workers=1)
    from .colour import camera_to_working

    camera_to_working(
        np.ones((2, 3, 3), np.float32), None, None, clipped=np.zeros((2, 3), bool), workers=1
    )
    return time.perf_counter() - t0


# --------------------------------------------------------------------------------------------
# Resampling inside the merge: frames with a transform are read at T_k (x, y, 1) with Keys'
# cubic convolution (a = -1/2) straight from their levels (the specification:
# hdrcore.merge.spec._sample / _linearise).


@_inline
def _keys(f):
    """Keys weights of taps -1, 0, 1, 2 at fraction ``f`` (float64, :func:`hdrcore.resample.keys4`),
    returned as float32."""
    w0, w1, w2, w3 = keys4(f)
    return np.float32(w0), np.float32(w1), np.float32(w2), np.float32(w3)


def tap_thresholds(sat: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Per-channel thresholds in ``dtype`` with ``v >= thr`` exactly when ``float64(v) >= sat``
    (integer frames: ``ceil(sat)``; float32 frames: the smallest float32 not below ``sat``)."""
    sat = np.asarray(sat, np.float64)
    if np.dtype(dtype).kind == "u":
        return np.ceil(sat).astype(dtype)
    thr = sat.astype(np.float32)
    low = thr.astype(np.float64) < sat
    thr[low] = np.nextafter(thr[low], np.float32(np.inf))
    return thr


@_njit
def _finish_block(
    y,
    x0,
    x1,
    n,
    order,
    den,
    num,
    s2,
    sv,
    share,
    fv,
    lo,
    nbad,
    me2,
    gthr,
    wsum_out,
    shares,
    clipped_out,
    under_out,
    gscore,
    ghost,
    pick,
    invw,
    zflag,
    radf,
    bb,
    cc,
    eb,
    tap_thr,
    ys,
    prov,
    pcnt,
    punits,
):
    """Radiance, ghost score, shares and fallback values of one block from interleaved sums
    (``den[C i + ch]``, ``C = len(tap_thr)`` channels: only the tuple's length is read), the
    sums' steps straight passes (SIMD). ``fv[i]`` is the exposure-order position of the darkest
    valid frame clipped at the pixel (``n``: none), ``lo[i]`` that of the brightest usable frame
    that gave it weight (the brightest usable one when none did; -1: none usable),
    ``nbad[i]`` the number of frames dropped and ``eb[j]`` the ``E_k`` of the ``j``-th frame.
    A pixel with a channel of no weight takes (in those channels, or in all) the value of one
    frame, ``pick[i]``, which takes the whole share when no channel has weight. The weight
    sum and the shares go to row ``ys`` of ``wsum_out`` and ``shares`` (``y``, or 0 of a
    worker's scratch row); with ``prov`` the block's provenance is added to row ``y`` of
    ``pcnt`` and ``punits`` (:class:`FusedOutputs`)."""
    nch = len(tap_thr)  # a compile-time constant: one specialisation per channel count
    zero = np.float32(0.0)
    one = np.float32(1.0)
    nbk = x1 - x0
    ne = nch * nbk
    ro = radf[y, nch * x0 : nch * x1]
    for e in range(ne):
        d = den[e]
        inv = one / (d if d >= _TINY else _TINY)
        a = num[e] * inv
        ro[e] = a
        a = a * a
        b = s2[e] * inv - a
        bb[e] = b if b >= zero else zero
        cc[e] = sv[e] * inv + a * me2
    ws = wsum_out[ys, x0:x1]
    gh = ghost[y, x0:x1]
    gs = gscore[y, x0:x1]
    nz = 0
    for i in range(nbk):
        e = nch * i
        # the channels' sums in channel order: ((c0 + c1) + c2) ...
        spread = bb[e]
        noise = cc[e]
        wsum = den[e]
        z = den[e] <= zero
        for ch in range(1, nch):
            spread = spread + bb[e + ch]
            noise = noise + cc[e + ch]
            wsum = wsum + den[e + ch]
            z = z | (den[e + ch] <= zero)
        noise = noise if noise >= _TINY else _TINY
        v = spread / noise
        gh[i] = v > gthr
        gs[i] = _f16_bits(v)
        ws[i] = wsum
        invw[i] = one / (wsum if wsum >= _TINY else _TINY)
        zflag[i] = z
        nz += z
    # fallbacks (hdrcore.merge.merge's docstring), for the few pixels with a channel of no
    # weight: no frame gave the pixel weight, a valid frame is clipped there and every usable frame
    # is a shorter exposure: the darkest clipped frame's value in every channel (a lower
    # bound; shorter frames below the noise floor, a black one, say nothing against it); no
    # valid frame at all: the darkest frame's, not clipped. Otherwise (some frame usable) the
    # channels of no weight take the brightest usable frame that gave the pixel weight (any
    # usable one when none did).
    co = clipped_out[y, x0:x1]
    uo = under_out[y, x0:x1]
    for i in range(nbk):
        co[i] = False
        uo[i] = False
        pick[i] = -1
    for i in range(nbk if nz > 0 else 0):
        if not zflag[i]:
            continue
        e = nch * i
        whole = den[e] <= zero
        for ch in range(1, nch):
            whole = whole & (den[e + ch] <= zero)
        f = fv[i]
        last = lo[i]
        allbad = nbad[i] == n
        cl = whole & (((f < n) & (last < f)) | allbad)
        co[i] = cl & (f < n)
        uo[i] = not cl
        if cl:
            jp = f if f < n else 0
            src = eb[jp]
            for ch in range(nch):
                ro[e + ch] = src[e + ch]
        else:
            jp = last
            src = eb[jp]
            for ch in range(nch):
                if den[e + ch] <= zero:
                    ro[e + ch] = src[e + ch]
        if whole:  # the whole share to that frame
            pick[i] = order[jp]
    for k in range(n):
        sk = share[k]
        so = shares[k, ys, x0:x1]
        for i in range(nbk):
            h = _f16_bits(sk[i] * invw[i])
            p = pick[i]
            one_k = _ONE_F16 if p == k else np.uint16(0)
            so[i] = one_k if p >= 0 else h
    if prov:
        # maps.provenance_summary's counts and sums (its _provenance_rows), of this block
        pc = pcnt[y]
        pu = punits[y]
        for i in range(nbk):
            best = shares[0, ys, x0 + i]
            arg = 0
            for k in range(n):
                b = shares[k, ys, x0 + i]
                pu[k] += _f16_units(b)
                if b > best:
                    best = b
                    arg = k
            pc[arg] += 1


@_njit
def _accumulate_run(
    xk,
    okf,
    ne,
    wcode,
    wfn,
    inv_max,
    shot,
    const_var,
    floor_norm,
    itk,
    it2,
    t2k,
    den,
    num,
    s2,
    sv,
    wbuf,
    eb,
):
    """The sums of one frame over ``ne`` interleaved samples of linear data (no LUT): straight
    SIMD loops for the built-in weightings (:func:`hdrcore.merge.weights.weight_by_code`, one
    loop for the noise-aware weight of RAW data, one for the others), a scalar one for any
    other weighting (``wfn``, its compiled scalar form, when ``wcode < 0``). ``eb`` receives
    ``E_k`` of every sample: the fallback values are read from it."""
    zero = np.float32(0.0)
    if wcode == 2:
        for e in range(ne):
            level = np.float32(xk[e]) * inv_max
            var = level * shot
            var = var + const_var
            ev = level * itk
            ok = okf[e]
            eb[e] = ev
            wk = weight_by_code(2, level, level, t2k, var)
            wk = wk * (ok if level > floor_norm else zero)
            wbuf[e] = wk
            den[e] += wk
            var = var * wk
            sv[e] += var * it2
            wk = wk * ev
            num[e] += wk
            s2[e] += wk * ev
    elif wcode >= 0:
        for e in range(ne):
            level = np.float32(xk[e]) * inv_max
            var = level * shot
            var = var + const_var
            ev = level * itk
            ok = okf[e]
            eb[e] = ev
            wk = weight_by_code(wcode, level, level, t2k, var)
            wk = wk * (ok if level > floor_norm else zero)
            wbuf[e] = wk
            den[e] += wk
            var = var * wk
            sv[e] += var * it2
            wk = wk * ev
            num[e] += wk
            s2[e] += wk * ev
    else:
        for e in range(ne):
            level = np.float32(xk[e]) * inv_max
            var = level * shot
            var = var + const_var
            ev = level * itk
            ok = okf[e]
            eb[e] = ev
            wk = wfn(level, level, t2k, var)
            wk = wk * (ok if level > floor_norm else zero)
            wbuf[e] = wk
            den[e] += wk
            var = var * wk
            sv[e] += var * it2
            wk = wk * ev
            num[e] += wk
            s2[e] += wk * ev


@_njit
def _accumulate_lut_run(
    xk,
    okf,
    nbk,
    wcode,
    wfn,
    inv_max,
    shot,
    const_var,
    floor_norm,
    itk,
    it2,
    t2k,
    lut,
    lut_var,
    den,
    num,
    s2,
    sv,
    wbuf,
    eb,
    tap_thr,
):
    """The sums of one resampled frame with a LUT over ``nbk`` pixels: each channel's
    interpolated level read linearly between the entries of its LUT row, one loop per channel
    (``C = len(tap_thr)``; table loads: scalar code); ``eb`` as :func:`_accumulate_run`."""
    nch = len(tap_thr)
    zero = np.float32(0.0)
    lmax1 = lut.shape[1] - 2
    for ch in range(nch):
        lr = lut[ch]
        vr = lut_var[ch]
        for i in range(nbk):
            e = nch * i + ch
            v = xk[e]
            level = v * inv_max
            # v >= 0 (clamped interpolation): max() only tells the compiler so
            lo = min(max(int(v), 0), lmax1)
            frac = v - np.float32(lo)
            l0 = lr[lo]
            xv = lr[lo + 1] - l0
            xv = xv * frac
            xv = xv + l0
            q0 = vr[lo]
            var = vr[lo + 1] - q0
            var = var * frac
            var = var + q0
            if shot != zero:
                var = var + xv * shot
            var = var + const_var
            ev = xv * itk
            ok = okf[e]
            eb[e] = ev
            wk = (
                weight_by_code(wcode, level, xv, t2k, var)
                if wcode >= 0
                else wfn(level, xv, t2k, var)
            )
            wk = wk * (ok if level > floor_norm else zero)
            wbuf[e] = wk
            den[e] += wk
            var = var * wk
            sv[e] += var * it2
            wk = wk * ev
            num[e] += wk
            s2[e] += wk * ev


@_njit
def _accumulate_levels_table(
    src, choff, tk, lmax, has_lut, inv_max, itk, okf, ne, den, num, s2, sv, wbuf, eb
):
    """The sums of one frame of integer levels read in place through its per-level table
    ``tk (C L, 4)`` (:func:`hdrcore.merge.engine.level_tables`: ``E_k, w, w var(E_k)`` of
    every level, the kernel's arithmetic, the noise floor applied; channel ``ch``'s entry of
    level ``v`` at ``choff[e] + v``, ``choff[e] = ch L``): three loads and five adds a sample,
    ``w E_k`` and ``w E_k**2`` the table's float32 products of its own ``E_k`` (``ok`` is 0 or
    1, so weighting first is exact), bit for bit :func:`_accumulate_run`'s (the Gaussian
    weight's ``exp``: numpy's). Entries are one 16-byte line: an 8-bit frame's three channels
    take 12 KiB (24 KiB with the two products stored: 0.227 -> 0.195 CPU s for 6 MP x 3
    frames, ``bench_merge.py --kernel``).
    Without a LUT ``E_k`` is computed (levels past the table are clipped there, and the
    fallbacks need their value); with one, levels past it are counted (the caller refuses
    them). ``eb`` as :func:`_accumulate_run`."""
    bad = 0
    for e in range(ne):
        v = src[e]
        iv = np.int32(v)
        bad += np.int32(iv > lmax)
        li = min(iv, lmax) + choff[e]
        te = tk[li, 0]
        ea = (np.float32(v) * inv_max) * itk
        ev = te if has_lut else ea
        ok = okf[e]
        eb[e] = ev
        wk = tk[li, 1] * ok
        wbuf[e] = wk
        den[e] += wk
        sv[e] += tk[li, 2] * ok
        wk = wk * te
        num[e] += wk
        s2[e] += wk * te
    return bad if has_lut else 0


@_njit
def _taps_run(flat, iy0, b, e0, e1, ntap, wxe, wye, acc, xk, hi, tap_thr):
    """Interpolated values ``xk[e0:e1]`` of a run of pixels whose support starts at row
    ``iy0`` and element ``b + e`` of the frame's flattened rows (``(H, W * C)``, ``C =
    len(tap_thr)``: a tap's neighbour is ``C`` elements on). Zero-based slices keep the loops
    free of negative-index checks, so they vectorise."""
    nch = len(tap_thr)
    zero = np.float32(0.0)
    m = e1 - e0
    a = acc[e0:e1]
    s0 = b + e0
    if ntap == 4:
        wx0 = wxe[0, e0:e1]
        wx1 = wxe[1, e0:e1]
        wx2 = wxe[2, e0:e1]
        wx3 = wxe[3, e0:e1]
        # the 4 source rows in one pass (the same order of operations as row by row)
        ra = flat[iy0][s0 : s0 + m + 3 * nch]
        rb = flat[iy0 + 1][s0 : s0 + m + 3 * nch]
        rc = flat[iy0 + 2][s0 : s0 + m + 3 * nch]
        rd = flat[iy0 + 3][s0 : s0 + m + 3 * nch]
        wy0 = wye[0, e0:e1]
        wy1 = wye[1, e0:e1]
        wy2 = wye[2, e0:e1]
        wy3 = wye[3, e0:e1]
        for q in range(m):
            c0 = wx0[q]
            c1 = wx1[q]
            c2 = wx2[q]
            c3 = wx3[q]
            t = np.float32(ra[q]) * c0
            t = t + np.float32(ra[q + nch]) * c1
            t = t + np.float32(ra[q + 2 * nch]) * c2
            t = t + np.float32(ra[q + 3 * nch]) * c3
            acc_ = t * wy0[q]
            t = np.float32(rb[q]) * c0
            t = t + np.float32(rb[q + nch]) * c1
            t = t + np.float32(rb[q + 2 * nch]) * c2
            t = t + np.float32(rb[q + 3 * nch]) * c3
            acc_ = acc_ + t * wy1[q]
            t = np.float32(rc[q]) * c0
            t = t + np.float32(rc[q + nch]) * c1
            t = t + np.float32(rc[q + 2 * nch]) * c2
            t = t + np.float32(rc[q + 3 * nch]) * c3
            acc_ = acc_ + t * wy2[q]
            t = np.float32(rd[q]) * c0
            t = t + np.float32(rd[q + nch]) * c1
            t = t + np.float32(rd[q + 2 * nch]) * c2
            t = t + np.float32(rd[q + 3 * nch]) * c3
            a[q] = acc_ + t * wy3[q]
    else:
        wx0 = wxe[0, e0:e1]
        wx1 = wxe[1, e0:e1]
        wy0 = wye[0, e0:e1]
        wy1 = wye[1, e0:e1]
        r0 = flat[iy0]
        r1 = flat[iy0 + 1]
        t0 = r0[s0 : s0 + m]
        t1 = r0[s0 + nch : s0 + nch + m]
        u0 = r1[s0 : s0 + m]
        u1 = r1[s0 + nch : s0 + nch + m]
        for q in range(m):
            t = np.float32(t0[q]) * wx0[q] + np.float32(t1[q]) * wx1[q]
            u = np.float32(u0[q]) * wx0[q] + np.float32(u1[q]) * wx1[q]
            a[q] = t * wy0[q] + u * wy1[q]
    out = xk[e0:e1]
    for q in range(m):
        out[q] = min(max(a[q], zero), hi)


FEATHER_FLOOR = 1e-3
"""The least factor :func:`coverage_feather` gives a resampled frame inside its support: never
0, so a frame that is the only usable one at a pixel still decides it (the fallbacks see a
weight, as without the feather)."""


@_inline
def coverage_feather(sx, sy, xf, yf, o, wlim, hlim, feather):
    """The factor on a resampled frame's weight at output pixel ``(xf, yf)``, read at
    ``(sx, sy)`` of the frame: its distance inside the frame's support (``o .. wlim``,
    ``o .. hlim``) over ``min(feather, the pixel's own distance inside the output grid)``,
    clamped to ``[FEATHER_FLOOR, 1]``. Where a frame's edge crosses the image (hand-held
    frames cover different areas) its weight rises over ``feather`` px instead of stepping
    from 0 to full: a locally tone-mapped frame that is brighter than its neighbours there
    then leaves a smooth transition, not a band along the edge. A frame covering as far as
    the output grid (no motion at that edge) keeps its full weight. Float64, as the spec.
    Inlined where it is called (a call per pixel kept :func:`_warp_setup`'s loop scalar)."""
    dk = min(min(sx - o, wlim - sx), min(sy - o, hlim - sy))
    dout = min(min(xf - o, wlim - xf), min(yf - o, hlim - yf))
    span = min(feather, max(dout, 1.0))
    return min(max(dk / span, FEATHER_FLOOR), 1.0)


@_inline
def _field_node(xf, fgeo, gw):
    """The displacement field's node column left of output column ``xf`` (clamped to the
    field; :func:`_warp_setup`)."""
    fx = min(max((xf - fgeo[1]) * fgeo[0], 0.0), gw - 1.0)
    return min(int(fx), gw - 2)


@_inline
def _support_at(sx, sy, xhi, yhi, fo, wlim, hlim):
    """A mapped point and its support's floor: a point inside the frame whose support is not
    is sampled at the nearest position whose support fits (merge/spec.py border_clamp)."""
    fit = (sx >= -0.5) & (sx <= xhi) & (sy >= -0.5) & (sy <= yhi)
    sx = min(max(sx, fo), wlim) if fit else sx
    sy = min(max(sy, fo), hlim) if fit else sy
    return sx, sy, np.floor(sx), np.floor(sy)


@_njit
def _warp_setup(
    m00,
    m01,
    m02,
    m10,
    m11,
    m12,
    m20,
    m21,
    m22,
    x0,
    yf,
    nbk,
    ntap,
    o,
    wlim,
    hlim,
    wxp,
    wyp,
    ins,
    ixs,
    iys,
    same,
    fld,
    use_fld,
    fgeo,
    fea,
    feather,
    sxb,
    syb,
):
    """For pixels ``x0 .. x0 + nbk - 1`` of row ``yf`` mapped by the 3x3 matrix ``m`` (with
    the perspective divide; affine motions have ``m2 = (0, 0, 1)``): the
    weights ``wxp[j, i]``, ``wyp[j, i]`` of the ``ntap`` taps per axis (Keys cubic in float64,
    then float32; or bilinear ``float32(1 - f), float32(f)``), ``ins[i]``
    whether the support lies in the frame (top-left tap ``o`` before the floor, ``<= wlim``,
    ``<= hlim``), ``ixs``/``iys`` the support's top-left tap (clamped so that an outside
    pixel's unused index stays valid) and ``same[i]`` whether pixel ``i`` continues pixel
    ``i - 1``'s run: both inside, the same source rows and the next column. With ``use_fld``
    the displacement field ``fld (gh, gw, 2)`` (node ``(i, j)`` at output pixel ``origin +
    step (j, i)``; ``fgeo = (1 / step, origin_x, origin_y)``; constant beyond the outer
    nodes) is interpolated bilinearly at the output pixel and added to the mapped position
    (local refinement: :meth:`DisplacementField.at`). ``fea[i]``: the frame's coverage
    feather (:func:`coverage_feather`, 1 with ``feather`` 0). ``sxb``, ``syb`` (float64,
    ``nbk`` or more): scratch.

    One straight loop per step (positions, field, feather, tap weights, supports), each with
    no call and no branch on a loop-invariant inside, so each is SIMD code: 13.2 -> 4.0 ns a
    pixel (Keys, feather; 22.1 -> 7.4 with a field), the same values to the bit (one loop
    over everything was scalar: a per-pixel call of the feather and the tap-count branch)."""
    gh = fld.shape[0]
    gw = fld.shape[1]
    fy = min(max((yf - fgeo[2]) * fgeo[0], 0.0), gh - 1.0)
    gi = min(int(fy), gh - 2)
    gv = fy - gi
    for i in range(nbk):
        xf = np.float64(x0 + i)
        sw = m20 * xf + m21 * yf + m22
        sxb[i] = (m00 * xf + m01 * yf + m02) / sw
        syb[i] = (m10 * xf + m11 * yf + m12) / sw
    if use_fld:
        # runs of pixels between the same two node columns (the column grows with x), each
        # with its four nodes read once
        i = 0
        while i < nbk:
            gj = _field_node(np.float64(x0 + i), fgeo, gw)
            if gj >= gw - 2:
                e = nbk
            else:  # near where the column reaches gj + 1, then checked exactly
                e = min(max(int(np.ceil((gj + 1) / fgeo[0] + fgeo[1])) - x0, i + 1), nbk)
                while e > i + 1 and _field_node(np.float64(x0 + e - 1), fgeo, gw) != gj:
                    e -= 1
                while e < nbk and _field_node(np.float64(x0 + e), fgeo, gw) == gj:
                    e += 1
            a00 = fld[gi, gj, 0]
            a01 = fld[gi, gj + 1, 0]
            a10 = fld[gi + 1, gj, 0]
            a11 = fld[gi + 1, gj + 1, 0]
            b00 = fld[gi, gj, 1]
            b01 = fld[gi, gj + 1, 1]
            b10 = fld[gi + 1, gj, 1]
            b11 = fld[gi + 1, gj + 1, 1]
            for q in range(i, e):
                fx = min(max((np.float64(x0 + q) - fgeo[1]) * fgeo[0], 0.0), gw - 1.0)
                gu = fx - gj
                sxb[q] += (a00 * (1 - gu) + a01 * gu) * (1 - gv) + (a10 * (1 - gu) + a11 * gu) * gv
                syb[q] += (b00 * (1 - gu) + b01 * gu) * (1 - gv) + (b10 * (1 - gu) + b11 * gu) * gv
            i = e
    if feather > 0.0:
        for i in range(nbk):
            fea[i] = coverage_feather(
                sxb[i], syb[i], np.float64(x0 + i), yf, o, wlim, hlim, feather
            )
    else:
        fea[:nbk] = 1.0
    xhi = wlim + ntap - o - 0.5
    yhi = hlim + ntap - o - 0.5
    fo = np.float64(o)
    if ntap == 4:
        for i in range(nbk):
            sx, sy, fx0, fy0 = _support_at(sxb[i], syb[i], xhi, yhi, fo, wlim, hlim)
            wa, wb, wc, wd = _keys(sx - fx0)
            wxp[0, i] = wa
            wxp[1, i] = wb
            wxp[2, i] = wc
            wxp[3, i] = wd
            wa, wb, wc, wd = _keys(sy - fy0)
            wyp[0, i] = wa
            wyp[1, i] = wb
            wyp[2, i] = wc
            wyp[3, i] = wd
            sxb[i] = fx0
            syb[i] = fy0
    else:
        for i in range(nbk):
            sx, sy, fx0, fy0 = _support_at(sxb[i], syb[i], xhi, yhi, fo, wlim, hlim)
            fx = sx - fx0
            fy = sy - fy0
            wxp[0, i] = np.float32(1.0 - fx)
            wxp[1, i] = np.float32(fx)
            wyp[0, i] = np.float32(1.0 - fy)
            wyp[1, i] = np.float32(fy)
            sxb[i] = fx0
            syb[i] = fy0
    for i in range(nbk):
        fx0 = sxb[i]
        fy0 = syb[i]
        ins[i] = (fx0 >= o) & (fx0 <= wlim) & (fy0 >= o) & (fy0 <= hlim)
        ixs[i] = np.int32(min(max(fx0 - o, 0.0), wlim - o))
        iys[i] = np.int32(min(max(fy0 - o, 0.0), hlim - o))
    same[0] = False
    for i in range(1, nbk):
        same[i] = (ins[i] & ins[i - 1]) & (iys[i] == iys[i - 1]) & (ixs[i] == ixs[i - 1] + 1)


@_njit
def _expand(nt, nbk, src, dst, tap_thr):
    """``dst[j, C i + ch] = src[j, i]`` for the ``C = len(tap_thr)`` channels (the tap loops
    run over elements)."""
    nch = len(tap_thr)
    for j in range(nt):
        a = src[j]
        b = dst[j]
        for i in range(nbk):
            v = a[i]
            for ch in range(nch):
                b[nch * i + ch] = v


@_inline
def _any_clipped(r, e, tap_thr):
    """Whether a sample's channels ``r[e:e + C]`` hold one at or above its threshold
    (``tap_thr``, one per channel in the frame's dtype, :func:`tap_thresholds`); unrolled over
    the ``C = len(tap_thr)`` channels (a compile-time constant)."""
    c = r[e] >= tap_thr[0]
    for ch in range(1, len(tap_thr)):
        c = c | (r[e + ch] >= tap_thr[ch])
    return c


@_njit
def _clipped_supports(flat, iy0, c0, m, ntap, tap_thr, cf, out):
    """``out[q]`` (``q < m``): whether the ``ntap x ntap`` support with top-left tap
    ``(c0 + q, iy0)`` holds a sample at or above its threshold in any channel
    (:func:`_any_clipped`). A run's supports share their rows, so each column is tested once
    (``cf``) and each support ORs ``ntap`` columns: straight loops."""
    nch = len(tap_thr)
    ncol = m + ntap - 1
    for q in range(ncol):
        cf[q] = False
    for jy in range(ntap):
        row = flat[iy0 + jy]
        r = row[nch * c0 : nch * (c0 + ncol)]
        for q in range(ncol):
            cf[q] = cf[q] | _any_clipped(r, nch * q, tap_thr)
    if ntap == 4:
        for q in range(m):
            out[q] = (cf[q] | cf[q + 1]) | (cf[q + 2] | cf[q + 3])
    else:
        for q in range(m):
            out[q] = cf[q] | cf[q + 1]


@_njit
def merge_rows(fr, warp, model, wfn, fin, out, r0, r1):
    """Rows ``r0:r1`` of the output grid; the arguments are grouped (:class:`FusedFrames`,
    :class:`FusedWarp`, :class:`FusedModel`, :class:`FusedFinish`, :class:`FusedOutputs`;
    ``wfn`` the weighting's compiled scalar form, used when ``model.wcode < 0``). Frame ``k``
    with ``has_mat[k]`` is read at ``mats[k] @ (x, y, 1)`` (``ntap`` 4: Keys cubic, 4 weights
    per axis shared by the ``C`` channels; 2: bilinear), the others at ``(x, y)``; ``flats[k]``
    is frame ``k`` as ``(H, W * C)``, ``C = len(tap_thr)`` (a constant of each compiled
    specialisation). A resampled frame is clipped at a pixel when any of the taps of any channel
    is at or above its saturation level (``tap_thr``: :func:`tap_thresholds` in the frames'
    dtype, a tuple; :func:`_clipped_supports`), and invalid when the support leaves the frame
    (its values read 0 there). ``oor[k]``: frame ``k`` (resampled, with a LUT) holds levels past
    the LUT, so clipped supports are searched for them. Resampled integer levels with a LUT are
    interpolated, then read linearly between LUT entries; with ``use_tab`` the integer frames
    read in place go through the per-level tables ``tabs (N, C L, 4)``
    (:func:`_accumulate_levels_table`: frames with a LUT, and the Gaussian weight, whose ``exp``
    is then numpy's to the last bit); otherwise integer levels and float frames are
    linear (``level = value * inv_max``). With ``has_colour`` (3 channels) each finished block
    is converted
    to the working space (:func:`hdrcore.merge.colour.convert_pixels` with ``cm``, ``cwb``,
    ``cneu``) while it is in cache. Returns the number of samples above the LUT's last level
    (the caller refuses the input).
    """
    frames, flats, masks, has_mask = fr.frames, fr.flats, fr.masks, fr.has_mask
    order, inv_t, inv_t2, t2 = fr.order, fr.inv_t, fr.inv_t2, fr.t2
    mats, has_mat, ntap, oor = warp.mats, warp.has_mat, warp.ntap, warp.oor
    flds, has_fld, fgeo = warp.flds, warp.has_fld, warp.fgeo
    wcode, shot, const_var = model.wcode, model.shot, model.const_var
    floor_norm, inv_max, hi = model.floor_norm, model.inv_max, model.hi
    has_lut, lut, lut_var, tap_thr = model.has_lut, model.lut, model.lut_var, model.tap_thr
    use_tab, tabs = model.use_tab, model.tabs
    me2, thr = fin.me2, fin.thr
    has_colour, cm, cwb, cneu = fin.has_colour, fin.cm, fin.cwb, fin.cneu
    rad, wsum_out, shares, clip_count = out.rad, out.wsum, out.shares, out.clip_count
    clipped_out, under_out, gscore, ghost = out.clipped, out.under, out.gscore, out.ghost
    n = len(order)  # the tuples may be padded (TUPLE_SLOTS)
    # the channel count: a compile-time constant (the length of the thresholds' tuple), so
    # numba compiles one specialisation per count and the channel loops unroll
    nch = len(tap_thr)
    h = frames[0].shape[0]
    w = frames[0].shape[1]
    keep = out.maps
    prov = not keep
    if prov:  # the weight sum, the shares and the clip count in a scratch row (not kept)
        wsum_out = np.empty((1, w), np.float32)
        shares = np.empty((n, 1, w), np.uint16)
        clip_count = np.empty((1, w), np.uint8)
    bw = min(w, _WBLOCK)
    b3 = nch * bw + 48  # padded: buffers off 4 KiB multiples (cache-set aliasing)
    xk = np.empty(b3, np.float32)  # a resampled frame's interleaved values (levels or floats)
    den = np.empty(b3, np.float32)
    num = np.empty(b3, np.float32)
    s2 = np.empty(b3, np.float32)
    sv = np.empty(b3, np.float32)
    wbuf = np.empty(b3, np.float32)
    okf = np.empty(b3, np.float32)
    # E_k of every frame (row j: the j-th in exposure order): the fallback values, read for
    # the few pixels that need one
    eb = np.empty((n, b3), np.float32)
    acc = np.empty(b3, np.float32)
    wxe = np.empty((4, b3), np.float32)
    wye = np.empty((4, b3), np.float32)
    wxp = np.empty((4, bw), np.float32)  # per pixel, before _expand
    wyp = np.empty((4, bw), np.float32)
    ixs = np.empty(bw, np.int32)
    iys = np.empty(bw, np.int32)
    same = np.empty(bw, np.bool_)  # pixel i continues pixel i - 1's run
    ins = np.empty(bw, np.bool_)
    fea = np.ones(bw, np.float64)  # a resampled frame's coverage feather per pixel
    sxb = np.empty(bw, np.float64)  # _warp_setup's scratch
    syb = np.empty(bw, np.float64)
    share = np.empty((n, bw), np.float32)
    # int32 (not int64): the per-pixel loops then vectorise at the float32 width
    # positions in exposure order (j, not the frame index k): the darkest valid frame clipped
    # at the pixel (n: none), the brightest usable frame that gave the pixel weight (the
    # brightest usable one while none has; -1: none usable)
    fv = np.empty(bw, np.int32)
    lo = np.empty(bw, np.int32)
    seen = np.empty(bw, np.bool_)  # some frame so far gave the pixel weight
    okp = np.empty(bw, np.bool_)  # this frame is usable at the pixel
    nbad = np.empty(bw, np.int32)
    pick = np.empty(bw, np.int32)
    invw = np.empty(bw, np.float32)
    zflag = np.empty(bw, np.bool_)
    tc = np.empty(bw, np.bool_)
    ones = np.ones(bw, np.bool_)
    cf = np.empty(bw + 4, np.bool_)  # per source column of a run: any tap clipped
    bb = np.empty(b3, np.float32)
    cc = np.empty(b3, np.float32)
    radf = rad.reshape(h, w * nch)
    row_len = nch * w
    tab_len = tabs.shape[1] // nch  # levels a channel of the per-level tables
    tab_max = tab_len - 1
    choff = np.empty(b3, np.int32)  # element e's channel row in the flattened tables
    for e in range(b3):
        choff[e] = np.int32((e % nch) * tab_len)
    lmax = lut.shape[1] - 1
    out_of_range = 0
    zero = np.float32(0.0)
    one = np.float32(1.0)
    nb = (w + _WBLOCK - 1) // _WBLOCK
    nr = r1 - r0
    o = 1.0 if ntap == 4 else 0.0
    # rows outermost: with blocks of 2048 pixels this measured faster than column blocks
    # outermost (which kept a block's band of source rows in cache with blocks of 512)
    for yb in range(nr * nb):
        y = r0 + yb // nb
        ys = y if keep else 0  # the row of wsum_out, shares and clip_count
        yf = np.float64(y)
        x0 = (yb % nb) * _WBLOCK
        x1 = min(w, x0 + _WBLOCK)
        nbk = x1 - x0
        ne = nch * nbk
        den[:ne] = zero
        num[:ne] = zero
        s2[:ne] = zero
        sv[:ne] = zero
        nbad[:nbk] = 0
        fv[:nbk] = n
        lo[:nbk] = -1
        seen[:nbk] = False
        crow = clip_count[ys]
        crow[x0:x1] = 0
        for j in range(n):
            k = order[j]
            fr = frames[k]
            flat = flats[k]
            warped = has_mat[k]
            vrow = masks[k][y, x0:x1] if has_mask[k] else ones[:nbk]  # valid (mask)
            frf = flat[y, nch * x0 : nch * x1]  # the row block in place (zero-based: vectorises)
            if warped:
                m00 = mats[k, 0, 0]
                m01 = mats[k, 0, 1]
                m02 = mats[k, 0, 2]
                m10 = mats[k, 1, 0]
                m11 = mats[k, 1, 1]
                m12 = mats[k, 1, 2]
                _warp_setup(
                    m00,
                    m01,
                    m02,
                    m10,
                    m11,
                    m12,
                    mats[k, 2, 0],
                    mats[k, 2, 1],
                    mats[k, 2, 2],
                    x0,
                    yf,
                    nbk,
                    ntap,
                    o,
                    np.float64(w - (ntap - o)),
                    np.float64(h - (ntap - o)),
                    wxp,
                    wyp,
                    ins,
                    ixs,
                    iys,
                    same,
                    flds[k],
                    has_fld[k],
                    fgeo,
                    fea,
                    warp.feather,
                    sxb,
                    syb,
                )
                _expand(ntap, nbk, wxp, wxe, tap_thr)
                _expand(ntap, nbk, wyp, wye, tap_thr)
                # runs of pixels whose supports share their rows and column offset: the taps
                # and the clipped-support flags of a run are contiguous in the source rows
                i = 0
                while i < nbk:
                    if not ins[i]:
                        e = nch * i
                        for ch in range(nch):
                            xk[e + ch] = zero
                        tc[i] = False
                        i += 1
                        continue
                    s = i
                    iy0 = iys[i]
                    dx = ixs[i] - i
                    i += 1
                    while i < nbk and same[i]:
                        i += 1
                    # the run's elements rounded up to whole SIMD vectors (no scalar tail;
                    # the extra values are overwritten by the next run) where the source row
                    # is long enough
                    e1 = nch * s + ((nch * (i - s) + 15) & ~15)
                    if nch * dx + e1 + nch * ntap > row_len:
                        e1 = nch * i
                    _taps_run(
                        flat, iy0, nch * dx, nch * s, e1, ntap, wxe, wye, acc, xk, hi, tap_thr
                    )
                    _clipped_supports(flat, iy0, dx + s, i - s, ntap, tap_thr, cf, tc[s:i])
                if oor[k]:  # levels past the LUT are clipped: count them
                    for i in range(nbk):
                        if ins[i] and tc[i]:
                            for jy in range(ntap):
                                for jx in range(ntap):
                                    for ch in range(nch):
                                        if int(fr[iys[i] + jy, ixs[i] + jx, ch]) > lmax:
                                            out_of_range += 1
                for i in range(nbk):
                    ins[i] = ins[i] & vrow[i]
            else:
                # read in place (the sums convert); tap_thr: v >= th exactly when
                # float64(v) >= sat
                for i in range(nbk):
                    tc[i] = _any_clipped(frf, nch * i, tap_thr)
                    ins[i] = vrow[i]
            # tc: clipped, ins: valid; a frame is dropped where invalid or clipped
            cs = crow[x0:x1]
            for i in range(nbk):
                valid = ins[i]
                cl = tc[i] & valid
                b = (not valid) | cl
                cs[i] += np.uint8(cl)
                nbad[i] += np.int32(b)
                f = fv[i]
                fv[i] = np.int32(j) if (f == n) & cl else f
                okp[i] = not b
                okv = zero if b else (np.float32(fea[i]) if warped else one)
                e = nch * i
                for ch in range(nch):
                    okf[e + ch] = okv
            itk = inv_t[k]
            it2 = inv_t2[k]
            t2k = t2[k]
            ebj = eb[j]
            if has_lut and warped:
                _accumulate_lut_run(
                    xk,
                    okf,
                    nbk,
                    wcode,
                    wfn,
                    inv_max,
                    shot,
                    const_var,
                    floor_norm,
                    itk,
                    it2,
                    t2k,
                    lut,
                    lut_var,
                    den,
                    num,
                    s2,
                    sv,
                    wbuf,
                    ebj,
                    tap_thr,
                )
            elif use_tab and not warped:  # (a resampled frame's values are in xk)
                out_of_range += _accumulate_levels_table(
                    frf,
                    choff,
                    tabs[k],
                    tab_max,
                    has_lut,
                    inv_max,
                    itk,
                    okf,
                    ne,
                    den,
                    num,
                    s2,
                    sv,
                    wbuf,
                    ebj,
                )
            elif warped:
                _accumulate_run(
                    xk,
                    okf,
                    ne,
                    wcode,
                    wfn,
                    inv_max,
                    shot,
                    const_var,
                    floor_norm,
                    itk,
                    it2,
                    t2k,
                    den,
                    num,
                    s2,
                    sv,
                    wbuf,
                    ebj,
                )
            else:  # the frame's own dtype (a specialisation per dtype)
                _accumulate_run(
                    frf,
                    okf,
                    ne,
                    wcode,
                    wfn,
                    inv_max,
                    shot,
                    const_var,
                    floor_norm,
                    itk,
                    it2,
                    t2k,
                    den,
                    num,
                    s2,
                    sv,
                    wbuf,
                    ebj,
                )
            # the brightest usable frame that gave the pixel weight (a usable frame without
            # any, e.g. a black one, only while no frame has)
            jj = np.int32(j)
            for i in range(nbk):
                e = nch * i
                sh = wbuf[e]
                for ch in range(1, nch):
                    sh = sh + wbuf[e + ch]
                share[k, i] = sh
                sig = sh > zero
                sn = seen[i]
                upd = okp[i] & (sig | (not sn))
                seen[i] = sn | sig
                last = lo[i]
                lo[i] = jj if upd else last
        _finish_block(
            y,
            x0,
            x1,
            n,
            order,
            den,
            num,
            s2,
            sv,
            share,
            fv,
            lo,
            nbad,
            me2,
            thr,
            wsum_out,
            shares,
            clipped_out,
            under_out,
            gscore,
            ghost,
            pick,
            invw,
            zflag,
            radf,
            bb,
            cc,
            eb,
            tap_thr,
            ys,
            prov,
            out.prov_count,
            out.prov_units,
        )
        ro = radf[y, nch * x0 : nch * x1]
        if has_colour and nch == 3:  # (merge refuses a conversion of other channel counts)
            convert_pixels(ro, clipped_out[y, x0:x1], True, cm, cwb, cneu)
    return out_of_range
