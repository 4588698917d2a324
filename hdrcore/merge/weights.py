"""Weighting functions of the HDR merge and the noise model behind the noise-aware weight.

A weighting function says how much a frame's sample counts in the weighted average
``E = sum(w * g(M) / dt) / sum(w)`` (Debevec & Malik 1997, eq. 6). A weighting is ONE scalar
function ``fn(level, linear, exposure_time_sq, variance) -> weight`` (float32 in, float32 out)
that numba can compile, wrapped in a :class:`Weighting` and entered in :data:`WEIGHTS`; the merge
kernel, its per-level tables and the whole-array form (``WEIGHTS[name](level, linear,
exposure_time, variance)``, :func:`weights`) are all made from it. The arguments:

``level``
    the sample's output level normalised to [0, 1] (``M / max_level``; for frames that are already
    linear floats the linear value itself),
``linear``
    the linearised value ``x = g(M)`` at the saturation scale (1.0 = sensor saturation),
``exposure_time_sq``
    the square of the frame's (relative) exposure time ``dt`` (float32 of the float64 square;
    the whole-array form takes ``dt`` itself),
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
from typing import Any

import numpy as np

from .._numba import AVAILABLE, numba
from .._numba import inline as _inline
from .._numba import njit as _njit
from ..errors import ParameterError, validate_method

__all__ = [
    "NoiseModel",
    "Weighting",
    "WeightFunction",
    "WEIGHTS",
    "weight_by_code",
    "weight_hat",
    "weight_gaussian",
    "weight_noise_aware",
    "weight_uniform",
    "weight_hat_noise_aware",
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
        if self.full_well is not None and not (np.isfinite(self.full_well) and self.full_well > 0):
            raise ParameterError("full well must be positive or None", found=str(self.full_well))
        if not np.isfinite(self.level_noise) or self.level_noise < 0:
            raise ParameterError("level noise must be finite and >= 0", found=str(self.level_noise))

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


def weight_hat(level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    """Debevec & Malik's triangle ``1 - |2 z - 1|`` on normalised levels [1]."""
    w = level * np.float32(2.0)
    w = w - np.float32(1.0)
    return np.float32(1.0) - abs(w)


