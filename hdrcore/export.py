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

from .errors import OutputError
from .io import write_exr

if TYPE_CHECKING:
    from .pipeline import PipelineResult

__all__ = ["exr_metadata", "write_result"]


def exr_metadata(result: PipelineResult) -> dict[str, Any]:
    """The run's provenance written in the EXR's ``hdrview`` attribute."""
    return {
        "reference": None if result.registration is None else result.registration.reference,
        "times_source": result.times_source,
        "working_space": result.params.working_space,
        "response": None if result.response is None else result.response.method,
    }


def write_result(
    path: str | os.PathLike[str],
    result: PipelineResult,
    *,
    half: bool = True,
    compression: str = "piz",
    force: bool = False,
    inputs: Iterable[str | os.PathLike[str]] = (),
    workers: int | None = None,
) -> Path:
    """Write ``result``'s merged radiance to the OpenEXR file ``path`` (atomically) with the
    run's provenance; return the path written.

    ``half``: half-float samples (else float32); ``compression``: one of
    :data:`hdrcore.io.EXR_COMPRESSIONS`; ``force``: replace an existing file; ``inputs``: files
    the output may never replace (the frames, a times list, a response curve). Raises
    :class:`~hdrcore.errors.OutputError` when the run stopped before the merge.
    """
    if result.radiance is None:
        raise OutputError(
            "the run has no merged radiance (it stopped before the merge)",
            path=path,
            expected="a result of a run until 'merge' or 'preview'",
            found=f"a run until {result.until!r}",
        )
    return write_exr(
        path,
        result.radiance,
        half=half,
        compression=compression,
        exposure_times=result.exposure_times,
        exposure_ratios=result.exposures.ratios,
        transforms=result.to_reference,
        sources=list(result.bracket.paths),
        metadata=exr_metadata(result),
        force=force,
        inputs=inputs,
        workers=workers,
    )
