"""The default exposure-ratio estimator: the seed's eq. 4 + 3V, made exact at the bin edges.

Changes against the published method (:mod:`.cerman2006`), each for a measured reason:

* The BTF is sampled at bin *edges* ``m + 1/2``, where the cumulative histogram of the frame an
  equation comes from is exact; only the other frame is interpolated. Sampling at level centres
  interpolates both and biases low levels.
* Noise matching (optional, ``noise_sigma`` in output levels of additive Gaussian noise): the
  dark frame scaled by ``k`` carries ``k`` times the noise of the bright frame, and noise shifts the
  quantiles of a sloped histogram. Blurring the bright histogram by ``sigma * sqrt(k^2 - 1)``
  levels gives both the same noise, which removes that bias (a fixed point in ``k``, two passes).
  The blur's ``sigma`` is taken on a grid of 1 % steps (a 0.5 % error of the noise-matching
  blur moves the ratio by far less than the blur's own correction), so a re-fit with another
  saturation level or noise floor, whose ratio moves by a fraction of a per cent, finds the
  blurred histograms and their transfer functions in a small cache instead of building them
  again (a 14-bit pair: 2 x 3 transfer functions of 16384 levels each).
* Per-channel fits beside the joint fit, with a disagreement flag; non-consecutive pairs and the
  consistent chain live in :mod:`.chain`.

References: J. Cerman, V. Hlavac, CVWW 2006, section 5 (eq. 4, the 3V iteration); M. D. Grossberg,
S. K. Nayar, ECCV 2002 (BTF by histogram matching).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.fft as sfft
from scipy.ndimage import gaussian_filter1d

from ..btf import BrightnessTransferFunction
from ._core import FitOptions, check_histograms, estimate_pair, pair_btfs
from .result import ExposureRatioResult

__all__ = ["REFINED", "exposure_ratio_refined", "blur_histogram"]

REFINED = FitOptions(name="Cerman 2006 refined", at_edges=True, weight_power=0.5)


def blur_histogram(hist: np.ndarray, sigma_levels: float) -> np.ndarray:
    """``hist`` convolved with a Gaussian of ``sigma_levels`` (mass kept, float64 counts).

    Mass that would leave ``0 .. max_level`` is folded back onto the end bins, as clipping does.
    """
    h = np.asarray(hist, np.float64)
    if sigma_levels <= 0:
        return h
    pad = int(np.ceil(4 * sigma_levels)) + 1
    z = np.pad(h, [(0, 0)] * (h.ndim - 1) + [(pad, pad)])
    radius = int(4.0 * sigma_levels + 0.5)  # scipy's: truncate x sigma, rounded
    if radius > FFT_BLUR_RADIUS:
        b = _fft_blur(z, sigma_levels, radius)
    else:
        b = gaussian_filter1d(z, sigma_levels, axis=-1, mode="constant", truncate=4.0)
    out = b[..., pad:-pad].copy()
    out[..., 0] += b[..., :pad].sum(axis=-1)
    out[..., -1] += b[..., -pad:].sum(axis=-1)
    return out


#: Gaussian kernels of more taps either side are applied through the FFT (:func:`_fft_blur`):
#: a 16-bit frame's noise spans hundreds of levels (the real Pixel 7 bracket as 16-bit TIFFs:
#: sigma 110-590 levels, 0.08-0.47 s a blur of 3 x 65536 bins directly, 17 blurs a bracket).
FFT_BLUR_RADIUS = 64


def _fft_blur(z: np.ndarray, sigma: float, radius: int) -> np.ndarray:
    """``gaussian_filter1d(z, sigma, axis=-1, mode="constant", truncate=4)`` through the FFT:
    scipy's kernel (``radius`` taps either side, normalised), the linear convolution's middle;
    the FFT's rounding (about 1e-16 of the total count) is clipped at 0, so no bin is negative."""
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 / (sigma * sigma) * x * x)
    kernel /= kernel.sum()
    n = z.shape[-1]
    size = sfft.next_fast_len(n + 2 * radius, real=True)
    spec = sfft.rfft(z, size, axis=-1) * sfft.rfft(kernel, size)
    out = sfft.irfft(spec, size, axis=-1)[..., radius : radius + n]
    return np.maximum(out, 0.0)


