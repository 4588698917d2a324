"""Writing a pipeline run's radiance map: one writer for ``hdrcore merge`` and the inspector.

:func:`write_result` writes :attr:`PipelineResult.radiance` as OpenEXR with everything a reader
needs to trace it back (:func:`hdrcore.io.write_exr`'s attributes): the exposure times and
ratios the merge used, each frame's transform to the reference, the source file names and the
run's reference frame, times source, working space and response method. The file is written
atomically (a temporary file in the same folder, then a rename).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import OutputError
from .io import write_exr

if TYPE_CHECKING:
    from .pipeline import PipelineResult

__all__ = ["common_crop", "crop_preview", "exr_metadata", "write_result"]


def exr_metadata(result: PipelineResult) -> dict[str, Any]:
    """The run's provenance written in the EXR's ``hdrview`` attribute."""
    return {
        "reference": None if result.registration is None else result.registration.reference,
        "times_source": result.times_source,
        "working_space": result.params.working_space,
        "response": None if result.response is None else result.response.method,
    }


def common_crop(result: PipelineResult) -> tuple[int, int, int, int]:
    """The rectangle ``(x0, y0, x1, y1)`` (half-open, reference pixels) of ``result``'s merge
    that every frame it merged covers (:func:`hdrcore.geometry.common_area`): a hand-held
    bracket's border strips, where fewer exposures and, for phones, another frame's local
    rendition make the merge differ, are left out. Each frame counts as covering a pixel when
    the pixel maps at least its resampling support (2 px) plus its largest local displacement
    inside it. The whole frame without registration."""
    from .geometry import common_area

    h, w = result.bracket.shape
    reg = result.registration
    if reg is None:
        return (0, 0, w, h)
    margin = 2.0
    local = getattr(reg, "local", None)
    for fld in getattr(local, "fields", None) or ():
        if fld is not None:
            margin = max(margin, 2.0 + float(np.abs(np.asarray(fld.offsets)).max()))
    return common_area(result.to_reference, (h, w), margin=margin)


def crop_preview(image: np.ndarray, rect: tuple[int, int, int, int], factor: int) -> np.ndarray:
    """The part of a preview made at ``1 / factor`` of the merge's size that lies inside the
    merge's ``rect`` (rounded inwards)."""
    x0, y0, x1, y1 = rect
    f = max(1, int(factor))
    return image[-(-y0 // f) : y1 // f, -(-x0 // f) : x1 // f]


def write_result(
    path: str | os.PathLike[str],
    result: PipelineResult,
    *,
    half: bool = True,
    compression: str = "piz",
    force: bool = False,
    inputs: Iterable[str | os.PathLike[str]] = (),
    workers: int | None = None,
    crop: tuple[int, int, int, int] | None = None,
    overwrite_radiance: bool = False,
) -> Path:
    """Write ``result``'s merged radiance to the OpenEXR file ``path`` (atomically) with the
    run's provenance; return the path written.

    ``half``: half-float samples (else float32); ``compression``: one of
    :data:`hdrcore.io.EXR_COMPRESSIONS`; ``force``: replace an existing file; ``inputs``: files
    the output may never replace (the frames, a times list, a response curve). Raises
    :class:`~hdrcore.errors.OutputError` when the run stopped before the merge. ``crop``:
    write only the rectangle ``(x0, y0, x1, y1)`` of the radiance (:func:`common_crop`); the
    EXR's ``hdrview`` attribute records it. ``overwrite_radiance``: the caller no longer
    needs ``result.radiance`` (nor the pipeline's cached merge): the half floats are made in its
    memory, no copy of the image (:func:`hdrcore.io.write_exr`'s ``overwrite_input``; not with a
    crop), and its values are lost.
    """
    if result.radiance is None:
        raise OutputError(
            "the run has no merged radiance (it stopped before the merge)",
            path=path,
            expected="a result of a run until 'merge' or 'preview'",
            found=f"a run until {result.until!r}",
        )
    radiance = result.radiance
    metadata = exr_metadata(result)
    if crop is not None:
        x0, y0, x1, y1 = (int(v) for v in crop)
        if not (0 <= x0 < x1 <= radiance.shape[1] and 0 <= y0 < y1 <= radiance.shape[0]):
            raise OutputError(
                "the crop is empty or outside the merge",
                path=path,
                expected=f"0 <= x0 < x1 <= {radiance.shape[1]}, 0 <= y0 < y1 <= "
                f"{radiance.shape[0]}",
                found=str((x0, y0, x1, y1)),
            )
        radiance = radiance[y0:y1, x0:x1]
        metadata = {**metadata, "crop": [x0, y0, x1, y1]}
    return write_exr(
        path,
        radiance,
        half=half,
        compression=compression,
        exposure_times=result.exposure_times,
        exposure_ratios=result.exposures.ratios,
        transforms=result.to_reference,
        sources=list(result.bracket.paths),
        metadata=metadata,
        force=force,
        inputs=inputs,
        workers=workers,
        overwrite_input=overwrite_radiance,
    )
