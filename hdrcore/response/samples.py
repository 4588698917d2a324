"""Input checks and correspondences shared by the response-recovery methods.

Two kinds of correspondences feed the solvers (Cerman & Hlavac 2006, section 4):

* pixel samples -- the same pixel's level in every frame (Debevec & Malik 1997, Mitsunaga &
  Nayar 1999); needs registered frames;
* level pairs from brightness transfer functions -- level ``z`` of a darker frame corresponds to
  level ``T(z)`` of the brighter one (Grossberg & Nayar 2003, and the seed's histogram variant of
  Debevec-Malik); needs no registration, only histograms.

Valid data (the seed's fix, section 4.2): only levels strictly inside ``(low_cut, cutoff *
max_level)`` enter a fit; the default ``cutoff = 0.98`` drops values that noise pushed against
saturation, ``cutoff = 1.0`` with ``low_cut = 0`` is the naive method.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, overload

import numpy as np

from ..errors import BracketError, EstimationError, ParameterError

__all__ = [
    "Correspondences",
    "btf_pairs",
    "check_bracket",
    "check_ratios",
    "consecutive_ratios",
    "hat_weight",
    "log_noise_weight",
    "pair_weight",
    "pixel_pairs",
    "pixel_samples",
    "valid_range",
]


def check_bracket(
    frames: Sequence[np.ndarray], max_level: int | None
) -> tuple[list[np.ndarray], int]:
    """Validate a bracket of integer frames (darkest first); return ``(H, W, C)`` arrays.

    ``(H, W)`` frames are treated as one channel. ``max_level`` defaults to 255 for uint8 and
    to the largest level found otherwise (give it explicitly for 10..16-bit data).
    """
    if isinstance(frames, np.ndarray) and frames.ndim >= 3 and frames.dtype != object:
        frames = list(frames)
    frames = list(frames)
    if len(frames) < 2:
        raise BracketError(
            "response recovery needs a bracket of at least two frames",
            expected=">= 2 frames of different exposure",
            found=f"{len(frames)} frame(s)",
        )
    out = []
    for k, f in enumerate(frames):
        a = np.asarray(f)
        if not np.issubdtype(a.dtype, np.integer):
            raise ParameterError(
                f"frame {k} must hold integer levels",
                expected="an integer dtype",
                found=str(a.dtype),
            )
        if a.ndim == 2:
            a = a[..., None]
        if a.ndim != 3:
            raise ParameterError(f"frame {k} must be (H, W) or (H, W, C)", found=str(a.shape))
        out.append(a)
    shapes = {a.shape for a in out}
    if len(shapes) != 1:
        raise BracketError("frames of a bracket must have the same size", found=str(sorted(shapes)))
    if max_level is None:
        max_level = 255 if out[0].dtype == np.uint8 else int(max(int(a.max()) for a in out))
    max_level = int(max_level)
    if max_level < 3:
        raise ParameterError("max_level must be >= 3", found=str(max_level))
    top = max(int(a.max()) for a in out)
    if top > max_level or min(int(a.min()) for a in out) < 0:
        raise ParameterError(
            "frame levels outside 0..max_level",
            expected=f"0..{max_level}",
            found=f"levels up to {top}",
        )
    return out, max_level


@overload
def consecutive_ratios(
    exposure_times: Sequence[float] | None, n_frames: int, *, required: Literal[True], method: str
) -> tuple[float, ...]: ...
@overload
def consecutive_ratios(
    exposure_times: Sequence[float] | None, n_frames: int, *, required: bool, method: str
) -> tuple[float, ...] | None: ...
def consecutive_ratios(
    exposure_times: Sequence[float] | None, n_frames: int, *, required: bool, method: str
) -> tuple[float, ...] | None:
    """Ratios ``t[k+1] / t[k]`` from exposure times; checks count, sign and order."""
    if exposure_times is None:
        if required:
            raise ParameterError(
                f"{method} needs the exposure times of the frames",
                expected="exposure_times (seconds, darkest first; --times FILE on the command "
                "line)",
                found="none",
            )
        return None
    t = [float(v) if v is not None else float("nan") for v in exposure_times]
    if len(t) != n_frames:
        raise ParameterError(
            "one exposure time per frame", expected=str(n_frames), found=str(len(t))
        )
    if any(not np.isfinite(v) or v <= 0 for v in t):
        raise ParameterError("exposure times must be positive numbers", found=str(t))
    for k in range(n_frames - 1):
        if t[k + 1] == t[k]:
            raise BracketError(
                f"frames {k} and {k + 1} have the same exposure time {t[k]:g} s; "
                "response recovery needs different exposures",
                expected="strictly increasing exposure times",
                found=str(t),
            )
        if t[k + 1] < t[k]:
            raise BracketError(
                "frames must be ordered darkest first",
                expected="strictly increasing exposure times",
                found=str(t),
            )
    return tuple(t[k + 1] / t[k] for k in range(n_frames - 1))


def check_ratios(ratios: Sequence[float], n_frames: int) -> tuple[float, ...]:
    r = tuple(float(v) for v in ratios)
    if len(r) != n_frames - 1:
        raise ParameterError(
            "one exposure ratio per consecutive pair",
            expected=str(n_frames - 1),
            found=str(len(r)),
        )
    for k, v in enumerate(r):
        if not np.isfinite(v) or v <= 1.0:
            raise BracketError(
                f"exposure ratio of frames {k} and {k + 1} is {v:g}; response recovery needs "
                "frames of different exposure, darkest first",
                expected="ratios > 1",
                found=str(r),
            )
    return r


def valid_range(max_level: int, cutoff: float, low_cut: float = 0.0) -> tuple[float, float]:
    """Open interval of levels that enter a fit: ``(low_cut * max, cutoff * max)``."""
    if not 0.0 < cutoff <= 1.0:
        raise ParameterError("saturation cutoff must be in (0, 1]", found=str(cutoff))
    if not 0.0 <= low_cut < cutoff:
        raise ParameterError("low cut must be in [0, cutoff)", found=str(low_cut))
    return low_cut * max_level, cutoff * max_level


def hat_weight(z: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Debevec-Malik hat weighting over ``[lo, hi]``: 1 in the middle, 0 at both ends."""
    z = np.asarray(z, dtype=np.float64)
    mid = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    return np.clip(1.0 - np.abs(z - mid) / half, 0.0, 1.0)


