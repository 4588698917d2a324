"""The HDR merge: a weighted average of linearised frames divided by their exposure times.

``E = sum_k(w_k * g(M_k) / dt_k) / sum_k(w_k)`` (Debevec & Malik 1997, eq. 6, in the linear
domain), where ``g`` linearises output levels to the saturation scale, ``dt_k`` are the (relative)
exposure times estimated after Cerman & Hlavac (2006, eqs. 3-4) and ``w_k`` a weighting function of
:mod:`hdrcore.merge.weights`.

Rules that keep the result free of colour casts and honest about what it could not see:

* A frame is dropped for *all* channels of a pixel when *any* channel of that pixel is at or above
  its saturation level (per-channel white levels allowed) or the warp marked the pixel invalid.
  Merging the unclipped channels of a frame with the clipped ones taken from a darker frame is
  what turns highlights magenta or green when one channel clips first.
* A sample at or below the noise floor gets zero weight in its own channel only.
* A pixel no frame gives weight to takes the darkest valid frame clipped there, a lower bound,
  and is flagged ``clipped``, when every usable frame is a shorter exposure than that frame
  (too short to see the pixel: a frame below the noise floor, or black, says nothing against
  a clip level). Otherwise a channel below the noise floor in every usable frame takes the
  brightest usable frame that gave the pixel weight (any usable one when none did; also where
  a longer exposure saw nothing where a shorter one clipped, data that contradict themselves,
  a marker or a moving object) and the pixel is flagged ``underexposed``. Such a value is that
  frame's ``E_k = g(M) / dt`` exactly as the weighted sums formed it (float32).
* With ``colour=`` (a :class:`~hdrcore.merge.colour.ColourConversion`) the radiance comes out in
  the working space, the pixels clipped in every frame neutral: the fused kernel converts each
  block while it is in cache, which saves a pass over the map.

Units: for integer frames ``saturation_level`` and ``noise_floor`` are output levels (the frames'
own units, 0..``max_level``); for float frames (already linear, 1.0 = saturation) they are linear
values. The radiance is in the units of ``g(M) / dt``: with times relative to the darkest frame,
``E`` of the darkest frame's unclipped pixels is its linear value.

Hand-held frames need not be warped beforehand: with ``transforms`` the merge resamples them
itself (Keys cubic convolution from the integer levels, see :func:`merge`; ``resample="bilinear"``
is a faster, softer opt-in), so the pipeline passes the bracket's own levels and no warped float
copies exist. The fused kernel runs the taps and the "any tap clipped" test of pixels whose
supports share their source rows as contiguous SIMD loops (see :mod:`hdrcore.merge._fused`); a
support leaving the frame reads as no data.

The work runs over chunks of rows so that every temporary stays in cache (float32 throughout); the
peak memory beyond inputs and outputs is a few megabytes per worker.

References
----------
J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with hand held
camera", Computer Vision Winter Workshop, 2006.
P. E. Debevec, J. Malik, "Recovering high dynamic range radiance maps from photographs",
SIGGRAPH 1997, eq. 6. doi:10.1145/258734.258884
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._threads import worker_count
from ..errors import ParameterError, validate_method
from . import _fused
from .colour import ColourConversion, apply_colour
from .consistency import GhostRegions, GhostTestParams, consistency_regions
from .deghost import fill_ghost_regions
from .maps import (
    DEFAULT_GHOST_THRESHOLD,
    DEFAULT_MODEL_ERROR,
    dominant_frame,
    provenance_summary,
    to_float16_nonnegative,
)
from .weights import WEIGHTS, NoiseModel

__all__ = [
    "MergeResult",
    "merge",
    "MERGE_ENGINES",
    "DEFAULT_SATURATION",
    "DEFAULT_CHUNK_PIXELS",
    "RESAMPLING",
    "GHOST_TESTS",
    "default_engine",
]

logger = logging.getLogger(__name__)

DEFAULT_SATURATION = 0.98
"""Default saturation level as a fraction of ``max_level`` (integer frames) or of 1.0 (floats)."""

GHOST_TESTS = {
    "regions": "blocks that disagree beyond noise, misregistration and the response's own "
               "error, in connected regions (hdrcore.merge.consistency)",
    "pixels": "every pixel whose score exceeds the threshold (hdrcore.merge.maps)",
}
"""How the ``ghost`` map is decided (``merge(..., ghost_test=...)``)."""

DEFAULT_CHUNK_PIXELS = 1 << 16
"""Pixels per chunk: keeps a chunk's temporaries (about 40 bytes per sample) in L2 cache."""


@dataclass(frozen=True, eq=False)
class MergeResult:
    """The merged radiance map and the per-pixel diagnostics of how it was made.

    radiance
        float32 ``(H, W, C)``, ``g(M) / dt`` in the units of the exposure times given.
    weight_sum
        float32 ``(H, W)``: the total weight (all frames, all channels) behind each pixel; 0 where
        a fallback value was used.
    shares
        float16 ``(N, H, W)``: frame ``k``'s share of the weight at each pixel, in the order the
        frames were given; sums to 1 over ``k`` at every pixel.
    clip_count
        uint8 ``(H, W)``: number of valid frames in which the pixel is clipped (any channel).
    clipped
        bool ``(H, W)``: clipped in every valid frame that could see the pixel (frames below
        the noise floor that are shorter exposures, e.g. a black frame, do not count); the value
        is the darkest clipped frame's (a lower bound).
    underexposed
        bool ``(H, W)``: some channel is at or below the noise floor in every usable frame.
    ghost_score, ghost
        float16 ``(H, W)`` per-pixel score of :func:`hdrcore.merge.maps.ghost_score_from_moments`
        and the ghost mask: with ``ghost_test="pixels"`` ``ghost_score > ghost_threshold``, with
        ``"regions"`` (the default) the pixels of the regions where blocks of the frames
        disagree (:func:`hdrcore.merge.consistency.consistency_regions`, in ``ghost_regions``).
    engine
        which implementation ran (a key of :data:`MERGE_ENGINES`).
    deghosted
        bool ``(H, W)``: pixels filled from one frame by ``merge(..., deghost=True)`` (``None``
        without it).
    """

    radiance: np.ndarray
    weight_sum: np.ndarray
    shares: np.ndarray
    clip_count: np.ndarray
    clipped: np.ndarray
    underexposed: np.ndarray
    ghost_score: np.ndarray
    ghost: np.ndarray
    exposure_times: tuple[float, ...]
    weighting: str
    units: str
    max_level: int | None
    saturation_level: tuple[float, ...]
    noise_floor: float
    noise: NoiseModel
    ghost_threshold: float
    model_error: float
    status: str
    message: str
    timings: dict[str, float] = field(default_factory=dict)
    engine: str = "numpy"
    deghosted: np.ndarray | None = None
    ghost_test: str = "pixels"
    ghost_regions: GhostRegions | None = None

    @property
    def n_frames(self) -> int:
        return int(self.shares.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.radiance.shape[0]), int(self.radiance.shape[1]))

    @property
    def dominant_frame(self) -> np.ndarray:
        """Index of the frame with the largest share at each pixel, uint8 ``(H, W)``."""
        return dominant_frame(self.shares)

    @property
    def success(self) -> bool:
        return self.status in ("ok", "warning")

    def summary(self) -> dict:
        """JSON-ready diagnostics (no arrays)."""
        n_pix = max(self.clipped.size, 1)
        return {
            "status": self.status,
            "message": self.message,
            "shape": list(self.shape),
            "n_frames": self.n_frames,
            "exposure_times": list(self.exposure_times),
            "weighting": self.weighting,
            "units": self.units,
            "max_level": self.max_level,
            "saturation_level": list(self.saturation_level),
            "noise_floor": self.noise_floor,
            "noise": self.noise.to_json(),
            "ghost_threshold": self.ghost_threshold,
            "model_error": self.model_error,
            "clipped_fraction": float(np.count_nonzero(self.clipped)) / n_pix,
            "underexposed_fraction": float(np.count_nonzero(self.underexposed)) / n_pix,
            "ghost_test": self.ghost_test,
            "ghost_fraction": float(np.count_nonzero(self.ghost)) / n_pix,
            "ghost_regions": None if self.ghost_regions is None
            else self.ghost_regions.to_json(),
            "deghosted_fraction": None if self.deghosted is None
            else float(np.count_nonzero(self.deghosted)) / n_pix,
            "provenance": provenance_summary(self.shares),
            "timings": dict(self.timings),
            "engine": self.engine,
        }


