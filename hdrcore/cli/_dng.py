"""``hdrcore merge --dng OUT.dng``: the pipeline's radiance map as a LinearRaw float DNG.

The merge's radiance is in the working space, white-balanced, per second of exposure
(:class:`hdrcore.pipeline.PipelineResult`). The DNG holds camera RGB without white balance, in
units of the reference frame's white: ``camera = C^-1 @ radiance * t_ref``, with ``C`` the
camera -> working conversion the merge applied (:func:`hdrcore.merge.colour.colour_conversion`,
the same arguments as the pipeline: the first frame's ``rgb_xyz_matrix`` and as-shot white
balance), so a raw editor that applies the file's ColorMatrix1 and AsShotNeutral gets the
merge's colours back. A bracket without a camera matrix (JPEG, or a RAW file without one) is
written with the sRGB matrix (its values are linear sRGB-primaries data).

Layout ``"cfa"`` (``--dng-layout``; ``"auto"`` picks it for a tripod RAW bracket: every frame
RAW with one CFA layout and no frame moved by more than :data:`TRIPOD_PX` at any corner): the
frames' CFA sites merged before demosaicing (:func:`hdrcore.merge.mosaic.merge_mosaic`, the
pipeline's times, saturation, noise floor and noise model), stored as the sensor's mosaic with
the camera's own matrix and white balance, for the raw editor to demosaic.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..io.dng import SRGB_XYZ_TO_CAMERA, DngMetadata, write_float_dng
from ..merge.colour import colour_conversion

__all__ = ["DNG_LAYOUTS", "TRIPOD_PX", "dng_layout", "write_result_dng"]

#: ``--dng-layout`` choices.
DNG_LAYOUTS = ("auto", "linear", "cfa")
#: Largest corner displacement (px) of a frame's registration for the bracket to count as shot
#: from a tripod (the simulator's tripod brackets register within 0.002 px).
TRIPOD_PX = 0.1


def dng_layout(result: Any, requested: str = "auto") -> str:
    """``"cfa"`` or ``"linear"``: what ``requested`` gives for this result (an error when
    ``"cfa"`` is asked of a bracket that cannot have it)."""
    from ..errors import ParameterError
    from ..geometry import corner_error

    b = result.bracket
    cfas = [f.cfa for f in b.frames]
    why = None
    if not b.is_linear or any(c is None for c in cfas):
        why = "the frames are not all RAW files with their CFA data"
    elif any(
        c.data.shape != cfas[0].data.shape or not np.array_equal(c.pattern, cfas[0].pattern)
        for c in cfas
    ):
        why = "the frames' CFA layouts differ"
    else:
        moved = max(
            float(np.max(corner_error(np.asarray(m), np.eye(3), b.shape)))
            for m in result.to_reference
        )
        if moved > TRIPOD_PX:
            why = (
                f"the frames moved (up to {moved:.2f} px at a corner; a CFA merge needs a "
                f"tripod bracket, at most {TRIPOD_PX} px)"
            )
    if requested == "linear" or (requested == "auto" and why is not None):
        return "linear"
    if requested == "cfa" and why is not None:
        raise ParameterError(
            f"no CFA DNG for this bracket: {why}", expected="--dng-layout linear or auto"
        )
    return "cfa"


def _camera_colour(result: Any) -> tuple[np.ndarray, tuple, tuple]:
    """(working -> camera 3x3, ColorMatrix1, white balance) for the result's bracket."""
    b = result.bracket
    f0 = b.frames[0].meta
    space = result.params.working_space
    has_matrix = f0.rgb_xyz_matrix is not None and np.any(np.asarray(f0.rgb_xyz_matrix) != 0)
    if b.is_linear and has_matrix:
        conv = colour_conversion(np.asarray(f0.rgb_xyz_matrix), f0.camera_whitebalance, space)
        return np.linalg.inv(conv.matrix), f0.rgb_xyz_matrix, tuple(conv.white_balance)
    if b.is_linear:
        conv = colour_conversion(None, f0.camera_whitebalance, space)
        return np.linalg.inv(conv.matrix), SRGB_XYZ_TO_CAMERA, tuple(conv.white_balance)
    if space.lower() != "srgb":
        conv = colour_conversion(None, None, space)
        return np.linalg.inv(conv.matrix), SRGB_XYZ_TO_CAMERA, (1.0, 1.0, 1.0)
    return np.eye(3), SRGB_XYZ_TO_CAMERA, (1.0, 1.0, 1.0)


