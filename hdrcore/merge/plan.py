"""Validation of :func:`hdrcore.merge.merge`'s input, once, into a :class:`Plan` for the kernel,
and the arrays the kernel writes (:class:`Outputs`).

Units: for integer frames ``saturation_level`` and ``noise_floor`` are output levels (the frames'
own units, 0..``max_level``); for float frames (already linear, 1.0 = saturation) they are linear
values.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ParameterError, validate_method
from .weights import WEIGHTS, NoiseModel

if TYPE_CHECKING:
    from .result import MergeResult

__all__ = [
    "DEFAULT_SATURATION",
    "IDENTITY",
    "RESAMPLING",
    "Outputs",
    "Plan",
    "SampleModel",
    "as_fields",
    "as_frames",
    "as_transforms",
    "make_plan",
    "new_outputs",
    "output_layout",
    "reused_outputs",
    "sample_model",
]

DEFAULT_SATURATION = 0.98
"""Default saturation level as a fraction of ``max_level`` (integer frames) or of 1.0 (floats)."""

RESAMPLING: dict[str, str] = {
    "cubic": "Keys cubic convolution (a = -1/2), 4x4 taps: the default, as sharp as a tripod",
    "bilinear": "bilinear, 2x2 taps: faster, slightly softer (opt-in)",
}
"""Interpolations of frames with a transform, by name (``merge(..., resample=...)``)."""


def levels_past_lut(last: int | None, found: str) -> ParameterError:
    """The error for frame levels past the response table's last entry ``last`` (the plan's
    check of an identity table, the kernel's count, the consistency test's)."""
    return ParameterError(
        "levels above max_level have no response LUT entry",
        expected=f"levels 0..{last}",
        found=found,
    )


@dataclass(frozen=True, eq=False)
class Plan:
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
    # px over which a resampled frame's weight rises from its edge (0: a step)
    feather: float = 0.0
    # float32 (C, L): the response LUT as given, which the region ghost test reads (its level
    # error and margins are those of non-linear data); ``lut`` is None when it is the
    # identity (:data:`IDENTITY_LUT_TOLERANCE`: the kernel's linear path)
    response: np.ndarray | None = None

    @property
    def warped(self) -> bool:
        return any(t is not None for t in self.transforms)


#: A response LUT within this relative distance of the identity at every level is applied as
#: the identity. Its table costs the merge a lookup per sample where the linear path is
#: vectorised: the 24 MP bench bracket of 16-bit linear TIFFs (recovered gamma 1.0000005,
#: 5.3e-6 from the identity at level 1, less elsewhere) merged in 0.87 s with the table, 0.15 s
#: without, the radiance the same to 3e-7 (weights and shares to the bit).
IDENTITY_LUT_TOLERANCE = 1e-5


def _identity(g: np.ndarray, max_level: int) -> bool:
    """Whether every channel of LUT ``g`` ``(C, max_level + 1)`` is the identity ``v /
    max_level`` within :data:`IDENTITY_LUT_TOLERANCE` of ``v`` (relative)."""
    v = np.arange(g.shape[1], dtype=np.float64) / float(max_level)
    return bool(np.all(np.abs(g - v) <= IDENTITY_LUT_TOLERANCE * v + 1e-12))


@dataclass(frozen=True)
class SampleModel:
    """The float32 constants the kernel applies to a sample of the plan: ``level = value *
    inv_max``, zero weight unless ``level > floor_norm``, ``var(x) = x shot + const_var``
    (plus the LUT's level-noise term), the ghost test's threshold and squared model error."""

    inv_max: np.float32
    floor_norm: np.float32
    shot: np.float32
    const_var: np.float32
    ghost_threshold: np.float32
    model_error2: np.float32


def sample_model(plan: Plan, ghost_threshold: float, model_error: float) -> SampleModel:
    inv_max = (
        np.float32(1.0 / plan.max_level) if plan.integer and plan.max_level else np.float32(1.0)
    )
    nm = plan.noise
    const = nm.read_noise**2
    if plan.integer and plan.lut is None:
        # linear levels: level noise and quantisation scale by 1 / max_level
        const += nm.level_variance() * float(inv_max) ** 2
    return SampleModel(
        inv_max=inv_max,
        floor_norm=np.float32(plan.floor * float(inv_max)),
        shot=np.float32(nm.shot_gain),
        const_var=np.float32(max(const, 1e-12)),
        ghost_threshold=np.float32(ghost_threshold),
        model_error2=np.float32(model_error**2),
    )


def as_frames(frames: Sequence[np.ndarray]) -> tuple[tuple[np.ndarray, ...], bool]:
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


def make_plan(
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
) -> Plan:
    arrs, integer = as_frames(frames)
    n = len(arrs)
    h, w, c = arrs[0].shape
    times = np.asarray(exposure_times, dtype=np.float64).ravel()
    if times.size != n:
        raise ParameterError("one exposure time per frame", expected=str(n), found=str(times.size))
    if not np.all(np.isfinite(times)) or np.any(times <= 0):
        raise ParameterError(
            "exposure times must be finite and positive",
            found=str([float(t) for t in times]),
        )
    order = np.argsort(times, kind="stable")

    lut = lut_var = response_lut = None
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
        # the kernel reads integer levels as uint8 or uint16
        top = min(np.iinfo(arrs[0].dtype).max, np.iinfo(np.uint16).max)
        if max_level < 1 or max_level > top:
            raise ParameterError(
                "max_level out of range for the frames' dtype",
                expected=f"1..{top} (levels of up to 16 bits; float frames otherwise)",
                found=str(max_level),
            )
        if response is not None:
            response_lut = np.ascontiguousarray(g, dtype=np.float32)
        if response is None or _identity(g, max_level):
            # (a response that is the identity: the levels are the linear values, read by the
            # kernel's vectorised linear path, their level noise the same as through the LUT)
            lut_len = max_level + 1
            if response is not None:
                # a LUT has no entry past max_level (the table path counts such samples)
                top = max(int(a.max(initial=0)) for a in arrs)
                if top > max_level:
                    raise levels_past_lut(max_level, f"level {top}")
        else:
            nl = noise or NoiseModel()
            slope = np.gradient(g, axis=1)  # g'(M) per level
            lut = response_lut
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
        weighting = "hat-noise-aware" if lut is not None else "noise-aware"
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
    tf_list = as_transforms(transforms, n)
    fld_list = as_fields(fields, n)
    # a frame with a field is resampled even where its transform is the identity
    tf_list = tuple(
        IDENTITY.copy() if t is None and fld is not None else t
        for t, fld in zip(tf_list, fld_list, strict=True)
    )

    return Plan(
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
        response=response_lut,
    )


def as_fields(fields: Sequence[Any] | None, n: int) -> tuple[Any, ...]:
    """One displacement field or ``None`` per frame; every field on the same node grid (one
    compiled lookup serves them all)."""
    if fields is None:
        return (None,) * n
    if len(fields) != n:
        raise ParameterError(
            "one displacement field (or None) per frame", expected=str(n), found=str(len(fields))
        )
    grid = None
    for k, fld in enumerate(fields):
        if fld is None:
            continue
        off = getattr(fld, "offsets", None)
        if off is None or not hasattr(fld, "step") or not hasattr(fld, "origin"):
            raise ParameterError(
                f"field {k} is not a displacement field",
                expected="DisplacementField (step, offsets, origin)",
                found=type(fld).__name__,
            )
        key = (float(fld.step), tuple(fld.origin), tuple(np.shape(off)))
        if grid is not None and key != grid:
            raise ParameterError(
                "the displacement fields of one merge must share their grid",
                expected=str(grid),
                found=f"field {k}: {key}",
            )
        grid = key
    return tuple(fields)


IDENTITY = np.eye(3)


def as_transforms(
    transforms: Sequence[np.ndarray | None] | None, n: int
) -> tuple[np.ndarray | None, ...]:
    """One float64 3x3 matrix (output -> frame pixel coordinates: a 2x3 affine matrix or a
    homography, normalised so ``m[2, 2] = 1``) or ``None`` per frame; identities (within 1e-9)
    become ``None`` so they take the direct path."""
    if transforms is None:
        return (None,) * n
    if len(transforms) != n:
        raise ParameterError(
            "one transform (2x3 matrix, 3x3 homography or None) per frame",
            expected=str(n),
            found=str(len(transforms)),
        )
    out: list[np.ndarray | None] = []
    for k, t in enumerate(transforms):
        if t is None:
            out.append(None)
            continue
        a = np.asarray(t, dtype=np.float64)
        if (
            a.shape not in ((2, 3), (3, 3))
            or not np.all(np.isfinite(a))
            or (a.shape == (3, 3) and abs(a[2, 2]) < 1e-12)
        ):
            raise ParameterError(
                f"transform {k} must be a finite 2x3 affine matrix or 3x3 homography "
                "(output -> frame pixels)",
                expected="(2, 3) or (3, 3)",
                found=str(a.shape),
            )
        m = np.eye(3)
        m[: a.shape[0]] = a
        m /= m[2, 2]
        out.append(None if np.max(np.abs(m - IDENTITY)) <= 1e-9 else np.ascontiguousarray(m))
    return tuple(out)


@dataclass
class Outputs:
    radiance: np.ndarray
    weight_sum: np.ndarray | None  # None: not kept (merge(..., weight_maps=False))
    shares: np.ndarray | None  # likewise
    clip_count: np.ndarray | None  # likewise
    clipped: np.ndarray
    underexposed: np.ndarray
    ghost_score: np.ndarray
    ghost: np.ndarray


def output_layout(shape: tuple[int, int, int], n: int) -> dict[str, tuple[tuple, type]]:
    """Shape and dtype of every output array of a merge of ``n`` frames of ``shape``."""
    h, w, c = shape
    return {
        "radiance": ((h, w, c), np.float32),
        "weight_sum": ((h, w), np.float32),
        "shares": ((n, h, w), np.float16),
        "clip_count": ((h, w), np.uint8),
        "clipped": ((h, w), np.bool_),
        "underexposed": ((h, w), np.bool_),
        "ghost_score": ((h, w), np.float16),
        "ghost": ((h, w), np.bool_),
    }


WEIGHT_MAPS = ("weight_sum", "shares", "clip_count")
"""The outputs ``merge(..., weight_maps=False)`` does not keep (more than half of the output
memory of a 5-frame merge)."""


_STORED = {"weight_sum": "weight_sum_map", "shares": "share_maps", "clip_count": "clip_count_map"}


def _outputs(arrays: dict[str, np.ndarray | None]) -> Outputs:
    """:class:`Outputs` of ``arrays`` (only the weight maps may be ``None``)."""
    a = {k: v for k, v in arrays.items() if k not in WEIGHT_MAPS}
    if any(v is None for v in a.values()):
        raise ValueError("only the weight maps may be left out")
    return Outputs(
        weight_sum=arrays["weight_sum"],
        shares=arrays["shares"],
        clip_count=arrays["clip_count"],
        **{k: v for k, v in a.items() if v is not None},
    )


def new_outputs(shape: tuple[int, int, int], n: int, weight_maps: bool = True) -> Outputs:
    return _outputs(
        {
            name: None if name in WEIGHT_MAPS and not weight_maps else np.empty(shp, dtype)
            for name, (shp, dtype) in output_layout(shape, n).items()
        }
    )


def reused_outputs(
    res: MergeResult, shape: tuple[int, int, int], n: int, weight_maps: bool = True
) -> Outputs:
    """The arrays of ``res`` as outputs, after checking they fit (``merge(..., reuse=res)``).
    The weight maps (:data:`WEIGHT_MAPS`) are left out without ``weight_maps`` and made anew
    when ``res`` has none (a merge without them)."""
    arrays: dict[str, np.ndarray | None] = {}
    for name, (shp, dtype) in output_layout(shape, n).items():
        # (stored as weight_sum_map, share_maps, clip_count_map: None when not kept)
        a = getattr(res, _STORED.get(name, name), None)
        if name in WEIGHT_MAPS and (not weight_maps or a is None):
            arrays[name] = np.empty(shp, dtype) if weight_maps else None
            continue
        if not (
            isinstance(a, np.ndarray)
            and a.shape == shp
            and a.dtype == dtype
            and a.flags.c_contiguous
            and a.flags.writeable
        ):
            raise ParameterError(
                f"reuse: the previous result's {name} does not fit this merge",
                expected=f"C-contiguous writeable {np.dtype(dtype).name} {shp}",
                found="missing" if not isinstance(a, np.ndarray) else f"{a.dtype} {a.shape}",
            )
        arrays[name] = a
    return _outputs(arrays)
