"""Tonemapped 8-bit previews of radiance maps: exposure, an operator, sRGB encoding.

1. Exposure: the radiance is scaled so that its log-average luminance (Reinhard et al. 2002,
   eq. 1) maps to ``key`` (0.18, "middle grey"; eq. 2), then by ``2**exposure`` stops; with
   ``auto_exposure=False`` only ``2**exposure`` applies.
2. An operator from :data:`TONEMAP_OPERATORS` maps the scaled values to display-linear
   [0, 1]: the global ``"linear"`` (clip), ``"reinhard"`` (Reinhard et al. 2002, eq. 4 on
   luminance, colour ratios kept) or ``"reinhard-rgb"`` (eq. 4 per channel, highlights
   desaturate to white); the local ``"durand"`` (Durand & Dorsey 2002 on a bilateral grid,
   :mod:`hdrcore.tonemap_local`: the window and the room both keep their detail); or
   ``"auto"``: ``"durand"`` when the scene's dynamic range (1st to 99th percentile of the
   luminance) exceeds :data:`AUTO_LOCAL_STOPS`, else ``"reinhard"``. The result says which
   operator ran and why.
3. sRGB encoding (IEC 61966-2-1) through colour-science's ``cctf_encoding``, applied as a 16-bit
   lookup table so a 24-megapixel preview costs a fraction of a second, then 8-bit quantisation.

colour-science has no tonemapping operators (they live in the separate colour-hdri package), so
the operators are written here; the transfer function and the Rec.709 luminance weights come from
colour-science.

Reference: E. Reinhard, M. Stark, P. Shirley, J. Ferwerda, "Photographic tone reproduction for
digital images", ACM Transactions on Graphics 21(3), 2002, eqs. 1, 2 and 4.
doi:10.1145/566654.566575
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from ._colour_cache import cache_file, cached_arrays
from ._threads import run_row_spans
from .errors import ParameterError, validate_method

__all__ = [
    "AUTO_LOCAL_STOPS",
    "TONEMAP_OPERATORS",
    "TonemapResult",
    "tonemap",
    "log_average_luminance",
    "srgb_encode_8bit",
    "tonemap_linear",
    "tonemap_reinhard",
    "tonemap_reinhard_rgb",
]

_LUT_SIZE = 1 << 16
_DELTA = 1e-6  # Reinhard's delta in eq. 1, avoids log(0) on black pixels


def _cache_file() -> str | None:
    """Where colour-science's constants for the preview are kept between processes
    (:mod:`hdrcore._colour_cache`: the user's cache folder, one file per colour-science
    version; ``None`` if unknown)."""
    return cache_file(_CONSTANTS)


_CONSTANTS = f"preview-srgb-{_LUT_SIZE}"


def _compute_constants() -> dict[str, np.ndarray]:
    import colour  # imported lazily: importing colour-science is slow

    m = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ, dtype=np.float64)
    x = np.linspace(0.0, 1.0, _LUT_SIZE)
    v = np.asarray(colour.cctf_encoding(x, function="sRGB"), dtype=np.float64)
    return {
        "luminance": m[1].astype(np.float32),
        "srgb": np.clip(np.rint(v * 255.0), 0, 255).astype(np.uint8),
    }


def _constants_valid(a: dict[str, np.ndarray]) -> bool:
    y, lut = a.get("luminance"), a.get("srgb")
    return (
        y is not None
        and lut is not None
        and y.shape == (3,)
        and y.dtype == np.float32
        and lut.shape == (_LUT_SIZE,)
        and lut.dtype == np.uint8
    )


def _colour_constants() -> tuple[np.ndarray, np.ndarray]:
    """``(luminance weights, sRGB 16-bit -> 8-bit table)`` from colour-science.

    Both are computed by colour-science (the Y row of its sRGB RGB -> XYZ matrix, and its sRGB
    ``cctf_encoding`` sampled at 65536 points) and kept in the user's cache folder, keyed by the
    colour-science version (:func:`hdrcore._colour_cache.cached_arrays`): importing
    colour-science is slow, and a command that only writes a preview would pay for it on every
    run.
    """
    a = cached_arrays(_CONSTANTS, _compute_constants, _constants_valid)
    return a["luminance"], a["srgb"]


def _luminance_weights() -> np.ndarray:
    """Rec.709 / sRGB luminance weights (the Y row of colour-science's RGB -> XYZ matrix)."""
    return _colour_constants()[0]


def _luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luminance of ``(..., 3)`` values (a copy of the channel for ``(..., 1)``)."""
    if rgb.shape[-1] == 1:
        return rgb[..., 0].astype(np.float32)
    y = _luminance_weights()
    out = np.multiply(rgb[..., 0], y[0], dtype=np.float32)
    out += rgb[..., 1] * y[1]
    out += rgb[..., 2] * y[2]
    return out


def tonemap_linear(x: np.ndarray, *, white: float | None = None) -> np.ndarray:
    """Clip exposed values to [0, 1] (in place)."""
    np.clip(x, 0.0, 1.0, out=x)
    return x


def tonemap_reinhard(x: np.ndarray, *, white: float | None = None) -> np.ndarray:
    """Reinhard et al. (2002) eq. 4 on luminance ``L``: ``L (1 + L / Lw**2) / (1 + L)``.

    The RGB values are scaled by ``Ld / L`` so hues and saturation are kept; ``white`` (``Lw``)
    is the smallest luminance mapped to white (``None``: infinity, eq. 3). In place.
    """
    lum = _luminance(x)
    np.maximum(lum, 1e-12, out=lum)
    ld = lum / (1.0 + lum)
    if white is not None:
        ld *= 1.0 + lum / np.float32(white) ** 2
    ld /= lum
    x *= ld[..., None]
    np.clip(x, 0.0, 1.0, out=x)
    return x


def tonemap_reinhard_rgb(x: np.ndarray, *, white: float | None = None) -> np.ndarray:
    """Reinhard et al. (2002) eq. 4 on each channel (bright colours go to white). In place."""
    np.maximum(x, 0.0, out=x)
    d = 1.0 + x
    if white is not None:
        x *= 1.0 + x / np.float32(white) ** 2
    x /= d
    np.clip(x, 0.0, 1.0, out=x)
    return x


def tonemap_durand(x: np.ndarray, *, white: float | None = None, **kw) -> np.ndarray:
    """Durand & Dorsey's local operator on a bilateral grid on a whole exposed image ``(H, W,
    3)`` (:func:`hdrcore.tonemap_local.tonemap_durand`; ``white`` does not apply)."""
    from .tonemap_local import tonemap_durand as local

    return local(x, _luminance_weights(), **kw)[0]


def tonemap_auto(x: np.ndarray, *, white: float | None = None) -> np.ndarray:
    """``"durand"`` for scenes of more than :data:`AUTO_LOCAL_STOPS`, else ``"reinhard"``
    (see :func:`tonemap`, which decides on the whole radiance map)."""
    raise ParameterError("'auto' chooses an operator for a whole image: call tonemap()")


TONEMAP_OPERATORS: dict[str, Callable[..., np.ndarray]] = {
    "auto": tonemap_auto,
    "durand": tonemap_durand,
    "linear": tonemap_linear,
    "reinhard": tonemap_reinhard,
    "reinhard-rgb": tonemap_reinhard_rgb,
}
"""Operators by name: exposed radiance (float32) -> display-linear [0, 1]. The global ones
work on chunks of pixels in place; ``"durand"`` needs the whole image; ``"auto"`` picks."""

LOCAL_OPERATORS = ("durand",)
"""Operators that need the whole image (and can hand a crop their state)."""

AUTO_LOCAL_STOPS = 8.0
"""``"auto"`` tonemaps a scene with a local operator when its luminance spans more than this
many stops between the 1st and 99th percentiles (``bench/bench_tonemap.py``: the frobisher
window-and-room bracket spans 11.5, the memorial church 9.9, the phone brackets 6.8-7.5; a
global curve keeps 8 stops of scene in the 5-95 % of the display)."""

AUTO_GLOBAL = "reinhard"
AUTO_LOCAL = "durand"


def _srgb_lut() -> np.ndarray:
    """colour-science's sRGB encoding at 65536 points, as 8-bit codes."""
    return _colour_constants()[1]