# --------------------------------------------------------------------------------------------
# Input validation: everything is checked once, here, and turned into a plan for the kernel.


@dataclass(frozen=True, eq=False)
class _Plan:
    frames: tuple[np.ndarray, ...]
    masks: tuple[np.ndarray | None, ...]
    times: np.ndarray  # float64 (N,)
    order: np.ndarray  # frame indices, shortest exposure first
    shape: tuple[int, int, int]
    integer: bool
    max_level: int | None
    lut: np.ndarray | None  # float32 (C, L) linear value per channel and level
    lut_var: np.ndarray | None  # float32 (C, L) level-noise variance through g' per level
    lut_len: int
    saturation: np.ndarray  # (C,) in frame units
    floor: float  # in frame units
    weighting: str
    noise: NoiseModel
    transforms: tuple[np.ndarray | None, ...] = ()  # per frame: output -> frame coordinates
    resample: str = "cubic"  # a key of RESAMPLING
    # per frame: a displacement field added to the transform's position (local refinement,
    # :class:`hdrcore.registration.field.DisplacementField`: ``step``, ``offsets``, ``origin``)
    fields: tuple[Any, ...] = ()

    @property
    def warped(self) -> bool:
        return any(t is not None for t in self.transforms)


def _as_frames(frames: Sequence[np.ndarray]) -> tuple[tuple[np.ndarray, ...], bool]:
    if frames is None or len(frames) == 0:
        raise ParameterError("no frames to merge", expected="at least one frame", found="0")
    arrs = []
    kinds = set()
    for k, f in enumerate(frames):
        a = np.asarray(f)
        if a.ndim == 2:
            a = a[..., None]
        if a.ndim != 3 or a.shape[2] < 1:
            raise ParameterError(
                f"frame {k} must be an image", expected="(H, W, C) or (H, W)", found=str(a.shape)
            )
        if a.dtype.kind == "f":
            kinds.add("float")
            if a.dtype != np.float32:
                a = a.astype(np.float32)
        elif a.dtype.kind == "u":
            kinds.add("integer")
        else:
            raise ParameterError(
                f"frame {k} has an unsupported dtype",
                expected="unsigned integer levels or float linear values",
                found=str(a.dtype),
            )
        arrs.append(np.ascontiguousarray(a))
    if len(kinds) > 1:
        raise ParameterError(
            "frames mix integer levels and float values",
            expected="all integer or all float",
            found=", ".join(str(a.dtype) for a in arrs),
        )
    shape = arrs[0].shape
    for k, a in enumerate(arrs[1:], start=1):
        if a.shape != shape:
            raise ParameterError(
                f"frame {k} has a different shape from frame 0",
                expected=str(shape),
                found=str(a.shape),
            )
    return tuple(arrs), kinds == {"integer"}


def _plan(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float],
    response: np.ndarray | None,
    max_level: int | None,
    masks: Sequence[np.ndarray | None] | None,
    saturation_level: float | Sequence[float] | None,
    noise_floor: float | None,
    weighting: str | None,
    noise: NoiseModel | None,
    transforms: Sequence[np.ndarray | None] | None = None,
    fields: Sequence[Any] | None = None,
) -> _Plan:
    arrs, integer = _as_frames(frames)
    n = len(arrs)
    h, w, c = arrs[0].shape
    times = np.asarray(exposure_times, dtype=np.float64).ravel()
    if times.size != n:
        raise ParameterError(
            "one exposure time per frame", expected=str(n), found=str(times.size)
        )
    if not np.all(np.isfinite(times)) or np.any(times <= 0):
        raise ParameterError(
            "exposure times must be finite and positive",
            found=str([float(t) for t in times]),
        )
    order = np.argsort(times, kind="stable")

    lut = lut_var = None
    lut_len = 0
    if integer:
        if response is not None:
            g = np.asarray(response, dtype=np.float64)
            if g.ndim == 1:
                g = np.broadcast_to(g, (c, g.size))
            if g.ndim != 2 or g.shape[0] != c or g.shape[1] < 2:
                raise ParameterError(
                    "response LUT must be (C, L) with one row per channel",
                    expected=f"({c}, max_level + 1)",
                    found=str(np.shape(response)),
                )
            if not np.all(np.isfinite(g)):
                raise ParameterError("response LUT must be finite")
            lut_len = g.shape[1]
            if max_level is None:
                max_level = lut_len - 1
            elif int(max_level) != lut_len - 1:
                raise ParameterError(
                    "response LUT length must be max_level + 1",
                    expected=str(int(max_level) + 1),
                    found=str(lut_len),
                )
        elif max_level is None:
            if arrs[0].dtype == np.uint8:
                max_level = 255
            else:
                raise ParameterError(
                    "max_level is needed for integer frames without a response LUT",
                    expected="the largest level, e.g. 4095 for 12-bit",
                    found="None",
                )
        max_level = int(max_level)
        if max_level < 1 or max_level > np.iinfo(arrs[0].dtype).max:
            raise ParameterError(
                "max_level out of range for the frames' dtype",
                expected=f"1..{np.iinfo(arrs[0].dtype).max}",
                found=str(max_level),
            )
        if response is None:
            lut_len = max_level + 1
        else:
            nl = noise or NoiseModel()
            slope = np.gradient(g, axis=1)  # g'(M) per level
            lut = np.ascontiguousarray(g, dtype=np.float32)
            lut_var = np.ascontiguousarray(slope**2 * nl.level_variance(), dtype=np.float32)
        unit_max = float(max_level)
    else:
        if response is not None:
            raise ParameterError(
                "a response LUT applies to integer levels only; float frames must be linear",
                expected="response=None for float frames",
                found=f"LUT of shape {np.shape(response)}",
            )
        if max_level is not None:
            max_level = int(max_level)
        unit_max = 1.0

    units = "levels" if integer else "linear values"
    if saturation_level is None:
        sat = np.full(c, DEFAULT_SATURATION * unit_max)
    else:
        sat = np.asarray(saturation_level, dtype=np.float64).ravel()
        if sat.size == 1:
            sat = np.full(c, float(sat[0]))
        if sat.size != c:
            raise ParameterError(
                "saturation level must be a number or one per channel",
                expected=f"1 or {c} values",
                found=str(sat.size),
            )
    floor = 0.0 if noise_floor is None else float(noise_floor)
    if not np.all(np.isfinite(sat)) or np.any(sat <= 0) or np.any(sat > unit_max):
        raise ParameterError(
            f"saturation level out of range ({units})",
            expected=f"0 < saturation <= {unit_max:g}",
            found=str([float(s) for s in sat]),
        )
    if not np.isfinite(floor) or floor < 0 or floor >= float(sat.min()):
        raise ParameterError(
            f"noise floor out of range ({units})",
            expected=f"0 <= noise floor < saturation level {float(sat.min()):g}",
            found=str(floor),
        )

    if weighting is None:
        weighting = "hat" if lut is not None else "noise-aware"
    weighting = validate_method(weighting, WEIGHTS, "weighting")
    noise = noise or NoiseModel()
    if not isinstance(noise, NoiseModel):
        raise ParameterError("noise must be a NoiseModel", found=type(noise).__name__)

    mask_list: list[np.ndarray | None] = [None] * n
    if masks is not None:
        if len(masks) != n:
            raise ParameterError(
                "one validity mask (or None) per frame", expected=str(n), found=str(len(masks))
            )
        for k, m in enumerate(masks):
            if m is None:
                continue
            m = np.asarray(m)
            if m.ndim == 3 and m.shape[2] == 1:
                m = m[..., 0]
            if m.shape != (h, w):
                raise ParameterError(
                    f"validity mask {k} does not match the frames",
                    expected=str((h, w)),
                    found=str(m.shape),
                )
            mask_list[k] = np.ascontiguousarray(m, dtype=bool)
    tf_list = _as_transforms(transforms, n)
    fld_list = _as_fields(fields, n)
    # a frame with a field is resampled even where its transform is the identity
    tf_list = tuple(_IDENTITY.copy() if t is None and fld is not None else t
                    for t, fld in zip(tf_list, fld_list, strict=True))

    return _Plan(
        frames=arrs,
        masks=tuple(mask_list),
        times=times,
        order=order,
        shape=(h, w, c),
        integer=integer,
        max_level=max_level,
        lut=lut,
        lut_var=lut_var,
        lut_len=lut_len,
        saturation=sat,
        floor=floor,
        weighting=weighting,
        noise=noise,
        transforms=tf_list,
        fields=fld_list,
    )