def log_noise_weight(dark: np.ndarray, bright: np.ndarray, max_level: int) -> np.ndarray:
    """Down-weighting of level pairs near black in a fit of ``ln g``.

    The residual ``ln g(T) - ln g(z)`` of a pair carries the level noise times ``d ln g / dz``,
    which goes as ``1 / z`` for power-law curves: a pair a few noise steps above zero is ten
    times noisier than one in the mid-tones and swamps a fit of linear 8-bit frames, whose dark
    frames hold most pixels there. The weight is the inverse of that noise, ``z_eff / z_ref``
    with ``z_eff = 1 / sqrt(1 / dark^2 + 1 / bright^2)``, capped at 1 from ``z_ref =
    max_level / 16`` (16 levels at 8 bits) up: 1 for a pair at 32 and 128, 0.24 at 4 and 16,
    0.12 at 2 and 8.
    """
    z_ref = max_level / 16.0
    d = np.maximum(np.asarray(dark, dtype=np.float64), 0.5)
    b = np.maximum(np.asarray(bright, dtype=np.float64), 0.5)
    z_eff = 1.0 / np.sqrt(1.0 / d**2 + 1.0 / b**2)
    return np.minimum(1.0, z_eff / z_ref)


def pair_weight(corr: Correspondences, lo: float, hi: float, max_level: int) -> np.ndarray:
    """The weight of every level pair in the fits and scores of :mod:`.joint`,
    :mod:`.parametric` and :mod:`.holdout`: its own (pixel count) times the hat weight of both
    levels (DM eq. 4) times :func:`log_noise_weight`."""
    return (
        corr.weight
        * np.sqrt(hat_weight(corr.dark, lo, hi) * hat_weight(corr.bright, lo, hi))
        * log_noise_weight(corr.dark, corr.bright, max_level)
    )


@dataclass(frozen=True, eq=False)
class Correspondences:
    """Level pairs ``(dark, bright)`` of consecutive frames ``(pair, pair + 1)`` with weights."""

    dark: np.ndarray
    bright: np.ndarray
    pair: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return int(self.dark.size)


