"""Parametric response families: the safe fallbacks of a degenerate recovery.

Each family is an inverse response ``g(x)`` of the normalised level ``x = z / max_level`` with
``g(0) = 0``, ``g(1) = 1``, non-decreasing, shared by every channel (a fallback must not tint):

* ``gamma`` -- ``g = x^gamma`` (a pure power law);
* ``srgb-toe`` -- the IEC 61966-2-1 shape with free exponent and offset, a linear segment
  tangent at ``x0 = a / (gamma - 1)``, and a black pedestal ``b`` cut off at the bottom (a
  lifted or crushed toe): ``g = max(0, (h(x) - b) / (1 - b))`` with
  ``h = ((x + a) / (1 + a))^gamma`` above ``x0`` (sRGB: ``a = 0.055``, ``gamma = 2.4``,
  ``b = 0``);
* ``filmic`` -- the inverse of an ACES-like filmic curve ``f(e) = A(k e) / A(k)`` with
  K. Narkowicz's fit ``A(e) = e (2.51 e + 0.03) / (e (2.43 e + 0.59) + 0.14)``; ``k`` sets how
  far into the shoulder the sensor saturates.

:func:`fit_family` fits a family's parameters to level pairs of consecutive frames with known
exposure ratios (the residual ``ln g(T(z)) - ln g(z) - ln R`` of :mod:`.holdout`), by bounded
least squares over the parameters.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from .curve import ResponseCurve, normalise_curve
from .samples import Correspondences, pair_weight

__all__ = ["FAMILIES", "Family", "family_curve", "fit_family", "srgb_inverse"]


def srgb_inverse(x: np.ndarray, gamma: float = 2.4, a: float = 0.055) -> np.ndarray:
    """The sRGB-shaped decoding with exponent ``gamma`` and offset ``a`` (IEC 61966-2-1 for
    the defaults), its linear segment tangent to the power part."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    x0 = a / (gamma - 1.0) if gamma > 1.0 else 0.0
    power = ((x + a) / (1.0 + a)) ** gamma
    if x0 <= 0:
        return power
    slope = ((x0 + a) / (1.0 + a)) ** gamma / x0
    return np.where(x <= x0, x * slope, power)


def _gamma(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.clip(x, 0.0, 1.0) ** p[0]


def _srgb_toe(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    h = srgb_inverse(x, p[0], p[1])
    b = p[2]
    return np.maximum(h - b, 0.0) / (1.0 - b)


def _aces(e: np.ndarray) -> np.ndarray:
    return e * (2.51 * e + 0.03) / (e * (2.43 * e + 0.59) + 0.14)


def _aces_inverse(y: np.ndarray) -> np.ndarray:
    # y (e (2.43 e + 0.59) + 0.14) = e (2.51 e + 0.03): a quadratic in e, positive root
    a = 2.43 * y - 2.51
    b = 0.59 * y - 0.03
    c = 0.14 * y
    disc = np.maximum(b * b - 4.0 * a * c, 0.0)
    return (-b - np.sqrt(disc)) / (2.0 * a)


def _filmic(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    k = p[0]
    return _aces_inverse(np.clip(x, 0.0, 1.0) * _aces(k)) / k


@dataclass(frozen=True)
class Family:
    """A parametric family: ``fn(x, params)``, starting values, bounds and parameter names."""

    fn: Callable[[np.ndarray, np.ndarray], np.ndarray]
    start: tuple[float, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    names: tuple[str, ...]
    description: str


FAMILIES: dict[str, Family] = {
    "gamma": Family(_gamma, (2.2,), (1.0,), (4.0,), ("gamma",), "power law x^gamma"),
    "srgb-toe": Family(
        _srgb_toe,
        (2.4, 0.055, 0.0),
        (1.5, 0.0, -0.05),
        (3.5, 0.3, 0.2),
        ("gamma", "offset", "pedestal"),
        "sRGB shape with free exponent, offset and black pedestal",
    ),
    "filmic": Family(
        _filmic,
        (2.0,),
        (0.3,),
        (16.0,),
        ("white",),
        "inverse ACES-like filmic curve (Narkowicz fit), sensor white k",
    ),
}
"""The fallback families by name."""


def family_curve(
    name: str, params: Sequence[float], max_level: int, n_channels: int = 3
) -> np.ndarray:
    """``(C, max_level + 1)`` normalised ``g`` of family ``name`` with ``params``."""
    fam = FAMILIES[name]
    x = np.arange(max_level + 1, dtype=np.float64) / max_level
    g = fam.fn(x, np.asarray(params, dtype=np.float64))
    g = np.maximum.accumulate(np.nan_to_num(g, nan=0.0))
    g[0] = 0.0
    return np.tile(normalise_curve(g)[0], (n_channels, 1))


def _stack(pairs: Sequence[Correspondences], lo: float, hi: float, max_level: int):
    d, b, r, w = [], [], [], []
    for corr in pairs:
        wt = pair_weight(corr, lo, hi, max_level)
        keep = wt > 0
        d.append(corr.dark[keep])
        b.append(corr.bright[keep])
        r.append(corr.pair[keep])
        w.append(wt[keep])
    return np.concatenate(d), np.concatenate(b), np.concatenate(r), np.concatenate(w)


def fit_family(
    name: str,
    pairs: Sequence[Correspondences],
    log_ratios: np.ndarray,
    max_level: int,
    lo: float,
    hi: float,
    *,
    n_channels: int = 3,
) -> ResponseCurve:
    """Fit family ``name`` (shared by the channels) to the level pairs of every channel with
    the known ``log_ratios``; returns the curve with its parameters and residual."""
    if name not in FAMILIES:
        raise ParameterError(
            f"unknown response family {name!r}", expected=f"one of {', '.join(FAMILIES)}"
        )
    fam = FAMILIES[name]
    d, b, p, w = _stack(pairs, lo, hi, max_level)
    if w.size < 2:
        raise ParameterError("no level pairs to fit a response family to")
    xd, xb = d / max_level, b / max_level
    target = np.asarray(log_ratios, dtype=np.float64)[p]

    def residual(q: np.ndarray) -> np.ndarray:
        gd = np.maximum(fam.fn(xd, q), 1e-9)
        gb = np.maximum(fam.fn(xb, q), 1e-9)
        return w * (np.log(gb) - np.log(gd) - target)

    best = None
    starts = [np.asarray(fam.start, float)]
    if name == "filmic":
        starts += [np.array([0.6]), np.array([6.0])]
    from scipy.optimize import least_squares  # here: scipy.optimize is 0.2 s to import

    for x0 in starts:
        sol = least_squares(residual, x0, bounds=(fam.lower, fam.upper), x_scale="jac")
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    rms = float(np.sqrt(2.0 * best.cost / np.sum(w**2)))
    params = {n: float(v) for n, v in zip(fam.names, best.x, strict=True)}
    text = ", ".join(f"{n} {v:.3g}" for n, v in params.items())
    return ResponseCurve(
        g=family_curve(name, best.x, max_level, n_channels),
        method=name,
        status="ok",
        message=f"{fam.description}: {text}; residual {100 * rms:.2f} %",
        parameters={"family": name, **params, "residual_rms": rms},
    )