def _as_fields(fields: Sequence[Any] | None, n: int) -> tuple[Any, ...]:
    """One displacement field or ``None`` per frame; every field on the same node grid (one
    compiled lookup serves them all)."""
    if fields is None:
        return (None,) * n
    if len(fields) != n:
        raise ParameterError("one displacement field (or None) per frame", expected=str(n),
                             found=str(len(fields)))
    grid = None
    for k, fld in enumerate(fields):
        if fld is None:
            continue
        off = getattr(fld, "offsets", None)
        if off is None or not hasattr(fld, "step") or not hasattr(fld, "origin"):
            raise ParameterError(f"field {k} is not a displacement field",
                                 expected="DisplacementField (step, offsets, origin)",
                                 found=type(fld).__name__)
        key = (float(fld.step), tuple(fld.origin), tuple(np.shape(off)))
        if grid is not None and key != grid:
            raise ParameterError("the displacement fields of one merge must share their grid",
                                 expected=str(grid), found=f"field {k}: {key}")
        grid = key
    return tuple(fields)


_IDENTITY = np.eye(3)

_LUT_MODE = "levels"
"""How resampled frames with a response LUT are linearised: ``"levels"`` (the default and the
fused kernel's) interpolates the levels and reads the LUT linearly between entries;
``"samples"`` (numpy reference only, kept for the accuracy comparison in
``bench/bench_merge.py``) linearises the 16 taps and interpolates linear values. On simulated
gamma brackets with the true motion "levels" is as accurate or slightly better (the scene is
smoother in the gamma domain than in linear values) and needs one table read, not 16."""


def _as_transforms(
    transforms: Sequence[np.ndarray | None] | None, n: int
) -> tuple[np.ndarray | None, ...]:
    """One float64 3x3 matrix (output -> frame pixel coordinates: a 2x3 affine matrix or a
    homography, normalised so ``m[2, 2] = 1``) or ``None`` per frame; identities (within 1e-9)
    become ``None`` so they take the direct path."""
    if transforms is None:
        return (None,) * n
    if len(transforms) != n:
        raise ParameterError(
            "one transform (2x3 matrix, 3x3 homography or None) per frame", expected=str(n),
            found=str(len(transforms)),
        )
    out: list[np.ndarray | None] = []
    for k, t in enumerate(transforms):
        if t is None:
            out.append(None)
            continue
        a = np.asarray(t, dtype=np.float64)
        if a.shape not in ((2, 3), (3, 3)) or not np.all(np.isfinite(a)) or (
                a.shape == (3, 3) and abs(a[2, 2]) < 1e-12):
            raise ParameterError(
                f"transform {k} must be a finite 2x3 affine matrix or 3x3 homography "
                "(output -> frame pixels)", expected="(2, 3) or (3, 3)", found=str(a.shape),
            )
        m = np.eye(3)
        m[: a.shape[0]] = a
        m /= m[2, 2]
        out.append(None if np.max(np.abs(m - _IDENTITY)) <= 1e-9 else np.ascontiguousarray(m))
    return tuple(out)


# --------------------------------------------------------------------------------------------
# The kernel.


@dataclass
class _Outputs:
    radiance: np.ndarray
    weight_sum: np.ndarray
    shares: np.ndarray
    clip_count: np.ndarray
    clipped: np.ndarray
    underexposed: np.ndarray
    ghost_score: np.ndarray
    ghost: np.ndarray


class _Scratch:
    """Per-worker buffers for one chunk, channel-planar so every operation is contiguous."""

    def __init__(self, n_frames: int, size: int, channels: int) -> None:
        planes = (channels, size)
        # E_k = g(M) / dt of every frame, as the sums saw it: the fallback values
        self.ek = np.empty((n_frames, channels, size), np.float32)
        self.den = np.empty(planes, np.float32)  # sum w
        self.num = np.empty(planes, np.float32)  # sum w E_k
        self.s2 = np.empty(planes, np.float32)  # sum w E_k^2
        self.sv = np.empty(planes, np.float32)  # sum w var(E_k)
        self.x = np.empty(size, np.float32)
        self.level = np.empty(size, np.float32)
        self.var = np.empty(size, np.float32)
        self.a = np.empty(size, np.float32)
        self.b = np.empty(size, np.float32)
        self.keep = np.empty(size, bool)
        self.ok = np.empty(size, bool)
        self.flag = np.empty(size, bool)
        self.idx = np.empty(size, np.intp)
        self.i32 = np.empty(size, np.int32)
        self.nbad = np.empty(size, np.uint8)
        self.bad = np.empty((n_frames, size), bool)
        self.clip = np.empty((n_frames, size), bool)
        self.share = np.empty((n_frames, size), np.float32)


_TINY = np.float32(1e-30)


def _accumulate(op, dst: np.ndarray, src: np.ndarray) -> None:
    if op is np.copyto:
        np.copyto(dst, src)
    else:
        np.add(dst, src, out=dst)


