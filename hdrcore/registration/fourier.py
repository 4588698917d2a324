"""Integer shift by cross-correlation in Fourier space (Cerman & Hlavac 2006, section 6, eq. 5).

The seed finds the whole-pixel shift between two consecutive, exposure-equalised frames as the
maximum of their cross-correlation, computed through the Fourier transform (eq. 5)::

    c(s) = F^-1( conj(F(a)) * F(b) )(s),       s* = argmax_s c(s)

where ``a`` is the bright frame and ``b`` the dark frame multiplied by the exposure ratio, so that
``b(x + s*) ~ a(x)``: the shift maps bright-frame coordinates to dark-frame coordinates, the
project's pair convention.

What we add to the paper's description, each for a stated reason:

* both images are clipped to the exposure range they share and compared in log units, which
  makes them the same function of scene radiance (exposure invariant) without discarding pixels
  (the FFT needs a full grid);
* a separable Hann window against the wrap-around edge (the frames are not periodic);
* partial spectral whitening (``whitening`` in [0, 1]; 1 is phase correlation) for a sharp peak;
* two peak-quality measures: the normalised cross-correlation at the peak (1: identical,
  ~0: unrelated) and the peak-to-sidelobe ratio of the (whitened) surface.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError

__all__ = ["FourierShift", "cross_correlation_shift"]


@dataclass(frozen=True)
class FourierShift:
    """Result of eq. 5: the integer shift and how much to trust it.

    ``dx, dy`` map coordinates of ``a`` (bright) to ``b`` (dark): ``b(x + dx, y + dy) ~ a(x, y)``.
    ``ncc`` is the normalised cross-correlation of the windowed images at that shift;
    ``psr`` the peak-to-sidelobe ratio of the correlation surface (peak minus mean, over standard
    deviation, 5x5 around the peak excluded); ``contrast`` the standard deviation of ``a`` inside
    the window (0 for a flat image).
    """

    dx: int
    dy: int
    ncc: float
    psr: float
    contrast: float


def _hann(n: int) -> np.ndarray:
    if n < 3:
        return np.ones(n)
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * (np.arange(n) + 0.5) / n)


def cross_correlation_shift(
    a: np.ndarray, b: np.ndarray, *, whitening: float = 0.9, window: bool = True
) -> FourierShift:
    """Integer shift maximising the cross-correlation of ``a`` and ``b`` (eq. 5).

    ``a`` and ``b`` are same-shape 2-D arrays already on a common scale (exposure-equalised,
    clipped; log units recommended). Shifts are searched over the whole circular range
    ``(-H/2, H/2] x (-W/2, W/2]``.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ParameterError(
            "eq. 5 needs two 2-D images of the same shape",
            found=f"{a.shape} and {b.shape}",
        )
    if not 0.0 <= whitening <= 1.0:
        raise ParameterError("whitening must be in [0, 1]", found=str(whitening))
    h, w = a.shape
    win = np.outer(_hann(h), _hann(w)) if window else np.ones((h, w))
    a0 = (a - np.average(a, weights=win)) * win
    b0 = (b - np.average(b, weights=win)) * win
    na = float(np.sqrt(np.sum(a0 * a0)))
    nb = float(np.sqrt(np.sum(b0 * b0)))
    contrast = float(np.sqrt(np.sum(a0 * a0) / np.sum(win * win)))
    if na <= 1e-12 * max(1.0, float(np.abs(a).max())) or nb <= 1e-12 * max(
        1.0, float(np.abs(b).max())
    ):
        return FourierShift(0, 0, 0.0, 0.0, contrast)
    fa = np.fft.rfft2(a0)
    fb = np.fft.rfft2(b0)
    cross = np.conj(fa) * fb  # eq. 5: correlation theorem
    plain = np.fft.irfft2(cross, s=(h, w))
    if whitening > 0:
        mag = np.abs(cross)
        cross = cross / np.power(mag + 1e-12 * float(mag.max()), whitening)
        surface = np.fft.irfft2(cross, s=(h, w))
    else:
        surface = plain
    iy, ix = np.unravel_index(int(np.argmax(surface)), surface.shape)
    dy = iy if iy <= h // 2 else iy - h
    dx = ix if ix <= w // 2 else ix - w
    ncc = float(plain[iy, ix] / (na * nb))
    mask = np.ones_like(surface, bool)
    ys = (np.arange(iy - 2, iy + 3) % h)[:, None]
    xs = (np.arange(ix - 2, ix + 3) % w)[None, :]
    mask[ys, xs] = False
    side = surface[mask]
    std = float(side.std())
    psr = float((surface[iy, ix] - side.mean()) / std) if std > 0 else 0.0
    return FourierShift(int(dx), int(dy), ncc, psr, contrast)