def write_result_dng(
    path: str | os.PathLike,
    result: Any,
    *,
    bits: int = 32,
    layout: str = "auto",
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> tuple[Path, str]:
    """Write ``result.radiance`` (a :class:`~hdrcore.pipeline.PipelineResult`) as a float DNG
    with the reference frame's EXIF and orientation and the merge's provenance in XMP; for the
    ``"cfa"`` layout, the frames' mosaics merged. Returns the path and the layout written."""
    kind = dng_layout(result, layout)
    b = result.bracket
    n = len(b.frames)
    ref = result.registration.reference if result.registration is not None else n // 2
    meta = b.frames[ref].meta
    to_camera, cam_matrix, wb = _camera_colour(result)
    t_ref = float(result.exposure_times[ref])
    provenance = {
        "software": f"hdrcore {__version__}",
        "reference": int(ref),
        "exposureTimes": [float(t) for t in result.exposure_times],
        "exposureRatios": [float(r) for r in result.exposures.ratios],
        "timesSource": result.times_source,
        "transforms": [np.asarray(m).tolist() for m in result.to_reference],
        "sources": [Path(p).name for p in b.paths],
        "workingSpace": result.params.working_space,
        "units": "camera RGB, no white balance; sample / scale = the reference frame's "
        "linear value (1 = its white level)",
    }
    if kind == "cfa":
        # The camera's own colour: the mosaic is camera raw, white balance not applied.
        f0 = b.frames[0].meta
        has_matrix = f0.rgb_xyz_matrix is not None and np.any(np.asarray(f0.rgb_xyz_matrix))
        cam_matrix = f0.rgb_xyz_matrix if has_matrix else SRGB_XYZ_TO_CAMERA
        wb = tuple(f0.camera_whitebalance or (1.0, 1.0, 1.0))[:3]
    dng_meta = DngMetadata(
        make=meta.make,
        model=meta.model,
        color_matrix=tuple(map(tuple, cam_matrix)),
        white_balance=wb,
        orientation=int(meta.orientation or 1),
        exposure_time=meta.exposure_time,
        f_number=meta.f_number,
        iso=meta.iso,
        capture_time=meta.capture_time,
        software=f"hdrcore {__version__}",
        provenance={**provenance, "layout": kind},
    )
    if kind == "linear":
        return write_float_dng(
            path,
            result.radiance,
            dng_meta,
            kind="linear",
            matrix=to_camera * t_ref,
            bits=bits,
            force=force,
            inputs=inputs,
        ), kind
    from ..merge.mosaic import merge_mosaic
    from ..merge.weights import NoiseModel

    # The pipeline's noise model for RAW (hdrcore.pipeline._noise_model): read noise in units
    # of max_level, at least one level.
    sigma = result.noise.sigma if result.noise is not None else float("nan")
    m = b.max_level
    noise = NoiseModel(
        read_noise=max(sigma if np.isfinite(sigma) else 0.0, 1.0) / m,
        full_well=None,
        level_noise=0.0,
    )
    mos = merge_mosaic(
        [f.cfa for f in b.frames],
        result.exposure_times,
        max_level=m,
        saturation_level=float(result.saturation),
        noise_floor=float(result.noise_floor),
        noise=noise,
    )
    # A cell clipped in every frame holds the darkest frame's (noisy, near-white) levels, a
    # lower bound: written at the darkest frame's white on all four sites, so the editor sees
    # it clipped (at the file's WhiteLevel) and reconstructs it as a highlight (darktable
    # rendered such noisy cells green).
    assert mos.merge is not None  # without transforms the sites are merged as one
    mosaic = mos.mosaic.copy()
    clipped = np.repeat(np.repeat(mos.merge.clipped, 2, axis=0), 2, axis=1)
    mosaic[clipped] = np.float32(1.0 / min(result.exposure_times))
    return write_float_dng(
        path,
        mosaic * np.float32(t_ref),
        dng_meta,
        kind="cfa",
        cfa_pattern=mos.channels,
        bits=bits,
        force=force,
        inputs=inputs,
    ), kind
