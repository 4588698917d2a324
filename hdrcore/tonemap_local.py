"""A local tonemapping operator for high-contrast scenes: Durand & Dorsey's base/detail
decomposition on a bilateral grid.

The log luminance ``l = log2 L`` of the exposed radiance is split into a *base*, an
edge-preserving smoothing (large structures: the window, the room), and a *detail* ``l - base``
(texture). Only the base is compressed, around middle grey, so the window and the room both fit
the display while the texture of each keeps its contrast; colour ratios are kept (section 5.2
of [1]), tempered towards grey by ``saturation``:

    out = pivot + c (base - pivot) + detail_gain (l - base)
    RGB_out = 2**out * (1 + saturation (RGB / L - 1))

``c`` is the smallest compression that fits the 1st..99th percentiles of the base between
``shadow_stops`` below middle grey and display white: a scene that already fits is not
compressed. The base is the bilateral filter of ``l`` (spatial sigma about a 24th of the
image's longer side, range sigma ``range_sigma`` stops), computed on a bilateral grid [2]: the
luminance is splatted into a coarse 3-D grid (space x log luminance), blurred there, and each
pixel reads the grid back (trilinear) at its own position and luminance. Reading the grid at
the pixel's own luminance keeps the base from crossing strong edges (a window frame 6 stops
above the wall gets no halo), and the grid is small: :class:`LocalToneState` keeps it with the
compression, so a crop of the full-resolution radiance map renders exactly as the preview
around it (``tonemap(crop, ..., state=preview.state, offset=...)``: the inspector's loupe).

References
----------
.. [1] F. Durand, J. Dorsey, "Fast bilateral filtering for the display of high-dynamic-range
   images", ACM TOG 21(3) (SIGGRAPH 2002). doi:10.1145/566654.566574
.. [2] J. Chen, S. Paris, F. Durand, "Real-time edge-aware image processing with the bilateral
   grid", ACM TOG 26(3) (SIGGRAPH 2007). doi:10.1145/1276377.1276506
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ._numba import njit as _njit
from .errors import ParameterError

__all__ = [
    "LocalToneParams",
    "LocalToneState",
    "dynamic_range_stops",
    "local_tone_state",
    "render_durand_8bit",
    "tonemap_durand",
]

_PIVOT = float(np.log2(0.18))  # middle grey of the exposed radiance (Reinhard's key)
_TINY = 1e-12


@dataclass(frozen=True)
class LocalToneParams:
    """Parameters of :func:`tonemap_durand` (chosen by looking at the brackets of
    ``../shared/data``, see ``bench/bench_tonemap.py``)."""

    cells: int = 24
    """Grid cells along the longer side (the spatial sigma of the bilateral filter)."""
    range_sigma: float = 1.0
    """Range sigma of the bilateral filter, in stops: edges of more contrast keep the base
    from crossing them."""
    range_bin: float = 0.5
    """Grid bin along log luminance, in stops."""
    shadow_stops: float = 6.5
    """How far below middle grey the base's 1st percentile may be placed (display black is
    about 8 stops below white)."""
    highlight_stops: float = float(-np.log2(0.18)) - 0.15
    """How far above middle grey the base's 99th percentile may be placed (just below white)."""
    detail_gain: float = 1.1
    """Gain of the detail layer (1: the scene's own local contrast; a little more keeps the
    compressed image from looking flat)."""
    saturation: float = 0.9
    """Weight of the colour ratios against grey: ``RGB_out = L_out (1 + s (RGB / L - 1))``
    (1 keeps them; below 1 tempers the saturation that a strongly compressed base leaves in
    lifted shadows)."""

    def __post_init__(self) -> None:
        if int(self.cells) < 2:
            raise ParameterError("cells must be >= 2", found=str(self.cells))
        for name in (
            "range_sigma",
            "range_bin",
            "shadow_stops",
            "highlight_stops",
            "detail_gain",
            "saturation",
        ):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise ParameterError(f"local tonemap {name} must be positive", found=str(v))