class _Kernel:
    def __init__(self, plan: _Plan, out: _Outputs, ghost_threshold: float, model_error: float):
        self.p = plan
        self.out = out
        self.ghost_threshold = np.float32(ghost_threshold)
        self.model_error2 = np.float32(model_error**2)
        self.inv_max = np.float32(1.0 / plan.max_level) if plan.integer else np.float32(1.0)
        self.floor_norm = np.float32(plan.floor * float(self.inv_max))
        self.weight_fn = WEIGHTS[plan.weighting]
        nm = plan.noise
        self.shot = np.float32(nm.shot_gain)
        const = nm.read_noise**2
        if plan.integer and plan.lut is None:
            # linear levels: level noise and quantisation scale by 1 / max_level
            const += nm.level_variance() * float(self.inv_max) ** 2
        self.const_var = np.float32(max(const, 1e-12))

    # ---- linearisation of one channel of one frame's chunk ---------------------------------
    def _linearise(
        self, col: np.ndarray, ch: int, s: _Scratch, m: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, level, var)`` of a column of levels or linear values, each float32 ``(m,)``."""
        p = self.p
        level, var = s.level[:m], s.var[:m]
        if not p.integer:
            np.copyto(level, col)
            x = level
        else:
            np.multiply(col, self.inv_max, out=level, dtype=np.float32)
            if p.lut is None:
                x = level
            else:
                x, idx = s.x[:m], s.idx[:m]
                np.copyto(idx, col, casting="unsafe")
                np.take(p.lut[ch], idx, out=x)
                np.take(p.lut_var[ch], idx, out=var)
                if self.shot:
                    np.multiply(x, self.shot, out=s.a[:m])
                    var += s.a[:m]
                var += self.const_var
                return x, level, var
        np.multiply(x, self.shot, out=var)
        var += self.const_var
        return x, level, var

    # ---- resampling of a frame with a transform (reference of _fused.merge_rows) ---------
    def _sample(
        self, k: int, r0: int, r1: int
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        """Frame ``k`` at ``T_k (x, y, 1)`` for the output pixels of rows ``r0:r1``.

        Keys cubic convolution (a = -1/2) of the raw samples (levels or linear floats) with the
        4 weights per axis shared by the channels, clamped to ``[0, max_level]`` (``[0, 1]``).
        Returns ``(values (C, m) float32, LUT values (C, m) float32 or None, tap_clip (m,),
        inside (m,))``: ``tap_clip`` where any of the 16 taps of any channel is at or above its
        saturation level, ``inside`` where the whole 4x4 support lies in the frame. With a
        response LUT the taps are linearised before the interpolation (``LUT values``).
        """
        p = self.p
        if p.resample == "cubic":
            from ..resample import keys_weights as weights  # the project's Keys weights

            ntap, o = 4, 1.0
        else:  # bilinear: weights 1 - f, f of taps 0, 1

            def weights(f):
                return np.stack([1.0 - f, f])

            ntap, o = 2, 0.0
        h, w, c = p.shape
        t = p.transforms[k]
        pix = np.arange(r0 * w, r1 * w, dtype=np.int64)
        yy = (pix // w).astype(np.float64)
        xx = (pix % w).astype(np.float64)
        sw = t[2, 0] * xx + t[2, 1] * yy + t[2, 2]
        sx = (t[0, 0] * xx + t[0, 1] * yy + t[0, 2]) / sw
        sy = (t[1, 0] * xx + t[1, 1] * yy + t[1, 2]) / sw
        fld = p.fields[k] if p.fields else None
        if fld is not None:  # local refinement: the field at the output pixel
            dx, dy = fld.at(xx, yy)
            sx = sx + dx
            sy = sy + dy
        fx0 = np.floor(sx)
        fy0 = np.floor(sy)
        inside = (fx0 >= o) & (fx0 <= w - (ntap - o)) & (fy0 >= o) & (fy0 <= h - (ntap - o))
        wx = weights(np.where(inside, sx - fx0, 0.0)).astype(np.float32)
        wy = weights(np.where(inside, sy - fy0, 0.0)).astype(np.float32)
        base = np.where(inside, (fy0 - o) * w + (fx0 - o), 0.0).astype(np.int64) * c
        flat = p.frames[k].reshape(-1)
        m = pix.size
        tap_clip = np.zeros(m, bool)
        vals = np.empty((c, m), np.float32)
        lut_vals = None if p.lut is None or _LUT_MODE != "samples" else np.empty((c, m), np.float32)
        hi = np.float32(p.max_level if p.integer else 1.0)
        for ch in range(c):
            acc = lacc = None
            for jy in range(ntap):
                row = lrow = None
                for jx in range(ntap):
                    # (clip: an outside pixel of a frame smaller than the support reads
                    # some sample; its value and flag are discarded below)
                    taps = flat.take(base + ((jy * w + jx) * c + ch), mode="clip")
                    tap_clip |= taps >= p.saturation[ch]
                    if p.lut is not None and np.any((taps >= p.lut_len) & inside):
                        raise IndexError(f"level {int(taps.max())} past the end of the LUT")
                    term = taps.astype(np.float32) * wx[jx]
                    row = term if row is None else row + term
                    if lut_vals is not None:
                        lv = p.lut[ch].take(np.minimum(taps, p.lut_len - 1)) * wx[jx]
                        lrow = lv if lrow is None else lrow + lv
                term = row * wy[jy]
                acc = term if acc is None else acc + term
                if lut_vals is not None:
                    lv = lrow * wy[jy]
                    lacc = lv if lacc is None else lacc + lv
            np.clip(acc, np.float32(0.0), hi, out=vals[ch])
            if lut_vals is not None:
                np.clip(lacc, np.float32(0.0), p.lut[ch, -1], out=lut_vals[ch])
        tap_clip &= inside
        vals[:, ~inside] = 0.0  # no data (a pixel with no valid frame at all reads 0 there)
        if lut_vals is not None:
            lut_vals[:, ~inside] = 0.0
        return vals, lut_vals, tap_clip, inside

    def _linearise_sampled(
        self, vals: np.ndarray, lut_vals: np.ndarray | None, ch: int, s: _Scratch, m: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, level, var)`` of interpolated values (see :meth:`_sample`), float32 ``(m,)``.

        With a LUT, ``x`` is the interpolation of the linearised taps and the variance that of
        the LUT's level noise at the interpolated level (linear between table entries).
        """
        p = self.p
        level, var = s.level[:m], s.var[:m]
        if not p.integer:
            np.copyto(level, vals)
            x = level
        else:
            np.multiply(vals, self.inv_max, out=level)
            if p.lut is None:
                x = level
            else:
                x = s.x[:m]
                lo = np.minimum(vals.astype(np.intp), p.lut_len - 2)
                frac = vals - lo.astype(np.float32)
                if lut_vals is not None:
                    np.copyto(x, lut_vals)
                else:  # _LUT_MODE "levels": the LUT linearly interpolated at the level
                    v0 = p.lut[ch].take(lo)
                    np.subtract(p.lut[ch].take(lo + 1), v0, out=x)
                    x *= frac
                    x += v0
                v0 = p.lut_var[ch].take(lo)
                np.subtract(p.lut_var[ch].take(lo + 1), v0, out=var)
                var *= frac
                var += v0
                if self.shot:
                    np.multiply(x, self.shot, out=s.a[:m])
                    var += s.a[:m]
                var += self.const_var
                return x, level, var
        np.multiply(x, self.shot, out=var)
        var += self.const_var
        return x, level, var

    # ---- one chunk of rows -------------------------------------------------------------------
    def run(self, r0: int, r1: int, s: _Scratch) -> None:
        p = self.p
        _, w, c = p.shape
        m = (r1 - r0) * w
        den, num, s2, sv = s.den[:, :m], s.num[:, :m], s.s2[:, :m], s.sv[:, :m]
        keep, ok, flag = s.keep[:m], s.ok[:m], s.flag[:m]
        nbad = s.nbad[:m]
        nbad.fill(0)
        clip_count = self.out.clip_count[r0:r1].reshape(m)
        clip_count.fill(0)
        for j, k in enumerate(p.order):
            bad, clip = s.bad[k, :m], s.clip[k, :m]
            mask = p.masks[k]
            valid = None if mask is None else mask[r0:r1].reshape(m)
            if p.transforms[k] is None:
                src = p.frames[k][r0:r1].reshape(m, c)
                sampled = None
                # A pixel is clipped in this frame when any channel reaches its saturation level.
                np.greater_equal(src[:, 0], p.saturation[0], out=clip)
                for ch in range(1, c):
                    np.greater_equal(src[:, ch], p.saturation[ch], out=flag)
                    clip |= flag
            else:
                # Resampled at the mapped position: clipped when any tap of the 4x4 support in
                # any channel is; no data where the support leaves the frame.
                sampled, lut_vals, tap_clip, inside = self._sample(k, r0, r1)
                np.copyto(clip, tap_clip)
                valid = inside if valid is None else valid & inside
            if valid is not None:
                clip &= valid
                np.logical_not(valid, out=bad)
                bad |= clip
            else:
                np.copyto(bad, clip)
            clip_count += clip
            nbad += bad
            np.logical_not(bad, out=ok)
            t = float(p.times[k])
            inv_t = np.float32(1.0 / t)
            inv_t2 = np.float32(1.0 / (t * t))
            share = s.share[k, :m]
            for ch in range(c):
                if sampled is None:
                    x, level, var = self._linearise(src[:, ch], ch, s, m)
                else:
                    x, level, var = self._linearise_sampled(
                        sampled[ch], None if lut_vals is None else lut_vals[ch], ch, s, m
                    )
                e = s.ek[k, ch, :m]
                np.multiply(x, inv_t, out=e)  # E_k = g(M) / dt
                wk = self.weight_fn(level, x, t, var)
                # zero weight at or below the noise floor (this channel) and for dropped pixels
                # (all channels: any channel clipped, or invalid after the warp)
                np.greater(level, self.floor_norm, out=keep)
                keep &= ok
                wk *= keep
                # the first frame initialises the sums (saves clearing them)
                acc = np.copyto if j == 0 else np.add
                _accumulate(acc, den[ch], wk)
                _accumulate(np.copyto if ch == 0 else np.add, share, wk)
                var *= wk  # w var(E_k) = w var(x) / dt^2
                var *= inv_t2
                _accumulate(acc, sv[ch], var)
                wk *= e  # w E_k
                _accumulate(acc, num[ch], wk)
                wk *= e  # w E_k^2
                _accumulate(acc, s2[ch], wk)
        self._finish(r0, r1, s, m)

    def _finish(self, r0: int, r1: int, s: _Scratch, m: int) -> None:
        p, out = self.p, self.out
        n = len(p.frames)
        c = p.shape[2]
        den, num = s.den[:, :m], s.num[:, :m]
        a, b, inv = s.a[:m], s.b[:m], s.x[:m]
        rad = out.radiance[r0:r1].reshape(m, c)
        spread, noise = s.level[:m], s.var[:m]
        wsum = out.weight_sum[r0:r1].reshape(m)
        anyzero = s.keep[:m]
        for ch in range(c):
            np.maximum(den[ch], _TINY, out=inv)
            np.divide(np.float32(1.0), inv, out=inv)
            np.multiply(num[ch], inv, out=a)  # E (0 where no weight)
            rad[:, ch] = a
            # ghost moments (maps.ghost_score_from_moments, channel-planar)
            np.multiply(s.s2[ch, :m], inv, out=b)
            np.square(a, out=a)
            b -= a
            np.maximum(b, 0.0, out=b)
            if ch == 0:
                np.copyto(spread, b)
            else:
                spread += b
            a *= self.model_error2
            np.multiply(s.sv[ch, :m], inv, out=b)
            b += a
            if ch == 0:
                np.copyto(noise, b)
                np.copyto(wsum, den[ch])
                np.less_equal(den[ch], 0.0, out=anyzero)
            else:
                noise += b
                wsum += den[ch]
                np.less_equal(den[ch], 0.0, out=s.flag[:m])
                anyzero |= s.flag[:m]
        np.maximum(noise, _TINY, out=noise)
        spread /= noise
        np.greater(spread, self.ghost_threshold, out=out.ghost[r0:r1].reshape(m))
        to_float16_nonnegative(spread, out.ghost_score[r0:r1].reshape(m), s.i32[:m])
        np.maximum(wsum, _TINY, out=inv)
        np.divide(np.float32(1.0), inv, out=inv)
        shares = s.share[:, :m]
        need = np.flatnonzero(anyzero)
        # which frames contributed to each pixel needing a fallback (before normalising)
        seen = shares[:, need] > 0.0
        shares *= inv
        clipped = out.clipped[r0:r1].reshape(m)
        under = out.underexposed[r0:r1].reshape(m)
        under.fill(False)
        clipped.fill(False)
        if need.size:
            self._fallback(need, seen, s, rad, shares, clipped, under)
        for k in range(n):
            to_float16_nonnegative(shares[k], out.shares[k, r0:r1].reshape(m), s.i32[:m])

    def _fallback(
        self,
        need: np.ndarray,
        seen: np.ndarray,
        s: _Scratch,
        rad: np.ndarray,
        shares: np.ndarray,
        clipped: np.ndarray,
        under: np.ndarray,
    ) -> None:
        """Values for pixels the weighted average could not estimate (see the module doc).

        ``need``: chunk pixels with a channel of no weight; ``seen (N, q)``: frame ``k``
        contributed weight to pixel ``need[q]`` (some channel above the noise floor).
        """
        p = self.p
        order = p.order
        n = len(order)
        seen_o = seen[order]  # (N, q), exposure order
        whole = (s.den[:, need] <= 0).all(axis=0)  # no frame contributed to any channel
        clip_o = s.clip[np.ix_(order, need)]  # clipped (and valid), exposure order
        has_clip = clip_o.any(axis=0)
        first = np.where(has_clip, np.argmax(clip_o, axis=0), 0)
        usable_o = ~s.bad[np.ix_(order, need)]
        last_usable = np.where(usable_o.any(axis=0), n - 1 - np.argmax(usable_o[::-1], axis=0),
                               -1)
        # 1) no frame gave the pixel weight, some valid frame is clipped there and every usable
        #    frame (below the floor) is a shorter exposure than the darkest clipped one: that
        #    frame's value, a lower bound (a frame too short to see the pixel, or black, says
        #    nothing against it). No valid frame at all: the darkest frame's value, not flagged.
        every = whole & ((has_clip & (last_usable < first)) | (s.nbad[need] == n))
        for j, k in enumerate(order):
            pick = need[every & (first == j)]
            if pick.size == 0:
                continue
            rad[pick] = s.ek[k][:, pick].T
            shares[:, pick] = 0.0
            shares[k, pick] = 1.0
        clipped[need[every & has_clip]] = True
        # 2) some channel at or below the noise floor in every usable frame: that channel takes
        #    the brightest usable frame that saw the pixel (any usable frame when none did; also
        #    where a longer exposure saw nothing where a shorter one clipped: the frames
        #    contradict each other, a marker or a moving object, and the longest reading stays)
        rest_q = np.flatnonzero(~every)
        if rest_q.size:
            rest = need[rest_q]
            zero = (s.den[:, rest] <= 0).T  # (q, C)
            usable = ~s.bad[np.ix_(order, rest)]
            sr = seen_o[:, rest_q]
            cand = np.where(sr.any(axis=0), sr, usable)
            last = n - 1 - np.argmax(cand[::-1], axis=0)
            for j, k in enumerate(order):
                sel = np.flatnonzero(last == j)
                if sel.size == 0:
                    continue
                pick = rest[sel]
                vals = s.ek[k][:, pick].T
                target = rad[pick]
                zc = zero[sel]
                target[zc] = vals[zc]
                rad[pick] = target
                wholes = pick[whole[rest_q[sel]]]
                if wholes.size:
                    shares[:, wholes] = 0.0
                    shares[k, wholes] = 1.0
            under[rest] = True