def srgb_encode_8bit(x: np.ndarray) -> np.ndarray:
    """uint8 sRGB codes of display-linear values (clipped to [0, 1]).

    The transfer function is colour-science's ``cctf_encoding(..., function="sRGB")`` sampled at
    65536 points (the linear input is quantised to 16 bits, finer than one 8-bit code).
    """
    a = np.asarray(x, dtype=np.float32)
    idx = np.multiply(a, np.float32(_LUT_SIZE - 1), dtype=np.float32)
    np.clip(idx, 0.0, float(_LUT_SIZE - 1), out=idx)
    idx += 0.5
    return _srgb_lut()[idx.astype(np.uint16)]


_OPERATOR_CODES = {"linear": 0, "reinhard": 1, "reinhard-rgb": 2}


@numba.njit(nogil=True, cache=True, fastmath=False)
def _tonemap_rows(src, scale, code, has_white, w2, y, lut, dst, r0, r1):  # pragma: no cover
    """:func:`tonemap` of the built-in global operators for rows ``r0:r1`` in one pass:
    scale, non-finite -> 0, operator, 16-bit LUT encoding, the float32 operations of the
    operator functions (:func:`tonemap_linear`, :func:`tonemap_reinhard`,
    :func:`tonemap_reinhard_rgb`, their readable specification) in the same order: the
    tests hold the two to the bit (``hdrcore/tonemap_spec.py``)."""
    w = src.shape[1]
    c = src.shape[2]
    one = np.float32(1.0)
    zero = np.float32(0.0)
    top = np.float32(_LUT_SIZE - 1)
    half = np.float32(0.5)
    v = np.empty(3, np.float32)
    for r in range(r0, r1):
        for x in range(w):
            for ch in range(3):
                a = np.float32(src[r, x, ch if c == 3 else 0]) * scale
                if not np.isfinite(a):
                    a = zero
                v[ch] = a
            if code == 1:
                lum = v[0] * y[0]
                lum = lum + v[1] * y[1]
                lum = lum + v[2] * y[2]
                if not (lum >= np.float32(1e-12)):
                    lum = np.float32(1e-12)
                ld = lum / (one + lum)
                if has_white:
                    ld = ld * (one + lum / w2)
                ld = ld / lum
                for ch in range(3):
                    v[ch] = v[ch] * ld
            elif code == 2:
                for ch in range(3):
                    a = v[ch]
                    if a < zero:
                        a = zero
                    d = one + a
                    if has_white:
                        a = a * (one + a / w2)
                    v[ch] = a / d
            for ch in range(3):
                a = v[ch]
                a = min(max(a, zero), one)
                a = a * top
                a = min(max(a, zero), top)
                a = a + half
                dst[r, x, ch] = lut[np.uint16(a)]