@dataclass(frozen=True, eq=False)
class LocalToneState:
    """What a crop needs to render exactly as the image it came from: the blurred bilateral
    grid of the base (``grid``, float32 ``(nz, ny, nx)``: base log2 luminance per cell and
    level), its geometry (``cell``: cell side in pixels of the full-resolution map;
    ``l0``, ``bin``: log2 luminance of the first level and the level step), the compression
    ``c`` and the parameters."""

    grid: np.ndarray
    cell: float
    l0: float
    bin: float
    c: float
    params: LocalToneParams
    base_range: tuple[float, float]

    def to_json(self) -> dict:
        return {
            "operator": "durand (bilateral grid)",
            "compression": self.c,
            "base_range_stops": [float(v) for v in self.base_range],
            "grid": list(self.grid.shape),
            "cell_px": self.cell,
            "range_sigma": self.params.range_sigma,
            "detail_gain": self.params.detail_gain,
            "saturation": self.params.saturation,
        }


def _log_luminance(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    lum = np.multiply(x[..., 0], weights[0], dtype=np.float32)
    lum += x[..., 1] * weights[1]
    lum += x[..., 2] * weights[2]
    np.maximum(lum, _TINY, out=lum)
    return np.log2(lum)


def dynamic_range_stops(
    radiance: np.ndarray,
    weights: np.ndarray,
    *,
    low: float = 1.0,
    high: float = 99.0,
    max_samples: int = 1 << 20,
) -> float:
    """Stops between the ``low`` and ``high`` percentiles of the luminance of the pixels with
    positive, finite values (a regular subsample of at most ``max_samples`` pixels)."""
    rad = np.asarray(radiance)
    h, w = rad.shape[:2]
    step = max(1, int(np.ceil(np.sqrt(h * w / max(1, max_samples)))))
    sub = np.ascontiguousarray(rad[::step, ::step], dtype=np.float32)
    if sub.ndim == 2:
        sub = np.repeat(sub[..., None], 3, axis=-1)
    lum = sub[..., 0] * weights[0] + sub[..., 1] * weights[1] + sub[..., 2] * weights[2]
    lum = lum[np.isfinite(lum) & (lum > 0)]
    if lum.size < 2:
        return 0.0
    lo, hi = np.percentile(np.log2(lum), [low, high])
    return float(hi - lo)


@_njit
def _splat(rad, scale, wts, inv_cell, l0, inv_bin, sums, counts):  # pragma: no cover
    """Nearest-cell splat of the log2 luminance of ``rad * scale`` into the grid (sum and
    count per cell); non-finite and negative values count as black."""
    h, w = rad.shape[0], rad.shape[1]
    nz, ny, nx = sums.shape
    for y in range(h):
        gy = min(max(int((y + 0.5) * inv_cell + 0.5), 0), ny - 1)
        for x in range(w):
            lum = 0.0
            for ch in range(3):
                v = np.float64(rad[y, x, ch]) * scale
                if v > 0.0 and v < np.inf:
                    lum += v * wts[ch]
            lg = np.log2(max(lum, 1e-12))
            gx = min(max(int((x + 0.5) * inv_cell + 0.5), 0), nx - 1)
            gz = min(max(int((lg - l0) * inv_bin + 0.5), 0), nz - 1)
            sums[gz, gy, gx] += lg
            counts[gz, gy, gx] += 1.0


@_njit
def _slice(lg, ys, xs, inv_cell, l0, inv_bin, grid, out, r0, r1):  # pragma: no cover
    """Trilinear read of the grid at the pixels of rows ``r0:r1`` of ``lg`` (log2 luminance),
    row ``y`` at ``ys[y]``, column ``x`` at ``xs[x]`` (float64, in the pixels the grid's cells
    are ``1 / inv_cell`` of); ``out`` (float32 or float64) takes the base. The whole image reads
    at ``offset + arange``, :func:`local_tone_state` at its subsample's pixels. The readable
    specification is ``hdrcore/tonemap_spec.py`` (``slice_grid``), used only by the tests."""
    w = lg.shape[1]
    nz, ny, nx = grid.shape
    for y in range(r0, r1):
        fy = (ys[y] + 0.5) * inv_cell
        iy = min(max(int(np.floor(fy)), 0), ny - 2)
        ty = min(max(fy - iy, 0.0), 1.0)
        for x in range(w):
            fx = (xs[x] + 0.5) * inv_cell
            ix = min(max(int(np.floor(fx)), 0), nx - 2)
            tx = min(max(fx - ix, 0.0), 1.0)
            fz = (np.float64(lg[y, x]) - l0) * inv_bin
            iz = min(max(int(np.floor(fz)), 0), nz - 2)
            tz = min(max(fz - iz, 0.0), 1.0)
            acc = 0.0
            for dz in range(2):
                wz = tz if dz else 1.0 - tz
                for dy in range(2):
                    wy = ty if dy else 1.0 - ty
                    for dx in range(2):
                        wx = tx if dx else 1.0 - tx
                        acc += wz * wy * wx * grid[iz + dz, iy + dy, ix + dx]
            out[y, x] = acc


def _read_grid(
    lg: np.ndarray,
    ys: np.ndarray,
    xs: np.ndarray,
    inv_cell: float,
    l0: float,
    inv_bin: float,
    grid: np.ndarray,
    dtype: type = np.float32,
    workers: int | None = None,
) -> np.ndarray:
    """The base at the pixels ``lg`` (rows at ``ys``, columns at ``xs``) through :func:`_slice`
    on row blocks."""
    from ._threads import run_row_spans

    lgc = np.ascontiguousarray(lg)
    ysf = np.ascontiguousarray(ys, np.float64)
    xsf = np.ascontiguousarray(xs, np.float64)
    out: np.ndarray = np.empty(lgc.shape, dtype)
    run_row_spans(
        lgc.shape[0],
        workers,
        lambda r0, r1: _slice(lgc, ysf, xsf, inv_cell, l0, inv_bin, grid, out, r0, r1),
    )
    return out


@_njit
def _render_rows(
    rad, scale, wts, grid, y0, x0, inv_cell, l0, inv_bin, c, pivot, gain, sat, lut, dst, r0, r1
):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of the 8-bit sRGB rendering of ``rad * scale`` in one pass: luminance,
    its log, the base read from the grid, the compressed output, the colour ratios, the 16-bit
    sRGB table (the readable specification is :func:`tonemap_durand` then
    ``srgb_encode_8bit``, within one code: that works in float32)."""
    w = rad.shape[1]
    nz, ny, nx = grid.shape
    top = lut.shape[0] - 1
    v = np.zeros(3)
    for y in range(r0, r1):
        fy = (y0 + y + 0.5) * inv_cell
        iy = min(max(int(np.floor(fy)), 0), ny - 2)
        ty = min(max(fy - iy, 0.0), 1.0)
        for xx in range(w):
            lum = 0.0
            for ch in range(3):
                a = np.float64(rad[y, xx, ch]) * scale
                if not (a > 0.0 and a < np.inf):
                    a = 0.0
                v[ch] = a
                lum += a * wts[ch]
            lum = max(lum, 1e-12)
            lg = np.log2(lum)
            fx = (x0 + xx + 0.5) * inv_cell
            ix = min(max(int(np.floor(fx)), 0), nx - 2)
            tx = min(max(fx - ix, 0.0), 1.0)
            fz = (lg - l0) * inv_bin
            iz = min(max(int(np.floor(fz)), 0), nz - 2)
            tz = min(max(fz - iz, 0.0), 1.0)
            base = 0.0
            for dz in range(2):
                wz = tz if dz else 1.0 - tz
                for dy in range(2):
                    wy = ty if dy else 1.0 - ty
                    for dx in range(2):
                        wx = tx if dx else 1.0 - tx
                        base += wz * wy * wx * grid[iz + dz, iy + dy, ix + dx]
            out = 2.0 ** (pivot + c * (base - pivot) + gain * (lg - base))
            for ch in range(3):
                q = (1.0 + sat * (v[ch] / lum - 1.0)) * out
                q = min(max(q, 0.0), 1.0)
                dst[y, xx, ch] = lut[int(q * top + 0.5)]


def _deprecated_engine(engine: str, where: str) -> None:
    """``engine=`` of the local operator: ``"numba"`` is the only engine; ``"numpy"`` is a
    deprecated alias of it for one release (issue 17)."""
    if engine == "numpy":
        warnings.warn(
            f"{where}(engine='numpy') is deprecated: the numpy engine is gone, the compiled "
            "kernel runs (the engine= parameter goes in the next release)",
            DeprecationWarning,
            stacklevel=3,
        )
    elif engine != "numba":
        raise ParameterError("tonemap engine must be 'numba' or 'numpy'", found=str(engine))


def local_tone_state(
    rad: np.ndarray,
    weights: np.ndarray,
    *,
    scale: float = 1.0,
    pixel_size: float = 1.0,
    params: LocalToneParams | None = None,
) -> LocalToneState:
    """The bilateral grid of the log2 luminance of ``rad * scale`` (one image ``(H, W, 3)``,
    pixels of ``pixel_size`` full-resolution pixels) and the compression it calls for."""
    from scipy import ndimage

    p = params or LocalToneParams()
    h, w = rad.shape[:2]
    cell_px = max(2.0, max(h, w) / float(p.cells))  # in the pixels of ``rad``
    cell = cell_px * float(pixel_size)
    step = max(1, int(np.sqrt(h * w / 2.0e5)))  # statistics on a regular subsample
    sub = np.asarray(rad[step // 2 :: step, step // 2 :: step], np.float32) * np.float32(scale)
    sub = np.where(np.isfinite(sub) & (sub > 0), sub, 0.0).astype(np.float32)
    lg_sub = _log_luminance(sub, weights)
    lo = float(np.percentile(lg_sub, 0.01))
    bin_ = float(p.range_bin)
    l0 = lo - 2 * bin_
    nz = int(np.ceil((float(lg_sub.max()) + 4 * bin_ - l0) / bin_)) + 1
    ny = int(np.ceil(h / cell_px)) + 2
    nx = int(np.ceil(w / cell_px)) + 2
    sums = np.zeros((nz, ny, nx))
    counts = np.zeros((nz, ny, nx))
    wts = np.asarray(weights, np.float64)
    _splat(
        np.ascontiguousarray(rad),
        float(scale),
        wts,
        1.0 / cell_px,
        l0,
        1.0 / bin_,
        sums,
        counts,
    )
    sig = (float(p.range_sigma) / bin_, 1.0, 1.0)
    bs = ndimage.gaussian_filter(sums, sig, mode="constant", truncate=3.0)
    bc = ndimage.gaussian_filter(counts, sig, mode="constant", truncate=3.0)
    # the grid's levels where nothing lies hold the level itself: a pixel reading them (a
    # crop, a value between the splatted ones) is its own base
    levels = (l0 + np.arange(nz) * bin_)[:, None, None]
    weight = bc / (bc + 1e-3)
    grid = np.where(bc > 0, bs / np.maximum(bc, 1e-300), levels)
    grid = (weight * grid + (1 - weight) * levels).astype(np.float32)
    ys = np.arange(step // 2, h, step)
    xs = np.arange(step // 2, w, step)
    base = _read_grid(lg_sub, ys, xs, 1.0 / cell_px, l0, 1.0 / bin_, grid, np.float64)
    b1, b99 = (float(v) for v in np.percentile(base, [1.0, 99.0]))
    c = 1.0
    if b99 > _PIVOT:
        c = min(c, float(p.highlight_stops) / (b99 - _PIVOT))
    if b1 < _PIVOT:
        c = min(c, float(p.shadow_stops) / (_PIVOT - b1))
    return LocalToneState(
        grid=np.ascontiguousarray(grid),
        cell=float(cell),
        l0=float(l0),
        bin=bin_,
        c=float(c),
        params=p,
        base_range=(b1, b99),
    )


def render_durand_8bit(
    rad: np.ndarray,
    weights: np.ndarray,
    lut: np.ndarray,
    *,
    scale: float = 1.0,
    state: LocalToneState | None = None,
    offset: tuple[float, float] = (0.0, 0.0),
    pixel_size: float = 1.0,
    params: LocalToneParams | None = None,
    workers: int | None = None,
) -> tuple[np.ndarray, LocalToneState]:
    """8-bit sRGB codes (through the 16-bit table ``lut``) of :func:`tonemap_durand` of
    ``rad * scale`` in one compiled pass (numba required), and the state."""
    from ._threads import run_row_spans

    src = np.ascontiguousarray(rad)
    if state is None:
        state = local_tone_state(src, weights, scale=scale, pixel_size=pixel_size, params=params)
        off = (0.0, 0.0)
    else:
        off = (offset[0] / float(pixel_size), offset[1] / float(pixel_size))
    p = state.params
    dst = np.empty(src.shape[:2] + (3,), np.uint8)
    wts = np.asarray(weights, np.float64)
    inv_cell = float(pixel_size) / state.cell
    run_row_spans(
        src.shape[0],
        workers,
        lambda r0, r1: _render_rows(
            src,
            float(scale),
            wts,
            state.grid,
            float(off[0]),
            float(off[1]),
            inv_cell,
            state.l0,
            1.0 / state.bin,
            state.c,
            _PIVOT,
            float(p.detail_gain),
            float(p.saturation),
            lut,
            dst,
            r0,
            r1,
        ),
    )
    return dst, state


def tonemap_durand(
    x: np.ndarray,
    weights: np.ndarray,
    *,
    state: LocalToneState | None = None,
    offset: tuple[float, float] = (0.0, 0.0),
    pixel_size: float = 1.0,
    params: LocalToneParams | None = None,
    engine: str | None = None,
) -> tuple[np.ndarray, LocalToneState]:
    """Display-linear values in [0, 1] (float32 ``(H, W, 3)``) of exposed radiance ``x``
    (already scaled so middle grey is 0.18), and the state that rendered them.

    ``weights``: the luminance weights. With ``state`` (from an earlier call) the image is a
    crop at ``offset`` (rows, columns in full-resolution pixels) of the image that made it, and
    ``pixel_size`` the size of its pixels in full-resolution pixels.

    The float form of the operator, in float32 numpy but for the grid read (compiled,
    :func:`_slice`): :func:`hdrcore.tonemap.tonemap` does not call it (it renders through the
    compiled :func:`render_durand_8bit`); it is the readable specification the tests hold that
    pass to (within one 8-bit code). ``engine``: deprecated, ignored (``"numpy"`` warns); the
    grid is always read by the compiled kernel.
    """
    if engine is not None:
        _deprecated_engine(engine, "tonemap_durand")
    x = np.where(np.isfinite(x) & (x > 0), x, 0.0).astype(np.float32)
    lg = _log_luminance(x, weights)
    bad = ~np.isfinite(lg)
    if bad.any():
        lg[bad] = np.log2(_TINY)
    if state is None:
        state = local_tone_state(x, weights, pixel_size=pixel_size, params=params)
        off = (0.0, 0.0)
    else:
        off = (offset[0] / float(pixel_size), offset[1] / float(pixel_size))
    p = state.params
    cell_px = state.cell / float(pixel_size)
    h, w = lg.shape
    base = _read_grid(
        lg,
        off[0] + np.arange(h),
        off[1] + np.arange(w),
        1.0 / cell_px,
        state.l0,
        1.0 / state.bin,
        state.grid,
    )
    out_l = _PIVOT + state.c * (base - _PIVOT) + float(p.detail_gain) * (lg - base)
    y = np.maximum(x, 0.0, dtype=np.float32) / np.exp2(lg)[..., None]  # colour ratios
    y -= 1.0
    y *= np.float32(p.saturation)  # towards grey (the luminance) below 1
    y += 1.0
    y *= np.exp2(out_l)[..., None]
    y[bad] = 0.0
    np.clip(y, 0.0, 1.0, out=y)
    return y.astype(np.float32, copy=False), state