# --------------------------------------------------------------------------------------------
# Engines: the numpy reference above (one vectorised operation at a time over chunks of rows)
# and the fused numba kernel of :mod:`hdrcore.merge._fused` (one pass per pixel). Both give the
# same result; the reference is the specification the fused kernel is tested against.


def _run_numpy(kernel: _Kernel, spans: list[tuple[int, int]], workers: int, rows: int) -> None:
    p = kernel.p
    _, w, c = p.shape
    n = len(p.frames)
    if workers == 1:
        scratch = _Scratch(n, rows * w, c)
        for r0, r1 in spans:
            kernel.run(r0, r1, scratch)
        return
    scratches = [_Scratch(n, rows * w, c) for _ in range(workers)]
    groups = [spans[i::workers] for i in range(workers)]

    def work(i: int) -> None:
        for r0, r1 in groups[i]:
            kernel.run(r0, r1, scratches[i])

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(work, range(workers)))


def _level_tables(kernel: _Kernel) -> np.ndarray:
    """float32 ``(N, C L, 8)``: ``E_k, w, w var(E_k), w E_k, w E_k**2`` (and three zeros: one
    aligned 32-byte line a level, so a sample's five values are one cache line even when a
    16-bit table does not fit the cache) of every level ``0..max_level`` (``L`` levels) of
    every frame, channel ``ch``'s level ``v`` at row ``ch L + v`` (the fused kernel's
    :func:`~hdrcore.merge._fused._accumulate_levels_table`).

    Built with the reference's own linearisation and weight function, in its operation order,
    so a table entry is bit for bit what the reference computes for a sample of that level
    (the noise floor is applied; clipping and masks, which depend on the pixel, are not).
    """
    p = kernel.p
    n, c = len(p.frames), p.shape[2]
    dtype = p.frames[0].dtype
    length = int(p.max_level) + 1
    levels = np.arange(length, dtype=dtype)
    s = _Scratch(n, length, c)
    tab = np.zeros((n, c * length, 8), np.float32)
    for k in range(n):
        t = float(p.times[k])
        inv_t = np.float32(1.0 / t)
        inv_t2 = np.float32(1.0 / (t * t))
        for ch in range(c):
            row = slice(ch * length, (ch + 1) * length)
            x, level, var = kernel._linearise(levels, ch, s, length)
            e = np.multiply(x, inv_t)
            wk = kernel.weight_fn(level, x, t, var)
            wk *= level > kernel.floor_norm
            tab[k, row, 0] = e
            tab[k, row, 1] = wk
            var *= wk
            var *= inv_t2
            tab[k, row, 2] = var
            wk *= e
            tab[k, row, 3] = wk
            wk *= e
            tab[k, row, 4] = wk
    return tab


