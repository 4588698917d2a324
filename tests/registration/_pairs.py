"""Helpers: simulated hand-held pairs with known motion (the seed's camera model)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from hdrcore.synthetic import simulate_bracket

#: The compiled kernels of the registration's searches whose numpy specifications
#: (hdrcore.registration.spec, same signatures) a test can put in their place.
SEARCH_KERNELS = ("score_candidates", "support_valid", "gauss_newton_sums")


@contextmanager
def on_specs() -> Iterator[None]:
    """Run the searches' kernels as their numpy specifications (hdrcore.registration.spec)."""
    from hdrcore.registration import _kernels, spec

    with pytest.MonkeyPatch.context() as mp:
        for name in SEARCH_KERNELS:
            mp.setattr(_kernels, name, getattr(spec, name))
        yield


def run(compiled: bool, f, *args, **kw):
    """``f(*args, **kw)`` with the compiled kernels, or with their specs (``compiled`` False)."""
    if compiled:
        return f(*args, **kw)
    with on_specs():
        return f(*args, **kw)


def green(frame: np.ndarray, max_level: int) -> np.ndarray:
    """The green channel of an integer frame as linear values in [0, 1] (linear response)."""
    return frame[..., 1].astype(np.float32) / max_level


def simulated_pair(
    *,
    bits=12,
    seed=0,
    motion=(0.0, 0.0, 0.0),
    shape=(128, 192),
    ratio=4.0,
    noise_sigma=1.0,
    scene="window",
):
    """(dark, bright, true pair matrix, max_level) for a pair with the bright frame moved."""
    sb = simulate_bracket(
        scene=scene,
        shape=shape,
        exposure_times=(1.0, ratio),
        bits=bits,
        noise_sigma=noise_sigma,
        motion=[(0.0, 0.0, 0.0), motion],
        reference=0,
        seed=seed,
    )
    ml = sb.max_level
    return green(sb.frames[0], ml), green(sb.frames[1], ml), sb.pair_matrix(0, 1), ml


def render_frames(
    to_reference,
    exposure_times,
    *,
    bits=12,
    seed=0,
    shape=(192, 288),
    noise_sigma=1.0,
    scene="window",
):
    """Frames of a bracket whose frame ``k`` sees the scene at ``to_reference[k] @ p`` (2x3 or
    3x3: any motion, a homography too), as the green channel in linear [0, 1], and max_level.

    The seed's camera model of :func:`hdrcore.synthetic.simulate_bracket` (linear response,
    Gaussian noise, quantisation) on radiance rendered like its ``"area"`` renderer (each pixel
    integrates the bilinear scene over its footprint: ``map_coordinates(order=2,
    prefilter=False)``), at positions mapped by a homography.
    """
    from scipy import ndimage

    from hdrcore.registration.transform import apply, homogeneous
    from hdrcore.synthetic import make_scene

    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    pos = [apply(homogeneous(m), xx, yy) for m in to_reference]
    reach = max(max(-x.min(), x.max() - (w - 1), -y.min(), y.max() - (h - 1)) for x, y in pos)
    margin = int(np.ceil(max(reach, 0.0))) + 8
    big = make_scene(scene, (h + 2 * margin, w + 2 * margin), seed)[..., 1].astype(np.float64)
    radiance = [
        np.maximum(
            ndimage.map_coordinates(
                big, [y + margin, x + margin], order=2, mode="nearest", prefilter=False
            ),
            1e-9,
        )
        for x, y in pos
    ]
    times = tuple(float(t) for t in exposure_times)
    key = 0.18 / (float(np.median(radiance[0])) * float(np.exp(np.mean(np.log(times)))))
    frames, ml = [], (1 << bits) - 1
    for k, (e, t) in enumerate(zip(radiance, times, strict=True)):
        rgb = np.repeat(e[..., None].astype(np.float32), 3, axis=2)
        sb = simulate_bracket(
            rgb,
            exposure_times=(t,),
            bits=bits,
            noise_sigma=noise_sigma,
            key=key,
            seed=seed * 101 + k,
        )
        frames.append(green(sb.frames[0], ml))
    return frames, ml


def homography_pair(matrix, *, ratio=4.0, **kw):
    """(dark, bright, truth pair matrix (3x3), max_level): the bright frame moved by ``matrix``
    (bright-frame pixel -> dark-frame pixel)."""
    from hdrcore.registration.transform import homogeneous

    (dark, bright), ml = render_frames([np.eye(3), matrix], (1.0, ratio), **kw)
    return dark, bright, homogeneous(matrix), ml


def perspective(shape, dx, dy, angle_deg, scale, px, py):
    """A homography: similarity about the centre, then perspective terms ``px, py`` (each the
    relative change of scale across half the frame's width or height)."""
    from hdrcore.registration.transform import homogeneous, similarity_matrix

    h, w = shape
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    centre = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]])
    back = np.array([[1, 0, cx], [0, 1, cy], [0, 0, 1.0]])
    p = np.array([[1, 0, 0], [0, 1, 0], [px / cx, py / cy, 1.0]])
    m = homogeneous(similarity_matrix(dx, dy, angle_deg, scale, shape)) @ back @ p @ centre
    return m / m[2, 2]
