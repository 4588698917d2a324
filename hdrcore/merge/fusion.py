"""Exposure fusion (Mertens, Kautz & Van Reeth 2007): a preview without a radiance map.

T. Mertens, J. Kautz, F. Van Reeth, "Exposure Fusion", Pacific Graphics 2007,
DOI: 10.1109/PG.2007.17. Each frame's display values get a weight per pixel, the product of
contrast (absolute Laplacian of the grey image), saturation (standard deviation over the
channels) and well-exposedness (a Gaussian of sigma 0.2 around mid-grey in every channel,
eq. 1-2); the weights are normalised per pixel and the frames blended in a Laplacian pyramid
(section 3.2) so the transitions are seamless.

For locally tone-mapped brackets (phones, :mod:`hdrcore.response.local_tonemap`) no global
response holds and a radiance map is a compromise; the fused frames keep each region's colour
and contrast as the camera rendered it. :func:`exposure_fusion` works at preview size: each
frame is reduced by block means and warped onto the reference frame by the registration.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from .._threads import thread_map, worker_count
from ..errors import ParameterError

__all__ = ["exposure_fusion", "fusion_weights"]

WELL_EXPOSED_SIGMA = 0.2


def fusion_weights(
    image: np.ndarray, *, contrast: float = 1.0, saturation: float = 1.0, exposedness: float = 1.0
) -> np.ndarray:
    """Mertens et al.'s weight map of one display-referred ``(H, W, 3)`` image in [0, 1]."""
    img = np.asarray(image, np.float32)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    # per channel, not numpy's reductions over a last axis of three (a third of the fusion)
    grey = (r + g + b) / np.float32(3.0)
    c = np.abs(ndimage.laplace(grey))
    s = np.sqrt(((r - grey) ** 2 + (g - grey) ** 2 + (b - grey) ** 2) / np.float32(3.0))
    far = (r - 0.5) ** 2 + (g - 0.5) ** 2 + (b - 0.5) ** 2
    e = np.exp(far * np.float32(-1.0 / (2 * WELL_EXPOSED_SIGMA**2)))
    return ((c + 1e-6) ** contrast * (s + 1e-6) ** saturation * e**exposedness).astype(np.float32)


_KERNEL = np.array([0.25, 0.5, 0.25], np.float32)


def _down(a: np.ndarray) -> np.ndarray:
    """Blur (binomial 1-2-1 twice) and keep every second pixel. The rows are kept before the
    blur along them (it does not mix rows): the same values, the second axis's two passes on
    half the pixels."""
    a = ndimage.correlate1d(a, _KERNEL, axis=0, mode="nearest")
    a = ndimage.correlate1d(a, _KERNEL, axis=0, mode="nearest")[::2]
    a = ndimage.correlate1d(a, _KERNEL, axis=1, mode="nearest")
    a = ndimage.correlate1d(a, _KERNEL, axis=1, mode="nearest")
    return a[:, ::2]