def _fused_supported(plan: _Plan) -> str | None:
    """Why the fused kernel cannot run this plan, or ``None`` when it can."""
    if not _fused.AVAILABLE:
        return "numba is not installed"
    if plan.shape[2] != 3:
        return f"{plan.shape[2]} channels (the fused kernel is unrolled for 3)"
    if plan.integer and plan.frames[0].dtype not in (np.uint8, np.uint16):
        return f"integer frames of dtype {plan.frames[0].dtype} (uint8 and uint16 only)"
    return None


def _run_numba(
    kernel: _Kernel, out: _Outputs, spans: list[tuple[int, int]], workers: int,
    force_tables: bool = False, colour: ColourConversion | None = None,
) -> None:
    """The fused kernel (:func:`hdrcore.merge._fused.merge_rows`) over ``spans`` of
    rows, ``colour`` applied inside it. Integer frames read in place go through the
    reference's per-level tables when they have a LUT or ``force_tables``."""
    p = kernel.p
    frames = p.frames
    if p.integer and len({f.dtype for f in frames}) > 1:
        frames = tuple(f.astype(np.uint16) for f in frames)
    frames_t = tuple(frames)
    dummy = np.ones((1, 1), bool)
    masks_t = tuple(m if m is not None else dummy for m in p.masks)
    has_mask = np.array([m is not None for m in p.masks], np.bool_)
    order = np.ascontiguousarray(p.order, np.int64)
    sat = np.ascontiguousarray(p.saturation, np.float64)
    me2 = kernel.model_error2
    thr = kernel.ghost_threshold
    outs = (
        out.radiance, out.weight_sum, out.shares.view(np.uint16), out.clip_count, out.clipped,
        out.underexposed, out.ghost_score.view(np.uint16), out.ghost,
    )
    inv_t = np.array([1.0 / t for t in p.times], np.float32)
    use_tab = bool(p.integer and (p.lut is not None or force_tables)
                   and not all(tf is not None for tf in p.transforms))
    if use_tab:
        tabs = _level_tables(kernel)
    else:
        tabs = np.zeros((len(frames), 3, 8), np.float32)
    inv_t2 = np.array([1.0 / (t * t) for t in p.times], np.float32)
    t2 = np.array([float(t) ** 2 for t in p.times], np.float32)
    wcode = _fused.WEIGHT_CODES[p.weighting]
    mats = np.zeros((len(frames), 3, 3))
    for k, tf in enumerate(p.transforms):
        mats[k] = _IDENTITY if tf is None else tf
    has_mat = np.array([tf is not None for tf in p.transforms], np.bool_)
    # local refinement: the frames' displacement fields on one node grid
    fl = [f for f in p.fields if f is not None] if p.fields else []
    if fl:
        flds = np.zeros((len(frames),) + np.shape(fl[0].offsets), np.float64)
        for k, f in enumerate(p.fields):
            if f is not None:
                flds[k] = f.offsets
        fgeo = np.array([1.0 / fl[0].step, fl[0].origin[0], fl[0].origin[1]])
    else:
        flds = np.zeros((len(frames), 2, 2, 2))
        fgeo = np.array([1.0, 0.0, 0.0])
    has_fld = np.array([bool(p.fields) and p.fields[k] is not None
                        for k in range(len(frames))], np.bool_)
    has_lut = p.lut is not None
    lut = p.lut if has_lut else np.zeros((3, 2), np.float32)
    lut_var = p.lut_var if has_lut else lut
    hi = np.float32(p.max_level if p.integer else 1.0)
    tap_thr = _fused.tap_thresholds(sat, frames_t[0].dtype)
    ntap = 4 if p.resample == "cubic" else 2
    # levels past the LUT (refused): only a frame that holds any is searched for them
    lmax = lut.shape[1] - 1
    oor = np.array([
        bool(has_lut and has_mat[k] and np.iinfo(f.dtype).max > lmax and f.max() > lmax)
        for k, f in enumerate(frames_t)
    ], np.bool_)

    flats = tuple(f.reshape(f.shape[0], -1) for f in frames_t)
    # padded to a multiple of TUPLE_SLOTS: one compiled kernel serves every frame count
    pad = -len(frames_t) % _fused.TUPLE_SLOTS
    frames_t += (frames_t[0],) * pad
    flats += (flats[0],) * pad
    masks_t += (masks_t[0],) * pad
    cm, cwb, cneu = colour if colour is not None else (np.eye(3), np.ones(3), np.ones(3))

    def work(span: tuple[int, int]) -> int:
        return _fused.merge_rows(
            frames_t, flats, masks_t, has_mask, mats, has_mat, order, inv_t, inv_t2, t2,
            wcode, kernel.shot, kernel.const_var, kernel.floor_norm, kernel.inv_max,
            hi, has_lut, lut, lut_var, tap_thr, me2, thr, span[0], span[1],
            *outs, ntap, oor, colour is not None, cm, cwb, cneu, use_tab, tabs,
            flds, has_fld, fgeo,
        )

    if workers == 1:
        bad_levels = sum(work(sp) for sp in spans)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            bad_levels = sum(pool.map(work, spans))
    if bad_levels:
        raise ParameterError(
            "levels above max_level have no response LUT entry",
            expected=f"levels 0..{p.max_level}",
            found=f"{bad_levels} samples above {p.max_level}",
        )


RESAMPLING: dict[str, str] = {
    "cubic": "Keys cubic convolution (a = -1/2), 4x4 taps: the default, as sharp as a tripod",
    "bilinear": "bilinear, 2x2 taps: faster, slightly softer (opt-in)",
}
"""Interpolations of frames with a transform, by name (``merge(..., resample=...)``)."""


MERGE_ENGINES: dict[str, str] = {
    "numba": "fused one-pass kernel compiled by numba (hdrcore.merge._fused)",
    "numpy": "vectorised numpy over chunks of rows: the reference implementation",
}
"""Implementations of :func:`merge` by name; both give the same result."""


def default_engine() -> str:
    """``"numba"`` when numba is importable, else ``"numpy"``."""
    return "numba" if _fused.AVAILABLE else "numpy"