def pixel_samples(
    frames: Sequence[np.ndarray],
    channel: int,
    max_level: int,
    *,
    n_samples: int = 1000,
    mask: np.ndarray | None = None,
    n_bins: int = 16,
    seed: int = 0,
    max_candidates: int = 60_000,
) -> np.ndarray:
    """Choose pixels whose levels cover the whole range; return their levels ``(N, P)``.

    For every frame the levels of ``channel`` are split into ``n_bins`` equal bins and up to
    ``n_samples / (P * n_bins)`` pixels are drawn from each, preferring pixels in flat
    neighbourhoods (small gradient) so that slight misregistration does not matter. ``mask``
    (``(H, W)`` bool) marks the pixels that may be used.
    """
    p = len(frames)
    h, w = frames[0].shape[:2]
    stack = np.stack([np.asarray(f)[..., channel] for f in frames])  # (P, H, W)
    usable = np.ones((h, w), bool) if mask is None else np.asarray(mask, bool)
    if usable.shape != (h, w):
        raise ParameterError(
            "mask must match the frame size", expected=str((h, w)), found=str(usable.shape)
        )
    if not usable.any():
        raise EstimationError("the mask excludes every pixel")
    # flatness: gradient magnitude of the middle frame
    mid = stack[p // 2].astype(np.float32)
    gy, gx = np.gradient(mid)
    grad = np.hypot(gx, gy).ravel()
    flat_idx = np.flatnonzero(usable.ravel())
    rng = np.random.default_rng(seed + 1009 * channel)
    if flat_idx.size > max_candidates:
        # stratify a random subset: plenty for ~1000 samples, and fast on large frames
        flat_idx = np.sort(rng.choice(flat_idx, size=max_candidates, replace=False))
    per_bin = max(1, int(np.ceil(n_samples / (p * n_bins))))
    chosen: list[np.ndarray] = []
    edges = np.linspace(0, max_level + 1, n_bins + 1)
    for k in range(p):
        levels = stack[k].ravel()[flat_idx]
        b = np.clip(np.searchsorted(edges, levels, side="right") - 1, 0, n_bins - 1)
        order = np.argsort(b, kind="stable")
        starts = np.searchsorted(b[order], np.arange(n_bins + 1))
        for j in range(n_bins):
            members = order[starts[j] : starts[j + 1]]
            if members.size == 0:
                continue
            if members.size > 4 * per_bin:
                g = grad[flat_idx[members]]
                members = members[g <= np.median(g)]
            take = min(per_bin, members.size)
            chosen.append(flat_idx[rng.choice(members, size=take, replace=False)])
    idx = np.unique(np.concatenate(chosen)) if chosen else np.zeros(0, np.intp)
    return stack.reshape(p, -1)[:, idx].T.astype(np.int64)


def pixel_pairs(z: np.ndarray, lo: float, hi: float) -> Correspondences:
    """Consecutive-frame level pairs of pixel samples ``z`` ``(N, P)`` inside ``(lo, hi)``."""
    n, p = z.shape
    dark = z[:, :-1]
    bright = z[:, 1:]
    ok = (dark > lo) & (dark < hi) & (bright > lo) & (bright < hi)
    pair = np.broadcast_to(np.arange(p - 1), (n, p - 1))
    return Correspondences(
        dark=dark[ok].astype(np.float64),
        bright=bright[ok].astype(np.float64),
        pair=pair[ok].astype(np.intp),
        weight=np.ones(int(ok.sum())),
    )


def btf_pairs(
    frames: Sequence[np.ndarray],
    channel: int,
    max_level: int,
    lo: float,
    hi: float,
    *,
    mask: np.ndarray | None = None,
    stride: int = 1,
    hists: Sequence[np.ndarray] | None = None,
) -> Correspondences:
    """Level pairs of consecutive frames from their brightness transfer functions.

    For every dark level ``m`` the continuous dark value ``m + 1/2`` (a bin edge, where the
    cumulative histogram is exact) corresponds to the bright value ``T(m + 1/2)``
    (:func:`hdrcore.btf.brightness_transfer_function`, Grossberg & Nayar 2002). Pairs with both
    values inside ``(lo, hi)`` are kept, weighted by the square root of the pixel count at the
    edge (the mean of the two neighbouring bins), so a histogram pair acts like that many
    pixels. ``hists``: the frames' histograms of ``channel`` with this ``mask`` and ``stride``
    when already counted (every channel of a frame in one pass,
    :func:`hdrcore.histogram.histograms`).
    """
    from ..btf import brightness_transfer_function
    from ..histogram import histogram

    if hists is None:  # else the frames' histograms of this channel (counted as below)
        hists = [
            histogram(np.asarray(f)[..., channel], max_level, mask, stride=stride) for f in frames
        ]
    dark, bright, pair, weight = [], [], [], []
    edge = np.arange(max_level + 1, dtype=np.float64) + 0.5
    for k in range(len(frames) - 1):
        btf = brightness_transfer_function(hists[k], hists[k + 1])
        t = btf.forward_at_edges()
        h = hists[k].astype(np.float64)
        count = 0.5 * (h + np.concatenate([h[1:], [0.0]]))
        ok = (edge > lo) & (edge < hi) & (t > lo) & (t < hi) & (count > 0)
        # the clipped bins (0 and max_level) carry no information, even without a cut
        ok &= (edge > 0.5) & (edge < max_level - 0.5) & (t > 0.5) & (t < max_level - 0.5)
        dark.append(edge[ok])
        bright.append(t[ok])
        pair.append(np.full(int(ok.sum()), k, np.intp))
        weight.append(np.sqrt(count[ok]))
    return Correspondences(
        dark=np.concatenate(dark),
        bright=np.concatenate(bright),
        pair=np.concatenate(pair),
        weight=np.concatenate(weight),
    )
