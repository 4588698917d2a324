"""Hand-held registration of differently exposed frames (Cerman & Hlavac 2006, section 6).

Consecutive frames are registered pairwise, exposure-invariantly: both frames linear, the darker
one multiplied by the exposure ratio ``k``, pixels above saturation or below the noise floor
discarded in both. An integer shift from cross-correlation in Fourier space (eq. 5) starts a
sub-pixel search minimising eq. 6 with the normalisation of eq. 7. Pair transforms are chained
to a reference frame (the middle one by default).

Motion models (``MODELS``), each with one more parameter family than the one before:

* ``"shift"``: x and y;
* ``"euclidean"``: shift and rotation (the seed's model);
* ``"similarity"`` (default): shift, rotation and scale. Hand-held phone brackets sway and
  refocus between frames (scales of 0.994-0.995 on an 8 MP bracket of issue 14, 8-13 px at
  its corners), which a rigid motion cannot follow;
* ``"homography"``: 8 parameters (perspective: a camera turning about its centre, or the
  dominant plane of a scene seen from a moved camera). On the real phone brackets in
  ``../shared/data`` (``bench/bench_models_real.py``, 12 pairs) the mean corner distance to
  SIFT + RANSAC homographies is 2.54 px (euclidean), 2.23 px (similarity) and 1.08 px
  (homography; median 0.42 px): a phone pitching or yawing between frames is a perspective
  motion.

Every result carries the motion as a 3x3 ``homography`` and, for the affine models, as a 2x3
``matrix`` (:mod:`hdrcore.geometry` handles both forms).

Methods (``REGISTRATION_METHODS``):

* ``"fast"`` (default): coarse-to-fine Gauss-Newton on the same cost
  (:mod:`hdrcore.registration.fast`);
* ``"Cerman 2006"``: the seed's Nelder-Mead simplex search (:mod:`hdrcore.registration.cerman2006`).

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .._threads import ordered_map
from ..errors import ParameterError, validate_method
from ..geometry import (
    affine_part,
    compose,
    corner_error,
    homogeneous,
    identity,
    invert,
    rigid_matrix,
    rigid_parameters,
    similarity_matrix,
    similarity_parameters,
    to_reference,
)
from ._problem import AFFINE_MODELS, MODELS
from .cerman2006 import register_pair_cerman2006
from .fast import register_pair_fast
from .fourier import FourierShift, cross_correlation_shift
from .result import FAILED_STATUSES, BracketRegistration, PairPreview, PairRegistration
from .warp import WarpResult, valid_mask, warp, warp_to_reference

__all__ = [
    "REGISTRATION_METHODS",
    "MODELS",
    "AFFINE_MODELS",
    "FAILED_STATUSES",
    "BracketRegistration",
    "FourierShift",
    "PairPreview",
    "PairRegistration",
    "WarpResult",
    "affine_part",
    "compose",
    "corner_error",
    "cross_correlation_shift",
    "homogeneous",
    "identity",
    "invert",
    "register_bracket",
    "register_pair",
    "rigid_matrix",
    "rigid_parameters",
    "similarity_matrix",
    "similarity_parameters",
    "to_reference",
    "valid_mask",
    "warp",
    "warp_to_reference",
]

REGISTRATION_METHODS: dict[str, Callable[..., PairRegistration]] = {
    "fast": register_pair_fast,
    "Cerman 2006": register_pair_cerman2006,
}


def register_pair(
    dark: np.ndarray,
    bright: np.ndarray,
    ratio: float,
    *,
    method: str = "fast",
    saturation: float = 1.0,
    noise_floor: float = 0.0,
    threshold: float = 0.1,
    model: str = "similarity",
    **options,
) -> PairRegistration:
    """Register the bright frame of a consecutive pair to the dark frame.

    Parameters
    ----------
    dark, bright : single-channel linear images ``(H, W)`` of the same size (e.g. the green
        channel or the luminance after the response LUT).
    ratio : exposure ratio ``k = t_bright / t_dark`` (from :mod:`hdrcore.exposure`).
    saturation, noise_floor : linear levels; pixels at or above ``saturation`` or at or below
        ``noise_floor`` are discarded (in either frame).
    threshold : ``t`` of eq. 7, as a fraction of ``saturation``: the normalising denominator
        ``a + k b`` never goes below it.
    model : a key of :data:`MODELS`: ``"similarity"`` (shift, rotation, scale; default),
        ``"homography"``, ``"euclidean"`` (shift and rotation) or ``"shift"``.
    method : a key of :data:`REGISTRATION_METHODS` (``"Cerman 2006"`` refuses ``"homography"``).
    options : ``initial`` (2x3 or 3x3 start instead of eq. 5), ``previews`` (bool), ``fft_size``,
        ``min_ncc``, ``lut`` (the frames are uint8/uint16 levels, any strides, and ``lut[level]``
        their linear value: a channel view of the raw RGB frames registers without a linear
        copy), and the search's own options.

    Returns a :class:`PairRegistration` whose ``homography`` (3x3; and ``matrix``, 2x3, for the
    affine models) maps bright-frame pixel coordinates to the dark frame; on failure its
    ``status`` says why and the motion is the identity.
    """
    key = validate_method(method, REGISTRATION_METHODS, "registration")
    return REGISTRATION_METHODS[key](
        dark,
        bright,
        ratio,
        saturation=saturation,
        noise_floor=noise_floor,
        threshold=threshold,
        model=model,
        **options,
    )


def register_bracket(
    frames: Sequence[np.ndarray],
    ratios: Sequence[float],
    *,
    reference: int | None = None,
    method: str = "fast",
    saturation: float = 1.0,
    noise_floor: float = 0.0,
    threshold: float = 0.1,
    model: str = "similarity",
    progress: Callable[[int, int], None] | None = None,
    then: Callable[[PairRegistration], PairRegistration] | None = None,
    **options,
) -> BracketRegistration:
    """Register consecutive pairs of a bracket (darkest first) and chain them to ``reference``.

    ``frames``: single-channel linear images; ``ratios[i] = t[i + 1] / t[i]``; ``reference``
    defaults to the middle frame. ``progress(done, total)`` is called after each pair. ``then``
    is applied to each registered pair on its worker, as soon as it is registered (e.g. a
    second motion model tried on it: no pair waits for the others' first pass); when it gives
    a pair without a 2x3 matrix (a homography), the chain is of 3x3 matrices. Other arguments
    as :func:`register_pair`.
    """
    n = len(frames)
    if n < 2:
        raise ParameterError("registration needs at least two frames", found=str(n))
    if len(ratios) != n - 1:
        raise ParameterError(
            "one exposure ratio per consecutive pair", expected=str(n - 1), found=str(len(ratios))
        )
    ref = n // 2 if reference is None else int(reference)
    if not 0 <= ref < n:
        raise ParameterError(
            "reference frame out of range", expected=f"0..{n - 1}", found=str(reference)
        )
    key = validate_method(method, REGISTRATION_METHODS, "registration")
    model = validate_method(model, MODELS, "motion model")

    def one(i: int) -> PairRegistration:
        pair = REGISTRATION_METHODS[key](
            frames[i],
            frames[i + 1],
            ratios[i],
            saturation=saturation,
            noise_floor=noise_floor,
            threshold=threshold,
            model=model,
            dark_index=i,
            bright_index=i + 1,
            **options,
        )
        return pair if then is None else then(pair)

    # The pairs are independent: registered side by side on the default workers (much of a
    # pair's search is single-threaded Python and numpy between compiled kernels).
    pairs = ordered_map(
        one,
        list(range(n - 1)),
        done=None if progress is None else (lambda i: progress(i + 1, n - 1)),
    )
    if model in AFFINE_MODELS and all(p.matrix is not None for p in pairs):
        chain = to_reference([_present(p.matrix) for p in pairs], ref)
        return BracketRegistration(ref, tuple(pairs), chain, model, key)
    chain = to_reference([_present(p.homography) for p in pairs], ref)
    return BracketRegistration(ref, tuple(pairs), None, model, key, to_reference_homography=chain)


def _present(m: np.ndarray | None) -> np.ndarray:
    """A pair's matrix, which every registered pair has (a failed one: the identity)."""
    if m is None:
        raise RuntimeError("a registered pair without its motion matrix")
    return m
