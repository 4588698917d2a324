"""The HDR merge: weighting functions, the weighted average, per-pixel maps and colour.

Public surface::

    from hdrcore.merge import merge, MergeResult, NoiseModel, WEIGHTS, camera_to_working
"""

from ._fused import warm_up
from .colour import WORKING_SPACES, camera_to_working, camera_to_working_matrix
from .maps import (
    DEFAULT_GHOST_THRESHOLD,
    DEFAULT_MODEL_ERROR,
    dominant_frame,
    ghost_score_from_moments,
    mean_shares,
    provenance_summary,
)
from .merge import (
    DEFAULT_CHUNK_PIXELS,
    DEFAULT_SATURATION,
    MERGE_ENGINES,
    RESAMPLING,
    MergeResult,
    default_engine,
    merge,
)
from .weights import WEIGHTS, NoiseModel, WeightFunction, weights

__all__ = [
    "DEFAULT_CHUNK_PIXELS",
    "DEFAULT_GHOST_THRESHOLD",
    "DEFAULT_MODEL_ERROR",
    "DEFAULT_SATURATION",
    "MERGE_ENGINES",
    "RESAMPLING",
    "WEIGHTS",
    "WORKING_SPACES",
    "MergeResult",
    "NoiseModel",
    "WeightFunction",
    "camera_to_working",
    "camera_to_working_matrix",
    "default_engine",
    "dominant_frame",
    "ghost_score_from_moments",
    "mean_shares",
    "merge",
    "provenance_summary",
    "warm_up",
    "weights",
]
