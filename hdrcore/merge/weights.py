"""Weighting functions of the HDR merge and the noise model behind the noise-aware weight.

A weighting function says how much a frame's sample counts in the weighted average
``E = sum(w * g(M) / dt) / sum(w)`` (Debevec & Malik 1997, eq. 6). Every function here has the
signature ``fn(level, linear, exposure_time, variance) -> weight`` where

``level``
    the sample's output level normalised to [0, 1] (``M / max_level``; for frames that are already
    linear floats the linear value itself),
``linear``
    the linearised value ``x = g(M)`` at the saturation scale (1.0 = sensor saturation),
``exposure_time``
    the frame's (relative) exposure time ``dt``,
``variance``
    the variance of ``x`` predicted by the :class:`NoiseModel`.

Zero weights for saturated samples and samples below the noise floor are applied by the merge
itself, not by these functions, so every function is a smooth prior only.

References
----------
.. [1] P. E. Debevec, J. Malik, "Recovering high dynamic range radiance maps from photographs",
   SIGGRAPH 1997, eq. 6 and the hat function of section 2.1. doi:10.1145/258734.258884
.. [2] M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic
   range enhancement using multiple exposures", J. Electronic Imaging 12(2), 2003 (Gaussian-like
   weight). doi:10.1117/1.1557695
.. [3] M. Granados, B. Ajdin, M. Wand, C. Theobalt, H.-P. Seidel, H. P. A. Lensch, "Optimal HDR
   reconstruction with linear digital cameras", CVPR 2010 (inverse-variance weights from a
   signal-dependent noise model). doi:10.1109/CVPR.2010.5540208
.. [4] S. W. Hasinoff, F. Durand, W. T. Freeman, "Noise-optimal capture for high dynamic range
   photography", CVPR 2010. doi:10.1109/CVPR.2010.5540167
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError, validate_method

__all__ = [
    "NoiseModel",
    "WeightFunction",
    "WEIGHTS",
    "weight_hat",
    "weight_gaussian",
    "weight_noise_aware",
    "weight_uniform",
    "weights",
]

WeightFunction = Callable[[np.ndarray, np.ndarray, float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class NoiseModel:
    """Variance of a linearised sample ``x`` (saturation scale, 1.0 = saturation).

    ``var(x) = read_noise**2 + x / full_well + g'(M)**2 * (level_noise**2 + 1/12)``

    read_noise
        standard deviation of signal-independent noise in linear units (fraction of saturation),
        e.g. sensor read noise of a RAW frame: ``sigma_read_DN / (white - black)``.
    full_well
        electrons collected at saturation (photon shot noise has variance ``x / full_well``);
        ``None`` for no shot noise.
    level_noise
        standard deviation of noise added after the response, in output levels (the seed's
        simulated camera, JPEG noise); with the quantisation step it is propagated through the
        slope ``g'`` of the response. Used for integer frames only.
    """

    read_noise: float = 2.5e-4
    full_well: float | None = None
    level_noise: float = 1.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.read_noise) or self.read_noise < 0:
            raise ParameterError("read noise must be finite and >= 0", found=str(self.read_noise))
        if self.full_well is not None and not (
            np.isfinite(self.full_well) and self.full_well > 0
        ):
            raise ParameterError("full well must be positive or None", found=str(self.full_well))
        if not np.isfinite(self.level_noise) or self.level_noise < 0:
            raise ParameterError(
                "level noise must be finite and >= 0", found=str(self.level_noise)
            )

    @property
    def shot_gain(self) -> float:
        """Variance per unit of linear signal (``1 / full_well``; 0 without shot noise)."""
        return 0.0 if self.full_well is None else 1.0 / float(self.full_well)

    def level_variance(self) -> float:
        """Variance in output levels of an integer sample (noise plus quantisation)."""
        return float(self.level_noise) ** 2 + 1.0 / 12.0

    def to_json(self) -> dict:
        return {
            "read_noise": self.read_noise,
            "full_well": self.full_well,
            "level_noise": self.level_noise,
        }


def weight_hat(
    level: np.ndarray, linear: np.ndarray, exposure_time: float, variance: np.ndarray
) -> np.ndarray:
    """Debevec & Malik's triangle ``1 - |2 z - 1|`` on normalised levels [1]."""
    w = np.multiply(level, 2.0, dtype=np.float32)
    w -= 1.0
    np.abs(w, out=w)
    np.subtract(1.0, w, out=w)
    return w


def weight_gaussian(
    level: np.ndarray, linear: np.ndarray, exposure_time: float, variance: np.ndarray
) -> np.ndarray:
    """Robertson et al.'s bell ``exp(-4 (z - 0.5)**2 / 0.5**2)`` on normalised levels [2]."""
    w = np.subtract(level, 0.5, dtype=np.float32)
    np.square(w, out=w)
    w *= -16.0
    np.exp(w, out=w)
    return w


def weight_noise_aware(
    level: np.ndarray, linear: np.ndarray, exposure_time: float, variance: np.ndarray
) -> np.ndarray:
    """Inverse variance of the radiance estimate ``x / dt``: ``dt**2 / var(x)`` [3], [4].

    With shot and read noise a longer exposure has the smaller relative variance, so it counts
    more wherever it is not clipped; this is the maximum-likelihood weight for linear RAW data.
    """
    return np.divide(np.float32(float(exposure_time) ** 2), variance, dtype=np.float32)


def weight_uniform(
    level: np.ndarray, linear: np.ndarray, exposure_time: float, variance: np.ndarray
) -> np.ndarray:
    """Every unclipped sample above the noise floor counts the same."""
    return np.ones(np.shape(level), np.float32)


WEIGHTS: dict[str, WeightFunction] = {
    "hat": weight_hat,
    "gaussian": weight_gaussian,
    "noise-aware": weight_noise_aware,
    "uniform": weight_uniform,
}
"""Weighting functions by name (see :func:`weights`)."""


def weights(
    level: np.ndarray,
    linear: np.ndarray,
    exposure_time: float,
    variance: np.ndarray,
    method: str = "hat",
) -> np.ndarray:
    """Weights of samples by the named function of :data:`WEIGHTS` (float32, >= 0)."""
    key = validate_method(method, WEIGHTS, "weighting")
    if not np.isfinite(exposure_time) or exposure_time <= 0:
        raise ParameterError("exposure time must be positive", found=str(exposure_time))
    return WEIGHTS[key](level, linear, float(exposure_time), variance)