def _merge_one_frame(plan: _Plan, k: int, y0: int, y1: int, **kw) -> MergeResult:
    """Frame ``k`` merged alone over output rows ``y0:y1`` with the plan's settings (for
    :func:`hdrcore.merge.deghost.fill_ghost_regions`). A resampled frame is cut to a band of
    rows holding both the output rows and the source rows they map to (its transform shifted
    to the band), so the output grid and the frame share one row offset."""
    h = plan.shape[0]
    t = plan.transforms[k] if plan.transforms else None
    fld = plan.fields[k] if plan.fields else None
    b0, b1 = y0, y1
    if t is not None:
        w = plan.shape[1]
        ys = np.array([y0, y1 - 1], float)
        xs = np.array([0.0, w - 1.0])
        sy = [(t[1, 0] * x + t[1, 1] * y + t[1, 2]) / (t[2, 0] * x + t[2, 1] * y + t[2, 2])
              for x in xs for y in ys]
        pad = 0 if fld is None else int(np.ceil(float(np.abs(fld.offsets[..., 1]).max())))
        b0 = max(0, min(y0, int(np.floor(min(sy))) - 3 - pad))
        b1 = min(h, max(y1, int(np.ceil(max(sy))) + 4 + pad))
        t = np.array(t, float)
        t[:, 2] += t[:, 1] * b0  # output row y of the band is row y + b0 of the grid
        t[1] -= b0 * t[2]  # ... and the frame's band starts at its row b0
    mask = plan.masks[k]
    res = merge(
        [plan.frames[k][b0:b1]], [float(plan.times[k])], max_level=plan.max_level,
        masks=None if mask is None else [mask[b0:b1]],
        saturation_level=tuple(float(v) for v in plan.saturation), noise_floor=plan.floor,
        weighting=plan.weighting, noise=plan.noise,
        transforms=None if t is None else [t],
        fields=None if fld is None else [fld.shifted(0.0, float(b0))],
        resample=plan.resample, **kw,
    )
    if (b0, b1) == (y0, y1):
        return res
    rows = slice(y0 - b0, y1 - b0)
    return replace(res, radiance=res.radiance[rows], weight_sum=res.weight_sum[rows],
                   clipped=res.clipped[rows], underexposed=res.underexposed[rows])


def _output_layout(shape: tuple[int, int, int], n: int) -> dict[str, tuple[tuple, type]]:
    """Shape and dtype of every output array of a merge of ``n`` frames of ``shape``."""
    h, w, c = shape
    return {
        "radiance": ((h, w, c), np.float32), "weight_sum": ((h, w), np.float32),
        "shares": ((n, h, w), np.float16), "clip_count": ((h, w), np.uint8),
        "clipped": ((h, w), np.bool_), "underexposed": ((h, w), np.bool_),
        "ghost_score": ((h, w), np.float16), "ghost": ((h, w), np.bool_),
    }


def _new_outputs(shape: tuple[int, int, int], n: int) -> _Outputs:
    return _Outputs(**{name: np.empty(shp, dtype)
                       for name, (shp, dtype) in _output_layout(shape, n).items()})


def _reused_outputs(res: MergeResult, shape: tuple[int, int, int], n: int) -> _Outputs:
    """The arrays of ``res`` as outputs, after checking they fit (``merge(..., reuse=res)``)."""
    arrays = {}
    for name, (shp, dtype) in _output_layout(shape, n).items():
        a = getattr(res, name, None)
        if not (isinstance(a, np.ndarray) and a.shape == shp and a.dtype == dtype
                and a.flags.c_contiguous and a.flags.writeable):
            raise ParameterError(
                f"reuse: the previous result's {name} does not fit this merge",
                expected=f"C-contiguous writeable {np.dtype(dtype).name} {shp}",
                found="missing" if not isinstance(a, np.ndarray)
                else f"{a.dtype} {a.shape}",
            )
        arrays[name] = a
    return _Outputs(**arrays)