def weight_gaussian(level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    """Robertson et al.'s bell ``exp(-4 (z - 0.5)**2 / 0.5**2)`` on normalised levels [2]."""
    w = level - np.float32(0.5)
    w = w * w
    w = w * np.float32(-16.0)
    return np.exp(w)


def weight_noise_aware(level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    """Inverse variance of the radiance estimate ``x / dt``: ``dt**2 / var(x)`` [3], [4].

    With shot and read noise a longer exposure has the smaller relative variance, so it counts
    more wherever it is not clipped; this is the maximum-likelihood weight for linear RAW data.
    """
    return exposure_time_sq / variance


def weight_uniform(level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    """Every unclipped sample above the noise floor counts the same."""
    return np.float32(1.0)


def weight_hat_noise_aware(level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    """Debevec & Malik's triangle times the inverse variance of ``x / dt``: ``(1 - |2 z - 1|)
    dt**2 / var(x)`` [1], [3]. The default for non-linear frames (a response LUT).

    The triangle alone weighs a sample by its level only, so a frame 128 times shorter counts
    as much as a long one at the same level: one level above the noise floor in a 1/512 s frame
    (mostly film base or noise, times 512) outweighed the long frames of Debevec's memorial
    bracket, bright specks 10-100 times their neighbours (isolated specks: 259 with the
    triangle, 14 with this weight). The inverse variance (``var(x)`` through the
    response's slope, :class:`NoiseModel`) gives each frame what its noise is worth; the
    triangle keeps the weight falling smoothly to the clipping level, where the inverse
    variance alone would switch frames between neighbouring pixels (a JPEG response is a few
    per cent off: the frobisher chart's bright patches broke up into blocks)."""
    return _hat(level, linear, exposure_time_sq, variance) * (exposure_time_sq / variance)


_BUILT_IN = (
    weight_hat,
    weight_gaussian,
    weight_noise_aware,
    weight_uniform,
    weight_hat_noise_aware,
)
"""The weightings the merge kernel inlines (SIMD); their codes are their positions here. Any
other weighting reaches the kernel through a compiled function pointer (scalar code)."""

_hat = _inline(weight_hat)
_gaussian = _inline(weight_gaussian)
_noise_aware = _inline(weight_noise_aware)
_uniform = _inline(weight_uniform)
_hat_noise_aware = _inline(weight_hat_noise_aware)


@_inline
def weight_by_code(code, level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    """The built-in weighting number ``code`` (a :attr:`Weighting.code`), inlined."""
    if code == 0:
        return _hat(level, linear, exposure_time_sq, variance)
    if code == 1:
        return _gaussian(level, linear, exposure_time_sq, variance)
    if code == 2:
        return _noise_aware(level, linear, exposure_time_sq, variance)
    if code == 4:
        return _hat_noise_aware(level, linear, exposure_time_sq, variance)
    return _uniform(level, linear, exposure_time_sq, variance)


@_njit
def _apply_code(code, level, linear, t2, variance, out):  # noqa: ANN001, ANN202
    for i in range(out.size):
        out[i] = weight_by_code(code, level[i], linear[i], t2, variance[i])


@_njit
def _apply_pointer(fn, level, linear, t2, variance, out):  # noqa: ANN001, ANN202
    for i in range(out.size):
        out[i] = fn(level[i], linear[i], t2, variance[i])


_SIGNATURE = "float32(float32, float32, float32, float32)"


class Weighting:
    """A weighting function from its scalar form ``fn(level, linear, exposure_time_sq,
    variance) -> weight`` (see the module's docstring): adding a weighting is this one
    function, ``WEIGHTS["name"] = Weighting(fn)``.

    Calling a ``Weighting`` applies it to whole arrays with the old signature
    ``(level, linear, exposure_time, variance) -> float32 weights`` (the kernel's per-level
    tables, the specification :mod:`hdrcore.merge.spec`, :func:`weights`); :attr:`code`
    (built-ins, inlined in the kernel) or :attr:`pointer` (any other: a compiled function
    pointer the kernel calls) is how the merge kernel runs it. Both run the same compiled
    scalar code."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        if not callable(fn):
            raise ParameterError("a weighting is a function", found=type(fn).__name__)
        self.fn = fn
        self.code = next((i for i, b in enumerate(_BUILT_IN) if b is fn), -1)
        self._pointer: Any = None
        self.__doc__ = fn.__doc__

    @property
    def pointer(self) -> Any:
        """The scalar form compiled as a C function pointer (numba ``cfunc``), made on first
        use; the kernel's argument type is the same for every weighting, so one compiled
        kernel serves them all."""
        if self._pointer is None:
            if not AVAILABLE:
                raise ParameterError(
                    "numba is needed to compile a weighting", found="numba not installed"
                )
            self._pointer = numba.cfunc(_SIGNATURE, cache=True)(self.fn)
        return self._pointer

    def __call__(
        self, level: np.ndarray, linear: np.ndarray, exposure_time: float, variance: np.ndarray
    ) -> np.ndarray:
        lv = np.ascontiguousarray(level, np.float32)
        shape = lv.shape
        lv = lv.ravel()
        lin = np.ascontiguousarray(np.broadcast_to(linear, shape), np.float32).ravel()
        var = np.ascontiguousarray(np.broadcast_to(variance, shape), np.float32).ravel()
        t2 = np.float32(float(exposure_time) ** 2)
        out = np.empty(lv.size, np.float32)
        if not AVAILABLE:  # pragma: no cover - numba is a dependency
            for i in range(out.size):
                out[i] = self.fn(lv[i], lin[i], t2, var[i])
        elif self.code >= 0:
            _apply_code(self.code, lv, lin, t2, var, out)
        else:
            _apply_pointer(self.pointer, lv, lin, t2, var, out)
        return out.reshape(shape)

    def __repr__(self) -> str:
        return f"Weighting({getattr(self.fn, '__name__', self.fn)!r})"


WEIGHTS: dict[str, Weighting] = {
    "hat": Weighting(weight_hat),
    "gaussian": Weighting(weight_gaussian),
    "noise-aware": Weighting(weight_noise_aware),
    "uniform": Weighting(weight_uniform),
    "hat-noise-aware": Weighting(weight_hat_noise_aware),
}
"""Weightings by name (see :func:`weights`): add one with ``WEIGHTS[name] = Weighting(fn)``."""


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