def log_average_luminance(radiance: np.ndarray, *, max_samples: int = 1 << 20) -> float:
    """Reinhard et al. (2002) eq. 1: ``exp(mean(log(delta + L)))`` over (a regular subsample of)
    the pixels with finite values."""
    rad = np.asarray(radiance)
    h, w = rad.shape[:2]
    step = max(1, int(np.ceil(np.sqrt(h * w / max(1, max_samples)))))
    sub = np.ascontiguousarray(rad[::step, ::step], dtype=np.float32)
    lum = _luminance(sub).ravel()
    lum = lum[np.isfinite(lum)]
    if lum.size == 0:
        return 1.0
    np.maximum(lum, 0.0, out=lum)
    return float(np.exp(np.mean(np.log(_DELTA + lum.astype(np.float64)))))


def _tonemap_numba(
    rad: np.ndarray, method: str, scale: float, white: float | None, workers: int | None
) -> np.ndarray:
    h, w, _ = rad.shape
    src = rad if rad.flags.c_contiguous else np.ascontiguousarray(rad)
    if src.dtype not in (np.float32, np.float64):
        src = src.astype(np.float32)
    dst = np.empty((h, w, 3), np.uint8)
    w2 = np.float32(1.0) if white is None else np.float32(white) ** 2
    y = _luminance_weights()
    lut = _srgb_lut()

    def work(r0: int, r1: int) -> None:
        _tonemap_rows(
            src,
            np.float32(scale),
            _OPERATOR_CODES[method],
            white is not None,
            w2,
            y,
            lut,
            dst,
            r0,
            r1,
        )

    run_row_spans(h, workers, work)
    return dst