def _up(a: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Twice the size (pixel repetition smoothed by 1-2-1), cut to ``shape``: along each axis
    an even output sample is ``0.75 a[i] + 0.25 a[i - 1]`` and an odd one ``0.75 a[i] + 0.25
    a[i + 1]`` (the edges repeated), which is what repeating and smoothing give, without the
    four-times larger repeated copy (np.repeat took a third of a phone bracket's fusion)."""
    return _up_axis(_up_axis(a, 0, shape[0]), 1, shape[1])


def _up_axis(a: np.ndarray, axis: int, size: int) -> np.ndarray:
    """:func:`_up` along one axis, ``size`` samples out (``2n - 1`` or ``2n``)."""
    a = np.moveaxis(a, axis, 0)
    prev = np.concatenate([a[:1], a[:-1]])
    nxt = np.concatenate([a[1:], a[-1:]])
    out = np.empty((size,) + a.shape[1:], a.dtype)
    q, h = a.dtype.type(0.25), a.dtype.type(0.75)
    out[0::2] = (h * a + q * prev)[: (size + 1) // 2]
    out[1::2] = (h * a + q * nxt)[: size // 2]
    return np.moveaxis(out, 0, axis)


def _extend_edges(image: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``image`` with every pixel outside ``valid`` (where a warped frame does not reach) set
    to the nearest valid pixel's value. A filled constant there would be a step in the frame's
    Laplacian pyramid at the edge of its coverage, which the blend carries into the result
    (its weight is zero there, but the pyramid's coarse levels reach across): on the Pixel 7
    bracket the preview's bottom 16 rows came out 20 % darker and a bright line ran 4 px
    inside the top edge."""
    if valid.all() or not valid.any():
        return image
    idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    return np.asarray(image[idx[0], idx[1]])


#: ``TonemapResult.method`` of a preview made by :func:`exposure_fusion`.
METHOD = "exposure-fusion"


def exposure_fusion(
    frames: Sequence[np.ndarray],
    *,
    max_level: int,
    to_reference: Sequence[np.ndarray] | None = None,
    factor: int = 1,
) -> np.ndarray:
    """Fuse integer ``(H, W, 3)`` frames into an 8-bit ``(H / factor, W / factor, 3)`` image.

    ``to_reference[k]`` maps frame ``k``'s pixel coordinates to the reference frame's (2x3 or
    3x3; ``None``: aligned); ``factor`` reduces the frames by block means first.
    """
    from ..geometry import invert, scale_matrix
    from ..registration.warp import warp
    from ..resample import downsample_area

    if len(frames) < 1:
        raise ParameterError("exposure fusion needs at least one frame")
    f = max(1, int(factor))

    def prepare(k: int) -> tuple[np.ndarray, np.ndarray]:
        # block means of the levels, then to [0, 1] (one pass over the frame, no full-size
        # float copy: 1.07 -> 0.3 CPU s for the Pixel 7's six 9 MP frames)
        a = downsample_area(frames[k], f) if f > 1 else np.asarray(frames[k], np.float32)
        a = a * np.float32(1.0 / max_level)
        valid = np.ones(a.shape[:2], bool)
        if to_reference is not None:
            back = scale_matrix(invert(np.asarray(to_reference[k], float)), 1.0 / f)
            if not np.allclose(back, np.eye(3)[: back.shape[0]], atol=1e-6):
                # outside the frame's reach its edge extended (the resampling's clamped taps),
                # not a constant: see _extend_edges
                res = warp(a, back, fill=None)
                a = res.image
                valid = np.asarray(res.mask, bool)
                if not np.isfinite(a).all():  # a perspective divide that failed
                    a = _extend_edges(np.nan_to_num(a, nan=0.0), valid & np.isfinite(a).all(-1))
        a = np.clip(a, 0.0, 1.0).astype(np.float32)
        return a, fusion_weights(a) * valid

    # Frame by frame on the default workers (scipy's filters release the GIL); the blend is
    # summed in frame order, as one thread sums it.
    prepared = thread_map(prepare, list(range(len(frames))))
    images = [a for a, _ in prepared]
    weights = [wk for _, wk in prepared]
    del prepared
    wsum = np.sum(weights, axis=0)
    wsum = np.where(wsum > 0, wsum, np.float32(1.0))
    weights = [wk / wsum for wk in weights]
    h, w = images[0].shape[:2]
    levels = max(1, int(np.floor(np.log2(max(min(h, w), 2)))) - 2)

    def blend(k: int) -> list[np.ndarray]:
        # Laplacian pyramid of the image, Gaussian pyramid of the weight (section 3.2)
        gi, gw = [images[k]], [weights[k]]
        for _ in range(levels - 1):
            gi.append(_down(gi[-1]))
            gw.append(_down(gw[-1]))
        lap = [gi[i] - _up(gi[i + 1], gi[i].shape) for i in range(levels - 1)] + [gi[-1]]
        return [lp * g[..., None] for lp, g in zip(lap, gw, strict=True)]

    result: list[np.ndarray] | None = None
    step = worker_count(None)
    for start in range(0, len(images), step):
        for blended in thread_map(blend, list(range(start, min(len(images), start + step)))):
            result = (
                blended if result is None else [r + b for r, b in zip(result, blended, strict=True)]
            )
    assert result is not None
    out = result[-1]
    for i in range(levels - 2, -1, -1):
        out = _up(out, result[i].shape) + result[i]
    return np.clip(np.rint(out * 255.0), 0, 255).astype(np.uint8)
