"""``hdrcore merge --dng OUT.dng``: the pipeline's radiance map as a LinearRaw float DNG.

The merge's radiance is in the working space, white-balanced, per second of exposure
(:class:`hdrcore.pipeline.PipelineResult`). The DNG holds camera RGB without white balance, in
units of the reference frame's white: ``camera = C^-1 @ radiance * t_ref``, with ``C`` the
camera -> working conversion the merge applied (:func:`hdrcore.merge.colour.colour_conversion`,
the same arguments as the pipeline: the first frame's ``rgb_xyz_matrix`` and as-shot white
balance), so a raw editor that applies the file's ColorMatrix1 and AsShotNeutral gets the
merge's colours back. A bracket without a camera matrix (JPEG, or a RAW file without one) is
written with the sRGB matrix (its values are linear sRGB-primaries data).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..io.dng import DngMetadata, write_float_dng
from ..merge.colour import colour_conversion
from ..synthetic.dng import SRGB_XYZ_TO_CAMERA

__all__ = ["write_result_dng"]


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


def write_result_dng(path: str | os.PathLike, result: Any, *, bits: int = 32,
                     force: bool = False, inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Write ``result.radiance`` (a :class:`~hdrcore.pipeline.PipelineResult`) as a float DNG
    with the reference frame's EXIF and orientation and the merge's provenance in XMP."""
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
    dng_meta = DngMetadata(
        make=meta.make, model=meta.model, color_matrix=tuple(map(tuple, cam_matrix)),
        white_balance=wb, orientation=int(meta.orientation or 1),
        exposure_time=meta.exposure_time, f_number=meta.f_number, iso=meta.iso,
        capture_time=meta.capture_time, software=f"hdrcore {__version__}",
        provenance=provenance,
    )
    return write_float_dng(path, result.radiance, dng_meta, kind="linear",
                           matrix=to_camera * t_ref, bits=bits, force=force, inputs=inputs)