def tonemap_chunks(
    rad: np.ndarray,
    op: Callable[..., np.ndarray],
    scale: float,
    white: float | None,
    chunk_pixels: int = 1 << 18,
) -> np.ndarray:
    """8-bit sRGB codes of a global operator ``op`` (float32, in place on ``(N, 3)`` pixels) on
    ``rad * scale`` ``(H, W, 1 or 3)``, non-finite values black, on chunks of ``chunk_pixels``:
    :func:`tonemap`'s path for operators added to :data:`TONEMAP_OPERATORS` (the built-in ones
    run compiled, :func:`_tonemap_rows`; the tests hold it to this path with their operator
    functions, ``hdrcore/tonemap_spec.py``)."""
    h, w, c = rad.shape
    flat = rad.reshape(h * w, c)
    out = np.empty((h * w, 3), np.uint8)
    step = max(1, int(chunk_pixels))
    for i in range(0, h * w, step):
        x = np.multiply(flat[i : i + step], np.float32(scale), dtype=np.float32)
        np.nan_to_num(x, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        if c == 1:
            x = np.repeat(x, 3, axis=1)
        op(x, white=white)
        out[i : i + step] = srgb_encode_8bit(x)
    return out.reshape(h, w, 3)


@dataclass(frozen=True, eq=False)
class TonemapResult:
    """An 8-bit sRGB preview and how it was made.

    ``image`` is uint8 ``(H, W, 3)``; ``scale`` the factor applied to the radiance before the
    operator (``key / log_average * 2**exposure``, or ``2**exposure``). ``method`` is the
    operator that ran, ``requested`` the one asked for (``"auto"``), ``dynamic_range`` the
    scene's stops between the 1st and 99th percentiles of luminance when ``"auto"`` measured
    them and ``reason`` its choice in words; ``state`` a local operator's
    :class:`~hdrcore.tonemap_local.LocalToneState` (pass it back with a crop of the same map:
    the crop renders as here).
    """

    image: np.ndarray
    method: str
    exposure: float
    key: float
    auto_exposure: bool
    log_average: float
    scale: float
    white: float | None
    timings: dict[str, float] = field(default_factory=dict)
    requested: str | None = None
    dynamic_range: float | None = None
    reason: str = ""
    state: Any = None

    def to_json(self) -> dict:
        return {
            "method": self.method,
            "requested": self.requested or self.method,
            "dynamic_range_stops": self.dynamic_range,
            "reason": self.reason,
            "local": None if self.state is None else self.state.to_json(),
            "exposure": self.exposure,
            "key": self.key,
            "auto_exposure": self.auto_exposure,
            "log_average": self.log_average,
            "scale": self.scale,
            "white": self.white,
            "shape": list(self.image.shape),
            "timings": dict(self.timings),
        }


def tonemap(
    radiance: np.ndarray,
    method: str = "reinhard",
    *,
    exposure: float = 0.0,
    key: float = 0.18,
    auto_exposure: bool = True,
    white: float | None = None,
    chunk_pixels: int = 1 << 18,
    engine: str | None = None,
    workers: int | None = None,
    state: Any = None,
    offset: tuple[float, float] = (0.0, 0.0),
    pixel_size: float = 1.0,
    local_params: Any = None,
) -> TonemapResult:
    """Tonemap a linear radiance map ``(H, W, 3)`` (or ``(H, W)``) to an 8-bit sRGB preview.

    ``exposure`` is in stops; ``white`` is in exposed units (after the scaling) for the Reinhard
    operators. Non-finite values are shown as black. The built-in operators run as one compiled
    pass over row blocks on ``workers`` threads (default up to 2); operators added to
    :data:`TONEMAP_OPERATORS` run on chunks of ``chunk_pixels``. ``engine``: deprecated, for one
    release: ``"numba"`` or ``None`` as before, ``"numpy"`` warns (DeprecationWarning) and the
    compiled pass runs (the numpy engine is gone, issue 17).

    Local operators (``"durand"``, or ``"auto"`` choosing it) work on the whole image:
    ``pixel_size`` is the size of its pixels in full-resolution pixels (a preview made at a
    quarter of the size: 4); ``state`` (a result's ``state``) with ``offset`` (rows, columns in
    full-resolution pixels) renders a crop of the same map as the image that made the state;
    ``local_params`` a :class:`~hdrcore.tonemap_local.LocalToneParams`.
    """
    t0 = time.perf_counter()
    key_m = validate_method(method, TONEMAP_OPERATORS, "tonemap")
    rad = np.asarray(radiance)
    if rad.ndim == 2:
        rad = rad[..., None]
    if rad.ndim != 3 or rad.shape[2] not in (1, 3):
        raise ParameterError("radiance must be (H, W, 3) or (H, W)", found=str(np.shape(radiance)))
    if rad.shape[0] == 0 or rad.shape[1] == 0:
        raise ParameterError("radiance is empty", found=str(rad.shape))
    if not np.isfinite(exposure):
        raise ParameterError("exposure must be finite (stops)", found=str(exposure))
    if not np.isfinite(key) or key <= 0:
        raise ParameterError("key must be positive", found=str(key))
    if white is not None and (not np.isfinite(white) or white <= 0):
        raise ParameterError("white must be positive or None", found=str(white))
    if engine is not None and engine not in ("numba", "numpy"):
        raise ParameterError("tonemap engine must be 'numba' or 'numpy'", found=str(engine))
    if engine == "numpy":
        warnings.warn(
            "tonemap(engine='numpy') is deprecated: the numpy engine is gone, the compiled "
            "pass runs (the engine= parameter goes in the next release)",
            DeprecationWarning,
            stacklevel=2,
        )
    if not np.isfinite(pixel_size) or pixel_size <= 0:
        raise ParameterError("pixel_size must be positive", found=str(pixel_size))

    log_avg = log_average_luminance(rad) if auto_exposure else 1.0
    scale = float(2.0**exposure) * (key / log_avg if auto_exposure else 1.0)
    requested, dr, reason = key_m, None, ""
    if key_m == "auto":
        if state is not None:
            key_m = AUTO_LOCAL  # a crop of an image a local operator rendered
            reason = "a crop rendered with its image's local state"
        else:
            from .tonemap_local import dynamic_range_stops

            dr = dynamic_range_stops(rad, _luminance_weights())
            key_m = AUTO_LOCAL if dr > AUTO_LOCAL_STOPS else AUTO_GLOBAL
            reason = (
                f"the scene spans {dr:.1f} stops (1st-99th percentile of luminance), "
                f"{'more' if key_m == AUTO_LOCAL else 'not more'} than "
                f"{AUTO_LOCAL_STOPS:g}: {key_m}"
            )
    t1 = time.perf_counter()
    h, w, c = rad.shape
    if key_m in LOCAL_OPERATORS:
        from .tonemap_local import render_durand_8bit

        if c == 1:
            rad = np.repeat(rad, 3, axis=2)
        image, st = render_durand_8bit(
            rad,
            _luminance_weights(),
            _srgb_lut(),
            scale=scale,
            state=state,
            offset=offset,
            pixel_size=pixel_size,
            params=local_params,
            workers=workers,
        )
        t2 = time.perf_counter()
        return TonemapResult(
            image=image,
            method=key_m,
            exposure=float(exposure),
            key=float(key),
            auto_exposure=bool(auto_exposure),
            log_average=float(log_avg),
            scale=scale,
            white=None if white is None else float(white),
            timings={"statistics": t1 - t0, "map": t2 - t1, "total": t2 - t0},
            requested=requested,
            dynamic_range=dr,
            reason=reason,
            state=st,
        )
    if key_m in _OPERATOR_CODES:
        image = _tonemap_numba(rad, key_m, scale, white, workers)
        t2 = time.perf_counter()
        return TonemapResult(
            image=image,
            method=key_m,
            exposure=float(exposure),
            key=float(key),
            auto_exposure=bool(auto_exposure),
            log_average=float(log_avg),
            scale=scale,
            white=None if white is None else float(white),
            timings={"statistics": t1 - t0, "map": t2 - t1, "total": t2 - t0},
            requested=requested,
            dynamic_range=dr,
            reason=reason,
        )
    image = tonemap_chunks(rad, TONEMAP_OPERATORS[key_m], scale, white, chunk_pixels)
    t2 = time.perf_counter()
    return TonemapResult(
        image=image,
        method=key_m,
        exposure=float(exposure),
        key=float(key),
        auto_exposure=bool(auto_exposure),
        log_average=float(log_avg),
        scale=scale,
        white=None if white is None else float(white),
        timings={"statistics": t1 - t0, "map": t2 - t1, "total": t2 - t0},
        requested=requested,
        dynamic_range=dr,
        reason=reason,
    )