def merge(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float],
    *,
    response: np.ndarray | None = None,
    max_level: int | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    saturation_level: float | Sequence[float] | None = None,
    noise_floor: float | None = None,
    weighting: str | None = None,
    noise: NoiseModel | None = None,
    ghost_threshold: float = DEFAULT_GHOST_THRESHOLD,
    model_error: float = DEFAULT_MODEL_ERROR,
    chunk_pixels: int = DEFAULT_CHUNK_PIXELS,
    workers: int | None = None,
    engine: str | None = None,
    transforms: Sequence[np.ndarray | None] | None = None,
    fields: Sequence[Any] | None = None,
    resample: str = "cubic",
    reuse: MergeResult | None = None,
    colour: ColourConversion | None = None,
    deghost: bool = False,
    ghost_test: str = "regions",
    ghost_params: GhostTestParams | None = None,
) -> MergeResult:
    """Merge aligned frames into one radiance map ``E = sum(w g(M) / dt) / sum(w)``.

    Parameters
    ----------
    frames
        ``N`` aligned frames ``(H, W, C)``, any exposure order: either unsigned integer output
        levels (with ``response`` and/or ``max_level``) or float32 linear values at the saturation
        scale (1.0 = saturation; float64 is converted).
    exposure_times
        ``N`` positive (relative) exposure times.
    response
        float ``(C, L)`` (or ``(L,)`` for all channels) LUT ``g``: level -> linear value at the
        saturation scale, ``L = max_level + 1``. ``None`` means the levels are linear
        (``g(M) = M / max_level``, e.g. RAW after black subtraction).
    max_level
        Largest level of integer frames (255, 4095, ``white - black``...). Defaults to ``L - 1`` of
        the LUT, or 255 for uint8.
    masks
        Optional ``N`` boolean ``(H, W)`` validity masks (``False`` = no data, e.g. the border of a
        warped frame) or ``None`` entries.
    saturation_level
        A sample at or above it is clipped; a number or one per channel (per-channel white
        levels). Integer frames: output levels; float frames: linear values. Default
        ``0.98 * max_level`` (or 0.98).
    noise_floor
        A sample at or below it gets zero weight in its channel; same units as
        ``saturation_level``. Default 0.
    weighting
        A name in :data:`hdrcore.merge.weights.WEIGHTS`; default ``"hat"`` with a response LUT
        (non-linear data), else ``"noise-aware"`` (linear data).
    noise
        :class:`NoiseModel` for the noise-aware weight and the ghost test.
    ghost_threshold, model_error
        See :mod:`hdrcore.merge.maps`.
    chunk_pixels, workers
        Pixels per chunk of rows and worker threads (numpy releases the GIL in its loops);
        ``workers=None`` uses up to two threads.
    engine
        A name in :data:`MERGE_ENGINES`; ``None`` picks the fused numba kernel when it can run
        the input (numba installed, uint8/uint16 or float frames) and the numpy reference
        otherwise. Both give the same result.
    transforms
        Optional ``N`` entries, each ``None`` (identity) or a 2x3 affine matrix mapping OUTPUT
        (reference-frame) pixel coordinates to that frame's pixel coordinates (x right, y down,
        origin at the centre of the top-left pixel), i.e.
        ``hdrcore.registration.invert(to_reference[k])``. Such a frame is resampled inside the
        merge, straight from its levels (or floats): Keys cubic convolution (a = -1/2), the 4
        weights per axis shared by the channels; integer levels are interpolated, clamped to
        ``[0, max_level]`` and linearised through the LUT read linearly between entries. The
        frame counts as clipped at a pixel when any of the 16 taps of any channel is at or
        above its saturation level (interpolation never mixes clipped and valid data) and as
        no data (like a ``False`` mask) where the 4x4 support leaves the frame. ``masks`` stay
        in output coordinates. Identity matrices take the direct path (no interpolation).
    resample
        A name in :data:`RESAMPLING`: ``"cubic"`` (above) or ``"bilinear"`` (2x2 taps, the same
        rules with the 2x2 support; about half the cost of a resampled frame, a little softer).
    reuse
        A previous result of the same shape and frame count whose arrays receive this result
        (overwritten: the caller must no longer use it). Writing into pages the process has
        already touched saves the first-touch cost of new output arrays (28 bytes a pixel for
        3 frames), which on a virtual machine can exceed the merge itself.

    colour
        A :class:`hdrcore.merge.colour.ColourConversion` (camera RGB -> working space,
        :func:`~hdrcore.merge.colour.colour_conversion`): the radiance comes out converted, the
        pixels clipped in every frame made neutral, exactly as
        :func:`~hdrcore.merge.colour.camera_to_working` would; the fused kernel does it while
        the block is in cache (one pass less over the map).
    deghost
        Fill each region where the frames disagree (``ghost``, grown by 2 pixels) from one
        frame, the one with the largest share there (a frame not resampled when its share is at
        least half of that), where that frame is usable
        (:mod:`hdrcore.merge.deghost`): a moving object comes out whole instead of doubled.
        Replaced pixels are marked in ``MergeResult.deghosted``; their shares go wholly to
        that frame and ``ghost`` still shows where the frames disagreed.
    ghost_test, ghost_params
        A name in :data:`GHOST_TESTS`: ``"regions"`` (default; the per-pixel test fires on
        JPEG, demosaicing, misregistration and the response's error of static non-linear
        brackets: 5 % of the memorial scans, 14 % of a hand-held phone bracket) or ``"pixels"``;
        ``ghost_params`` the :class:`~hdrcore.merge.consistency.GhostTestParams` of
        ``"regions"``.

    Raises
    ------
    ParameterError
        For an empty list, mismatched shapes, non-positive times, out-of-range levels, unknown
        weighting names, a LUT or mask that does not fit the frames and a transform that is not
        a finite 2x3 matrix.
    """
    t0 = time.perf_counter()
    plan = _plan(
        frames, exposure_times, response, max_level, masks, saturation_level, noise_floor,
        weighting, noise, transforms, fields,
    )
    resample = validate_method(resample, RESAMPLING, "resampling")
    if resample != plan.resample:
        plan = replace(plan, resample=resample)
    if not np.isfinite(ghost_threshold) or ghost_threshold <= 0:
        raise ParameterError("ghost threshold must be positive", found=str(ghost_threshold))
    if not np.isfinite(model_error) or model_error < 0:
        raise ParameterError("model error must be >= 0", found=str(model_error))
    ghost_test = validate_method(ghost_test, GHOST_TESTS, "ghost test")
    if workers is None:
        workers = worker_count(None)
    if int(chunk_pixels) < 1 or int(workers) < 1:
        raise ParameterError(
            "chunk_pixels and workers must be >= 1", found=f"{chunk_pixels}, {workers}"
        )
    if engine is None:
        engine = "numba" if _fused_supported(plan) is None else "numpy"
    else:
        engine = validate_method(engine, MERGE_ENGINES, "merge engine")
        why = _fused_supported(plan) if engine == "numba" else None
        if why is not None:
            raise ParameterError(
                "the numba merge engine cannot run this input", expected="engine='numpy'",
                found=why,
            )
    h, w, c = plan.shape
    n = len(plan.frames)
    t1 = time.perf_counter()
    out = (_new_outputs((h, w, c), n) if reuse is None
           else _reused_outputs(reuse, (h, w, c), n))
    kernel = _Kernel(plan, out, float(ghost_threshold), float(model_error))
    rows = max(1, int(chunk_pixels) // w)
    if engine == "numba":
        # no per-chunk scratch: chunks only balance the threads' work
        rows = max(rows, -(-h // (16 * int(workers))))
    spans = [(r, min(h, r + rows)) for r in range(0, h, rows)]
    workers = min(int(workers), len(spans))
    if engine == "numba":
        # exp() of the Gaussian weight is not numpy's to the last bit: integer levels take it
        # from the per-level tables the reference computes, so they stay bit for bit the same
        _run_numba(kernel, out, spans, workers, force_tables=plan.integer
                   and plan.weighting == "gaussian", colour=colour)
    else:
        try:
            _run_numpy(kernel, spans, workers, rows)
        except IndexError as exc:  # np.take of a level past the end of the LUT
            raise ParameterError(
                "levels above max_level have no response LUT entry",
                expected=f"levels 0..{plan.max_level}", found=str(exc),
            ) from exc
    if colour is not None and engine != "numba":
        apply_colour(out.radiance, colour, clipped=out.clipped, out=out.radiance,
                     workers=workers)
    t2 = time.perf_counter()
    ghost_score, ghost = out.ghost_score, out.ghost
    ghost_regions = None
    if ghost_test == "regions":
        ghost_regions = consistency_regions(
            plan.frames, plan.times, saturation=plan.saturation, floor=plan.floor,
            lut=plan.lut, max_level=plan.max_level, noise=plan.noise, masks=plan.masks,
            transforms=plan.transforms or None, candidates=ghost, score=ghost_score,
            params=ghost_params, workers=workers,
            engine="numba" if engine == "numba" else "numpy")
        np.copyto(ghost, ghost_regions.ghost)
    t_ghost = time.perf_counter()
    deghosted = None
    if deghost:
        def single(k: int, y0: int, y1: int) -> MergeResult:
            return _merge_one_frame(plan, k, y0, y1, response=response, engine=engine,
                                    workers=workers, ghost_threshold=ghost_threshold,
                                    model_error=model_error, colour=colour,
                                    ghost_test="pixels")

        # frames not resampled are preferred where nearly as well exposed (no interpolation
        # error in their values)
        prefer = (np.array([t is None for t in plan.transforms]) if plan.warped else None)
        deghosted = fill_ghost_regions(out.radiance, out.weight_sum, out.shares, ghost, single,
                                       prefer=prefer)
    t3 = time.perf_counter()

    n_pix = h * w
    n_clipped = int(np.count_nonzero(out.clipped))
    n_under = int(np.count_nonzero(out.underexposed))
    notes = []
    if n_clipped:
        notes.append(
            f"{100.0 * n_clipped / n_pix:.2f}% of pixels clipped in every frame "
            "(darkest frame's value, a lower bound)"
        )
    if n_under:
        notes.append(
            f"{100.0 * n_under / n_pix:.2f}% of pixels below the noise floor in every frame "
            "in some channel (brightest frame's value)"
        )
    n_ghost = int(np.count_nonzero(ghost))
    if n_ghost:
        notes.append(f"{100.0 * n_ghost / n_pix:.2f}% of pixels disagree between frames (ghosts)")
    if deghosted is not None and deghosted.any():
        notes.append(f"{100.0 * np.count_nonzero(deghosted) / n_pix:.2f}% of pixels filled "
                     "from one frame (deghost)")
    status = "warning" if notes else "ok"
    message = "; ".join(notes) if notes else f"merged {n} frames"
    logger.debug("merge: %s", message)
    return MergeResult(
        radiance=out.radiance,
        weight_sum=out.weight_sum,
        shares=out.shares,
        clip_count=out.clip_count,
        clipped=out.clipped,
        underexposed=out.underexposed,
        ghost_score=ghost_score,
        ghost=ghost,
        exposure_times=tuple(float(t) for t in plan.times),
        weighting=plan.weighting,
        units="levels" if plan.integer else "linear",
        max_level=plan.max_level,
        saturation_level=tuple(float(v) for v in plan.saturation),
        noise_floor=float(plan.floor),
        noise=plan.noise,
        ghost_threshold=float(ghost_threshold),
        model_error=float(model_error),
        status=status,
        message=message,
        timings={"validate": t1 - t0, "merge": t2 - t1, "ghosts": t_ghost - t2,
                 "maps": t3 - t_ghost, "total": t3 - t0},
        engine=engine,
        deghosted=deghosted,
        ghost_test=ghost_test,
        ghost_regions=ghost_regions,
    )
