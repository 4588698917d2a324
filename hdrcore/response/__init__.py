"""Camera response recovery (Cerman & Hlavac 2006, section 4) and the response object.

Methods, chosen by name through :data:`RESPONSE_METHODS` and :func:`recover_response`:

* ``"debevec1997"`` -- Debevec & Malik 1997 from pixel samples, with the seed's saturation fix;
* ``"debevec-histogram"`` -- the seed's histogram variant (BTF correspondences, no
  registration);
* ``"mitsunaga1999"`` -- Mitsunaga & Nayar 1999 polynomial from pixel samples, ratios iterable;
* ``"grossberg2003"`` -- Grossberg & Nayar 2003 polynomial constrained by the BTFs;
* ``"joint-histogram"`` / ``"joint-pixels"`` -- the channels fitted jointly (one shared shape,
  separate curves only when held-back data support them; :mod:`.joint`).

``"auto"`` (the default, :func:`select_response`) compares the joint recovery, the parametric
families of :mod:`.parametric` (gamma, sRGB with toe, filmic) and plain sRGB on correspondences
held back from the fit, keeps the best, and falls back to a safe curve with a warning when the
recovery is degenerate (:mod:`.degeneracy`); the curve's ``selection`` says which won and by
how much.

Every method enforces a non-decreasing curve and returns a :class:`ResponseCurve` normalised to
``g(0) = 0``, ``g(max_level) = 1``. :func:`resolve_response` turns a command-line ``--response``
value (``linear``, ``srgb``, a saved ``.json`` curve or a method name) into a curve.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ParameterError, validate_method
from .curve import ChannelFit, ResponseCurve, normalise_curve
from .debevec1997 import debevec1997
from .debevec_histogram import debevec_histogram
from .grossberg2003 import grossberg2003
from .joint import joint_histogram, joint_pixels
from .mitsunaga1999 import mitsunaga1999
from .plot import plot_curves, render_curves
from .select import ResponseSelection, select_response

__all__ = [
    "AUTO",
    "RESPONSE_METHODS",
    "SPECIAL_RESPONSES",
    "DEFAULT_METHOD",
    "ChannelFit",
    "ResponseCurve",
    "debevec1997",
    "debevec_histogram",
    "grossberg2003",
    "joint_histogram",
    "joint_pixels",
    "linear_response",
    "mitsunaga1999",
    "normalise_curve",
    "plot_curves",
    "recover_response",
    "render_curves",
    "resolve_response",
    "ResponseSelection",
    "select_response",
    "srgb_response",
]

RESPONSE_METHODS: dict[str, Callable[..., ResponseCurve]] = {
    "debevec1997": debevec1997,
    "debevec-histogram": debevec_histogram,
    "mitsunaga1999": mitsunaga1999,
    "grossberg2003": grossberg2003,
    "joint-histogram": joint_histogram,
    "joint-pixels": joint_pixels,
}
"""Response-recovery methods by name. Each takes ``(frames, exposure_times, **parameters)``."""

#: ``"auto"``: the response chosen on held-back correspondences among the joint recovery, the
#: parametric families and sRGB, with a fallback when the recovery is degenerate
#: (:func:`select_response`). Histograms only: no registration needed.
AUTO = "auto"

#: Default for brackets that may be hand-held.
DEFAULT_METHOD = AUTO


def recover_response(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None = None,
    *,
    method: str = DEFAULT_METHOD,
    **parameters: Any,
) -> ResponseCurve:
    """Recover the inverse camera response of a bracket with the named method.

    ``frames`` are integer ``(H, W[, C])`` arrays, darkest first; ``exposure_times`` seconds per
    frame (exact for the Debevec-Malik variants, starting values for the polynomial methods).
    ``parameters`` go to the method (e.g. ``max_level``, ``mask``, ``cutoff``, ``order``); an
    unknown one raises :class:`ParameterError` listing the accepted names.
    """
    if str(method).strip().lower() == AUTO:
        key, fn = AUTO, select_response
    else:
        key = validate_method(method, {AUTO: None, **RESPONSE_METHODS}, "response")
        fn = RESPONSE_METHODS[key]
    accepted = [
        name
        for name, p in inspect.signature(fn).parameters.items()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    unknown = sorted(set(parameters) - set(accepted))
    if unknown:
        raise ParameterError(
            f"unknown parameter(s) {', '.join(unknown)} for response method {key!r}",
            expected=f"some of {', '.join(accepted)}",
        )
    return fn(frames, exposure_times, **parameters)


def _check_special(max_level: int, n_channels: int) -> tuple[int, int]:
    m, c = int(max_level), int(n_channels)
    if m < 1:
        raise ParameterError("max_level must be >= 1", found=str(max_level))
    if c < 1:
        raise ParameterError("n_channels must be >= 1", found=str(n_channels))
    return m, c


def linear_response(max_level: int = 255, n_channels: int = 3) -> ResponseCurve:
    """The identity ``g(z) = z / max_level`` (RAW data, already linear frames)."""
    m, c = _check_special(max_level, n_channels)
    g = np.tile(np.arange(m + 1) / m, (c, 1))
    return ResponseCurve(g=g, method="linear", message="identity (linear data)")


def srgb_response(max_level: int = 255, n_channels: int = 3) -> ResponseCurve:
    """sRGB decoding (IEC 61966-2-1 EOTF, ``colour.models.eotf_sRGB``) at every level (kept in
    the user's cache folder: :func:`hdrcore._colour_cache.srgb_eotf`)."""
    from .._colour_cache import srgb_eotf

    m, c = _check_special(max_level, n_channels)
    v = srgb_eotf(m)
    g = normalise_curve(np.tile(v, (c, 1)))
    return ResponseCurve(g=g, method="srgb", message="sRGB decoding (colour-science eotf_sRGB)")


SPECIAL_RESPONSES: dict[str, Callable[..., ResponseCurve]] = {
    "linear": linear_response,
    "srgb": srgb_response,
}


def resolve_response(
    spec: str | os.PathLike | ResponseCurve,
    frames: Sequence[np.ndarray] | None = None,
    exposure_times: Sequence[float] | None = None,
    *,
    max_level: int | None = None,
    n_channels: int | None = None,
    **parameters: Any,
) -> ResponseCurve:
    """A response curve from a ``--response`` value.

    ``spec`` is a :class:`ResponseCurve` (returned as is), ``"linear"`` or ``"srgb"`` (built for
    ``max_level`` and ``n_channels``, taken from ``frames`` when given), a path to a saved JSON
    curve, or a method name of :data:`RESPONSE_METHODS` (recovered from ``frames`` with
    ``exposure_times`` and ``parameters``).
    """
    if isinstance(spec, ResponseCurve):
        return spec
    text = os.fspath(spec)
    if frames is not None and len(frames) > 0:
        first = np.asarray(frames[0])
        if n_channels is None:
            n_channels = 1 if first.ndim == 2 else int(first.shape[-1])
        if max_level is None and first.dtype == np.uint8:
            max_level = 255
    lowered = text.strip().lower()
    if lowered in SPECIAL_RESPONSES:
        if max_level is None:
            raise ParameterError(
                f"the {lowered!r} response needs the frames' max_level",
                expected="max_level (e.g. 255 for 8-bit)",
            )
        return SPECIAL_RESPONSES[lowered](max_level, n_channels or 3)
    methods = {k.lower() for k in RESPONSE_METHODS} | {AUTO}
    if lowered in methods:
        if frames is None:
            raise ParameterError(
                f"response method {text!r} needs the frames of a bracket to recover from"
            )
        if max_level is not None:
            parameters.setdefault("max_level", max_level)
        return recover_response(frames, exposure_times, method=text, **parameters)
    if text.lower().endswith(".json") or Path(text).is_file():
        return ResponseCurve.load(text)
    valid = [AUTO, *SPECIAL_RESPONSES, *RESPONSE_METHODS]
    raise ParameterError(
        f"unknown response {text!r}",
        expected=f"one of {', '.join(repr(v) for v in valid)} or a saved curve (.json)",
        found=repr(text),
    )