#: Relative step of the grid the noise-matching blur's sigma is taken on.
BLUR_SIGMA_STEP = 0.01
_BLUR_CACHE_SIZE = 24
_blur_cache: OrderedDict[tuple, tuple[np.ndarray, tuple[BrightnessTransferFunction, ...]]] = (
    OrderedDict()
)
_blur_lock = threading.Lock()


def quantised_sigma(sigma: float) -> float:
    """``sigma`` on the grid of :data:`BLUR_SIGMA_STEP` relative steps (0 stays 0)."""
    if not sigma > 0 or not np.isfinite(sigma):
        return 0.0
    step = np.log1p(BLUR_SIGMA_STEP)
    return float(np.exp(np.round(np.log(sigma) / step) * step))


def _digest(a: np.ndarray) -> bytes:
    a = np.ascontiguousarray(a)
    return hashlib.blake2b(
        a.data.cast("B"), digest_size=16, person=str((a.dtype.str, a.shape)).encode()[:16]
    ).digest()


def blurred_transfer(
    hd: np.ndarray, hb: np.ndarray, sigma: float
) -> tuple[np.ndarray, tuple[BrightnessTransferFunction, ...]]:
    """``hb`` blurred by ``sigma`` levels and the pair's transfer functions against ``hd``,
    from a small cache keyed on the histograms' contents and ``sigma`` (a deterministic digest,
    never an object's identity: a cached value is what a fresh computation gives)."""
    key = (_digest(hd), _digest(hb), float(sigma))
    with _blur_lock:
        hit = _blur_cache.get(key)
        if hit is not None:
            _blur_cache.move_to_end(key)
            return hit
    blurred = blur_histogram(hb, sigma)
    value = (blurred, pair_btfs(hd, blurred))
    with _blur_lock:
        _blur_cache[key] = value
        while len(_blur_cache) > _BLUR_CACHE_SIZE:
            _blur_cache.popitem(last=False)
    return value


def exposure_ratio_refined(
    hist_dark: np.ndarray,
    hist_bright: np.ndarray,
    *,
    saturation: float | None = None,
    noise_floor: float | None = None,
    lut: np.ndarray | None = None,
    noise_sigma: float | None = None,
    **kwargs: Any,
) -> ExposureRatioResult:
    """Ratio ``t_bright / t_dark`` from ``(C, max_level + 1)`` histograms (see module docstring).

    ``noise_sigma`` (output levels) switches on noise matching; ``None`` or 0 leaves it off.
    """
    result = estimate_pair(
        hist_dark,
        hist_bright,
        REFINED,
        saturation=saturation,
        noise_floor=noise_floor,
        lut=lut,
        **kwargs,
    )
    if not noise_sigma or noise_sigma <= 0 or not np.isfinite(result.ratio):
        return result
    hd, hb = check_histograms(hist_dark, hist_bright)
    kwargs.pop("btfs", None)  # the blurred histograms have their own transfer functions
    k = result.ratio
    for _ in range(2):
        s = quantised_sigma(float(noise_sigma) * np.sqrt(max(k * k - 1.0, 0.0)))
        # Float counts: the BTF normalises them anyway.
        blurred, btfs = blurred_transfer(hd, hb, s)
        result_b = estimate_pair(
            hd,
            blurred,
            REFINED,
            saturation=saturation,
            noise_floor=noise_floor,
            lut=lut,
            btfs=btfs,
            **kwargs,
        )
        if not np.isfinite(result_b.ratio):
            return result
        k = result_b.ratio
    return replace(
        result_b, initial_ratio=result.initial_ratio, iterates=result.iterates + result_b.iterates
    )
